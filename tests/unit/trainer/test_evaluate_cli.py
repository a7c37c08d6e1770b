"""``patternrl eval`` in process: a team too small for a pattern is refused in one line."""

from __future__ import annotations

import pytest

from patternrl.cli import main


@pytest.mark.parametrize("robots", ["0", "1", "-3"])
def test_eval_refuses_fewer_than_two_robots(
    robots: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["eval", "--brain", "rule:assign", "--pattern", "circle", "--robots", robots,
            "--episodes", "1", "--no-progress"]
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip().splitlines() == [
        f"patternrl eval: --robots must be >= 2 (a pattern needs 2 robots), got {robots}"
    ]


def test_eval_takes_a_team_of_two(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["eval", "--brain", "rule:assign", "--pattern", "line", "--robots", "2",
            "--episodes", "1", "--no-progress", "--json"]
    assert main(argv) == 0
    assert '"n_robots": 2' in capsys.readouterr().out


@pytest.mark.parametrize("spec", ["realistic,noise_m=-1", "windy"])
def test_eval_refuses_bad_conditions_in_one_line(
    spec: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["eval", "--brain", "rule:assign", "--pattern", "line", "--robots", "4",
            "--episodes", "1", "--no-progress", "--conditions", spec]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("patternrl eval: conditions:")


def test_eval_under_conditions_reports_them_and_the_hold(
    capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    argv = ["eval", "--brain", "rule:frame-balanced", "--pattern", "circle", "--robots", "5",
            "--episodes", "2", "--no-progress", "--json", "--conditions",
            "realistic,kinematics=diff", "--estimator", "--hold-steps", "10"]
    assert main(argv) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["conditions"].startswith("perfect,noise_m=0.05") and "kinematics=diff" in d[
        "conditions"]
    assert d["estimator"] is True and d["hold_steps"] == 10
    assert 0.0 <= d["success_rate"] <= d["formed_rate"] <= 1.0


def test_eval_notes_a_pattern_inside_the_guard_and_a_wider_one_forms(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Under ``harsh`` the guard keeps robots 0.45 m apart as they see them, wider than the
    built-ins' 0.40 m: eval says so in one line on stderr, and the JSON on stdout stays
    whole; the same circle spaced 0.55 m by ``patterns show --spacing --save`` draws no
    note and forms."""
    import json

    base = ["eval", "--brain", "rule:frame-balanced", "--robots", "6", "--episodes", "2",
            "--no-progress", "--json", "--conditions", "harsh", "--estimator"]
    assert main([*base, "--pattern", "circle"]) == 0
    out, err = capsys.readouterr()
    notes = err.strip().splitlines()
    assert len(notes) == 1 and notes[0].startswith(
        "patternrl eval: note: the pattern's closest pair is 0.40 m apart, inside the 0.45 m")
    json.loads(out)
    wide = tmp_path / "wide.csv"
    assert main(["patterns", "show", "circle", "--robots", "6", "--spacing", "0.55",
                 "--save", str(wide)]) == 0
    capsys.readouterr()
    assert main([*base, "--pattern", str(wide)]) == 0
    out, err = capsys.readouterr()
    assert err == "" and json.loads(out)["formed_rate"] > 0.0
    # the perfect world has no guard, and a filter that is off, nothing to note
    for extra in (["--conditions", "perfect"], ["--safety", "off"]):
        assert main([*base, "--pattern", "circle", *extra]) == 0
        assert capsys.readouterr().err == ""


def test_eval_from_a_formed_pattern_measures_the_transition(
    capsys: pytest.CaptureFixture[str]
) -> None:
    """``--from circle``: every episode starts with the circle formed, so the cross is a short
    way off (the circle and the cross of 10 share their centre), far shorter than from random
    starts; the result names the start."""
    import json

    def run(*extra: str) -> dict[str, object]:
        argv = ["eval", "--brain", "rule:frame-balanced", "--pattern", "cross", "--robots",
                "10", "--episodes", "3", "--no-progress", "--json", *extra]
        assert main(argv) == 0
        out: dict[str, object] = json.loads(capsys.readouterr().out)
        return out

    formed, random = run("--from", "circle"), run()
    assert formed["start"] == "circle" and random["start"] == "random"
    assert formed["success_rate"] == 1.0
    assert isinstance(formed["mean_steps"], float) and isinstance(random["mean_steps"], float)
    assert formed["mean_steps"] < 0.5 * random["mean_steps"]


def test_eval_refuses_an_unknown_start_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["eval", "--brain", "rule:assign", "--pattern", "cross", "--robots", "10",
            "--episodes", "1", "--no-progress", "--from", "spiral"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "spiral" in err[0] and err[0].startswith("patternrl eval:")


def test_eval_without_the_guard_lets_the_charging_adversary_collide(
    capsys: pytest.CaptureFixture[str]
) -> None:
    """``--safety orca-no-guard`` measures what the guard costs: on views 3 steps late the
    robots that charge their nearest peer collide without it and not with it."""
    import json

    base = ["eval", "--brain", "adversary:charge", "--pattern", "circle", "--robots", "10",
            "--episodes", "2", "--no-progress", "--json", "--conditions", "latency_steps=3",
            "--estimator", "--seed", "3000000"]
    out = {}
    for mode in ("orca", "orca-no-guard"):
        assert main([*base, "--safety", mode]) == 0
        out[mode] = json.loads(capsys.readouterr().out)
    assert out["orca"]["safety"] == "orca" and out["orca"]["collisions"] == 0
    assert out["orca-no-guard"]["safety"] == "orca-no-guard"
    assert out["orca-no-guard"]["orca"]["guard"] is False
    assert out["orca-no-guard"]["collisions"] > 0
