"""The world's ``--hold-steps``: the option's checks, the held rule, how a phase that held (or
did not) is printed, and a log's report recomputing the held share from the poses."""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from patternrl.cli import main
from runtime.decision.patterns import make_pattern
from runtime.wire import keys
from runtime.wire.messages import PatternMsg, Pose, encode_pattern, encode_pose
from runtime.world_config import DEFAULT_WORLD, HOLD_SHARE, holds
from sim_bridge.launch.launch import format_table
from sim_bridge.log.recorder import Recorder
from sim_bridge.log.report import report_log
from sim_bridge.world.run_results import PhaseResult, RunResult, result_dict
from sim_bridge.world.sim import print_result

W = DEFAULT_WORLD


@pytest.mark.parametrize("argv", [["sim", "--insecure"], ["launch", "--brains", "rule:assign"]])
@pytest.mark.parametrize("value", ["-1", "1001"])
def test_hold_steps_out_of_range_is_one_line_and_exit_2(
    argv: list[str], value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*argv, "--hold-steps", value]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"patternrl {argv[0]}: error: --hold-steps must be in 0..1000, got {value}"]


@pytest.mark.parametrize("command", ["sim", "launch"])
def test_hold_steps_is_in_the_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--hold-steps N watch each formed pattern N steps more" in text
    assert "still formed on 90% of them" in text


def test_the_held_rule_is_evals_share() -> None:
    assert HOLD_SHARE == 0.9
    assert holds(True, 18, 20) and not holds(True, 17, 20)
    assert holds(True, 5, 5) and not holds(True, 4, 5)
    assert not holds(False, 0, 20)  # nothing formed, nothing held
    assert holds(True, 0, 0) and not holds(False, 0, 0)  # no window: held is formed


def _phase(pattern: str, formed: bool, hold: int, held_steps: int) -> PhaseResult:
    return PhaseResult(
        index=0, pattern=pattern, n_robots=4, formed=formed, steps=57, step_limit=400,
        lower_bound_steps=40, travel_m=10.0, lower_bound_travel_m=9.0, collisions=0,
        contacts=0, min_separation_m=0.3, deadline_misses=0, late_commands=0,
        final_error_m=0.01, brain="rule:assign", brain_ids=["rule:assign"], joins=0, leaves=0,
        start_step=0, end_step=57 + hold, wall_s=1.0, hold_steps=hold, held_steps=held_steps,
        held=holds(formed, held_steps, hold))


def test_a_phase_formed_but_not_held_is_printed_and_fails(
    capsys: pytest.CaptureFixture[str]
) -> None:
    ok, loose = _phase("circle", True, 20, 19), _phase("line", True, 20, 8)
    assert ok.hold_text() == "held 19/20" and loose.hold_text() == "NOT held (8/20)"
    res = RunResult([ok, loose], "done", 200, 3.0, None)
    assert res.all_formed and not res.all_held and res.hold_steps == 20
    print_result(res, False)
    out = capsys.readouterr().out
    assert "circle     formed       57 steps, held 19/20 (lower bound 40)" in out
    assert "line       formed       57 steps, NOT held (8/20) (lower bound 40)" in out
    d = result_dict(res)
    assert d["all_formed"] and not d["all_held"]
    assert [(p["held_steps"], p["held"]) for p in d["phases"]] == [(19, True), (8, False)]
    table = format_table([ok, loose, _phase("heart", False, 20, 0)]).splitlines()
    assert table[0].split()[:5] == ["pattern", "brain", "formed", "held", "steps"]
    assert "yes 19/20" in table[2] and "NO 8/20" in table[3]
    assert table[4].split()[2:4] == ["NO", "-"]


def test_without_hold_steps_nothing_about_holding_is_printed(
    capsys: pytest.CaptureFixture[str]
) -> None:
    p = _phase("circle", True, 0, 0)
    assert p.held and p.hold_text() == ""
    res = RunResult([p], "done", 57, 1.0, None)
    assert res.all_held == res.all_formed is True and res.hold_steps == 0
    print_result(res, False)
    assert "held" not in capsys.readouterr().out
    assert "held" not in format_table([p])


# ------------------------------------------------------------------ a log with a hold window

SWARM = "holdlog"
OFF = [0.3] * 5 + [0.0] + [0.0, 0.0, 0.1, 0.1, 0.0, 0.0, 0.1, 0.1, 0.0, 0.0]
"""Robot 0's offset from its slot per step (metres): formed first at step 5, then watched
10 steps, formed after 6 of them."""


def _write_held_log(path: Path) -> None:
    line = make_pattern("line", 3)
    t0 = time.time_ns()
    with Recorder(path) as rec:
        def ev(kind: str, step: int, **kw: Any) -> None:
            rec.event(kind, step, step * W.dt_s, **kw)

        ev("run_start", 0, swarm=SWARM, robots=3, patterns=["line"], mode="lockstep",
           world=asdict(W))
        for r in range(3):
            ev("join", 0, robot=r)
        rec.write_wire(keys.pattern_key(SWARM), encode_pattern(
            PatternMsg(1, "line", line, W.formed_tol_m)), t0)
        ev("pattern", 0, version=1, name="line", n=3, reason="phase", points=line.tolist(),
           formed_tol_m=W.formed_tol_m)
        ev("phase_start", 0, phase=0, pattern="line", n=3)
        for step, off in enumerate(OFF):
            pos = line + np.array([3.0, 3.0])
            pos[0, 1] += off
            for r, (x, y) in enumerate(pos.tolist()):
                rec.write_wire(keys.pose_key(SWARM, r), encode_pose(
                    Pose(r, step, step * W.dt_s, x, y, 0.0, 0.0, 3)), t0 + step * 10**8 + r)
        end = len(OFF) - 1
        ev("phase_end", end, index=0, pattern="line", formed=True, steps=5, start_step=0,
           end_step=end, hold_steps=10, held_steps=6, held=False)
        ev("run_end", end, outcome="done", steps=end)


def test_the_report_recomputes_the_held_share(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "held.mcap"
    _write_held_log(log)
    (ph,) = report_log(log).phases
    assert ph.formed and ph.steps == 5 and ph.end_step == 15
    assert (ph.hold_steps, ph.held_steps, ph.held) == (10, 6, False)
    assert ph.mismatches == []
    assert main(["replay", str(log)]) == 0
    out = capsys.readouterr().out.splitlines()
    header = next(line for line in out if line.startswith("#  pattern"))
    assert header.split()[:6] == ["#", "pattern", "n", "formed", "held", "steps"]
    row = next(line for line in out if line.startswith("0  line"))
    assert row.split()[3:7] == ["yes", "NO", "6/10", "5"]
