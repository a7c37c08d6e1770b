"""End to end: the world watches a formed pattern ``--hold-steps`` more steps and says whether
it held.

Real ``patternrl sim`` and ``patternrl robot --brain rule:assign`` processes over loopback
Zenoh in lockstep, perfect conditions, judged from their JSON result and the MCAP log they
leave (the first passage recomputed here from the recorded poses); the same seed without
``--hold-steps`` gives the first pattern's figures unchanged; ``patternrl launch`` shows the
held column.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support import ROOT, free_port, stop_processes

from runtime.decision.formation import assign_slots, slot_distances
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.reader import LogData, read_log
from sim_bridge.log.report import report_log

TOL = DEFAULT_WORLD.formed_tol_m
HOLD = 5
ROBOTS = 4
pytestmark = pytest.mark.timeout(240)


@dataclass
class Run:
    code: int
    result: dict[str, Any]
    output: str
    """The world's stdout and stderr."""
    log: Path


def _sim_run(tmp: Path, tag: str, *extra: str) -> Run:
    """One lockstep run of the world and its robots, to the end."""
    swarm, port, log = f"hold-{tag}-{os.getpid()}", free_port(), tmp / f"{tag}.mcap"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("PATTERNRL_ZENOH_PORT", None)
    cli = [sys.executable, "-m", "patternrl.cli"]
    net = ["--swarm", swarm, "--zenoh-port", str(port), "--insecure"]
    procs: list[subprocess.Popen[Any]] = []
    try:
        # a long step deadline: every robot answers every step, so a seed plays the same way
        world = subprocess.Popen(
            [*cli, "sim", *net, "--robots", str(ROBOTS), "--patterns", "circle,line",
             "--seed", "1", "--step-deadline-ms", "5000", "--record", str(log), "--json",
             "--wait-robots-s", "90", *extra],
            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(world)
        procs += [subprocess.Popen(
            [*cli, "robot", *net, "--id", str(i), "--brain", "rule:assign"],
            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for i in range(ROBOTS)]
        out, _ = world.communicate(timeout=180)
    finally:
        stop_processes(procs)
    lines = out.strip().splitlines()
    result = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {}
    return Run(world.returncode, result, out, log)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Run]:
    """The same seed played with ``--hold-steps 5`` and without."""
    tmp = tmp_path_factory.mktemp("hold")
    return {HOLD: _sim_run(tmp, "held", "--hold-steps", str(HOLD)), 0: _sim_run(tmp, "plain")}


def _farthest(run: LogData, step: int, pattern: np.ndarray) -> float:
    """Distance of the robot farthest from its slot at ``step``, from the recorded poses."""
    _, P = run.frames.at(step)
    return float(slot_distances(P, pattern, assign_slots(P, pattern)).max())


def _phase_patterns(run: LogData) -> list[np.ndarray]:
    return [np.asarray(e["points"]) for e in run.events_of("pattern") if e["reason"] == "phase"]


def test_a_formed_pattern_is_watched_and_held(runs: dict[int, Run]) -> None:
    held = runs[HOLD]
    assert held.code == 0, held.output[-3000:]
    res = held.result
    assert res["outcome"] == "done" and res["all_formed"] and res["all_held"]
    for p in res["phases"]:
        assert p["formed"] and p["held"], p
        assert (p["hold_steps"], p["held_steps"]) == (HOLD, HOLD)
        # the phase ran the first passage and the window; its steps are the first passage's
        assert p["end_step"] == p["start_step"] + p["steps"] + HOLD
        assert f"{p['pattern']}: formed in {p['steps']} steps, held {HOLD}/{HOLD}" in held.output

    run = read_log(held.log)
    assert run.recovery.finished
    ends = run.events_of("phase_end")
    assert len(ends) == len(res["phases"]) == 2
    for e, p, pattern in zip(ends, res["phases"], _phase_patterns(run), strict=True):
        for name in ("hold_steps", "held_steps", "held", "steps", "travel_m", "end_step"):
            assert e[name] == p[name], name
        # the first passage, from the poses: formed at start + steps, not before
        first = e["start_step"] + e["steps"]
        assert _farthest(run, first, pattern) <= TOL
        for s in range(e["start_step"], first):
            assert _farthest(run, s, pattern) > TOL, s
        # and still formed at every step of the window
        for s in range(first + 1, e["end_step"] + 1):
            assert _farthest(run, s, pattern) <= TOL, s
    # the log's report recomputes the same, held share included
    rep = report_log(held.log)
    for ph in rep.phases:
        assert ph.mismatches == [] and ph.formed and ph.held
        assert (ph.hold_steps, ph.held_steps) == (HOLD, HOLD)


def test_without_hold_steps_the_phase_ends_at_the_first_passage(runs: dict[int, Run]) -> None:
    plain, held = runs[0], runs[HOLD]
    assert plain.code == 0, plain.output[-3000:]
    assert plain.result["all_formed"] and plain.result["all_held"]
    for p in plain.result["phases"]:
        assert (p["hold_steps"], p["held_steps"], p["held"]) == (0, 0, True)
        assert p["end_step"] == p["start_step"] + p["steps"]
    assert " held " not in plain.output and "NOT held" not in plain.output
    # the same seed: the first pattern's first passage is the same, watched or not
    a, b = plain.result["phases"][0], held.result["phases"][0]
    for name in ("steps", "travel_m", "final_error_m", "lower_bound_steps", "start_step"):
        assert a[name] == b[name], name
    # the log's report shows no held column without a window
    rep = report_log(plain.log)
    assert all(ph.held_steps is None and ph.mismatches == [] for ph in rep.phases)


def test_launch_reports_the_held_column(tmp_path: Path, procs: Any) -> None:
    log = tmp_path / "launch.mcap"
    launch = procs.start("launch", "launch", "--robots", "3", "--patterns", "circle",
                         "--record", str(log), "--seed", "2", "--brains", "rule:assign",
                         "--swarm", f"hold-launch-{os.getpid()}", "--hold-steps", "3",
                         "--no-plot")
    assert launch.wait(timeout=180) == 0, procs.log("launch")
    out = procs.log("launch")
    assert "every pattern formed and held" in out
    header = next(line for line in out.splitlines() if line.startswith("pattern "))
    assert header.split()[:5] == ["pattern", "brain", "formed", "held", "steps"]
    assert "yes 3/3" in out
    (end,) = read_log(log).events_of("phase_end")
    assert (end["hold_steps"], end["held_steps"], end["held"]) == (3, 3, True)
