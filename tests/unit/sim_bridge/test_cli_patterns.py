"""``patternrl patterns`` in process: big teams bounded and drawn, ``--json`` after the action."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from patternrl.cli import main
from sim_bridge.launch.cli_patterns import MAX_SHOW_ROBOTS


def test_show_refuses_more_than_the_maximum_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["patterns", "show", "circle", "--robots", str(MAX_SHOW_ROBOTS + 1)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip().splitlines() == [
        f"patternrl patterns: --robots must be in 2..{MAX_SHOW_ROBOTS}, got {MAX_SHOW_ROBOTS + 1}"
    ]


def test_show_draws_thousands_of_robots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "big.png"
    argv = ["patterns", "show", "circle", "--robots", "5000", "--out", str(out), "--json"]
    assert main(argv) == 0
    info = json.loads(capsys.readouterr().out)
    assert len(info["points"]) == 5000 and info["png"] == str(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("argv", [
    ["patterns", "list", "--json"],
    ["patterns", "--json", "list"],
])
def test_list_json_before_or_after_the_action(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 0
    assert "circle" in json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("argv", [
    ["patterns", "show", "line", "--robots", "4", "--json"],
    ["patterns", "--json", "show", "line", "--robots", "4"],
])
def test_show_json_before_or_after_the_action(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 0
    assert len(json.loads(capsys.readouterr().out)["points"]) == 4


def test_show_spaces_a_pattern_wider_and_saves_it_for_pattern_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from runtime.decision.patterns import make_pattern, min_spacing

    out = tmp_path / "wide.csv"
    assert main(["patterns", "show", "heart", "--robots", "12", "--spacing", "0.6",
                 "--save", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["min_spacing_m"] == pytest.approx(0.6) and info["saved"] == str(out)
    pts = make_pattern(str(out), 12)  # read back as a pattern file: the same shape, wider
    ref = make_pattern("heart", 12)
    assert min_spacing(pts) == pytest.approx(0.6, abs=1e-5)
    assert pts == pytest.approx(ref * (0.6 / min_spacing(ref)), abs=1e-5)
    for bad, why in (("0.1", "--spacing must be at least 2R"),
                     ("nan", "--spacing must be at least 2R")):
        assert main(["patterns", "show", "heart", "--spacing", bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0]
    assert main(["patterns", "show", "line", "--robots", "5000", "--spacing", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "beyond the pattern files'" in err[0]
    assert main(["patterns", "show", "heart", "--save", str(tmp_path / "no" / "x.csv")]) == 2
    assert "cannot write" in capsys.readouterr().err
