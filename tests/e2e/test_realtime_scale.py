"""Realtime mode end to end: late commands never make the swarm unsafe, and many robots decide.

Real ``patternrl sim --mode realtime`` and ``patternrl robot`` processes on loopback;
every verdict comes from the MCAP log the world leaves. Nothing here is a timed budget:
slow robots are made slow on purpose (``--debug-delay-ms``), and the scale test counts
the steps for which a robot's command arrived at all, so a busy machine costs progress,
not the verdict.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.reader import LogData, read_log

pytestmark = pytest.mark.timeout(240)
W = DEFAULT_WORLD
GENERAL = str(Path(__file__).resolve().parents[2] / "exports" / "general.onnx")


def swarm_name(tag: str) -> str:
    return f"e2e-rt-{tag}-{os.getpid()}"


def min_separation_m(run: LogData) -> float:
    """The smallest centre distance of any two robots over every recorded step."""
    xy = run.frames.xy  # (S, m, 2), NaN where absent
    d = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)
    m = xy.shape[1]
    d[:, np.arange(m), np.arange(m)] = np.inf
    return float(np.nanmin(d))


def test_late_commands_never_collide(procs: Any, tmp_path: Path, kit: Any) -> None:
    """Robots that answer 0-130 ms late at 10 Hz (so a third or more of their commands
    miss their step): the world applies a late command a step or more later, guarded, or
    holds the robot still, and no two robots ever come closer than 2R."""
    n = 12
    swarm, port, log = swarm_name("late"), kit.free_port(), tmp_path / "late.mcap"
    world = procs.world(swarm, port, "--robots", str(n), "--patterns", "circle,line",
                        "--seed", "5", "--mode", "realtime", "--max-steps", "120",
                        "--record", str(log), "--json", "--wait-robots-s", "120")
    for i in range(n):
        procs.robot(swarm, port, i, "--brain", GENERAL, "--mode", "realtime",
                    "--debug-delay-ms", "130")
    assert world.wait(timeout=200) in (0, 1), procs.log("world")[-2000:]  # 1: not formed
    result = json.loads(procs.log("world").strip().splitlines()[-1])

    run = read_log(log)
    assert run.recovery.finished and run.malformed == 0
    ends = run.events_of("phase_end")
    assert len(ends) == 2
    steps = sum(e["steps"] for e in ends)
    misses = sum(e["deadline_misses"] for e in ends)
    assert misses >= 0.1 * n * steps, (misses, steps)  # the delay did make robots late
    assert sum(e["late_commands"] for e in ends) > 0
    assert run.events_of("collision") == []
    assert [e["collisions"] for e in ends] == [0, 0]
    assert min_separation_m(run) >= 2 * W.radius_m, min_separation_m(run)
    assert all(p["collisions"] == 0 for p in result["phases"])
    # late robots still moved: the swarm made progress (every robot travelled)
    first, last = run.frames.xy[0], run.frames.xy[-1]
    assert (np.linalg.norm(last - first, axis=1) > 0.05).all()


def test_slowed_robots_form_on_stale_commands(procs: Any, tmp_path: Path, kit: Any) -> None:
    """Robots whose every command goes out 0-250 ms late at 10 Hz (most are one to three
    steps old when they arrive): the world applies them, stale, within the default age bound;
    the swarm forms the circle with 0 collisions, and the log and its report tell each
    applied command's age."""
    from sim_bridge.log.report import analyse
    from sim_bridge.world.world_link import DEFAULT_MAX_AGE_STEPS

    n = 8
    swarm, port, log = swarm_name("stale"), kit.free_port(), tmp_path / "stale.mcap"
    world = procs.world(swarm, port, "--robots", str(n), "--patterns", "circle",
                        "--seed", "11", "--mode", "realtime", "--max-steps", "400",
                        "--min-rate-hz", "10",  # a fixed rate: the robots stay late
                        "--record", str(log), "--json", "--wait-robots-s", "120")
    for i in range(n):
        procs.robot(swarm, port, i, "--brain", GENERAL, "--mode", "realtime",
                    "--debug-delay-ms", "250")
    assert world.wait(timeout=200) == 0, procs.log("world")[-2000:]  # 0: formed
    (phase,) = json.loads(procs.log("world").strip().splitlines()[-1])["phases"]
    assert phase["formed"] and phase["collisions"] == 0

    run = read_log(log)
    assert run.recovery.finished and run.malformed == 0
    (end,) = run.events_of("phase_end")
    stale = run.events_of("stale_command")
    ages = [a for e in stale for a in e["ages"]]
    assert end["stale_commands"] == len(ages) >= 0.2 * n * end["steps"], (len(ages), end)
    assert max(ages) == end["command_age_max"] <= DEFAULT_MAX_AGE_STEPS
    assert min(ages) >= 1 and any(a >= 2 for a in ages)  # late by more than a step, applied
    assert run.events_of("collision") == [] and end["collisions"] == 0
    assert min_separation_m(run) >= 2 * W.radius_m - 1e-6, min_separation_m(run)
    (rep,) = analyse(run).phases  # the report recomputed from the log tells the same
    assert rep.formed and rep.collisions == 0 and rep.stale_commands == len(ages)
    assert sum(rep.command_ages.values()) == len(ages) and rep.guard_scaled == end["guard_scaled"]


@pytest.mark.parametrize("topology", ["peer", "router"])
def test_thirty_robot_processes_decide_in_realtime(procs: Any, tmp_path: Path, kit: Any,
                                                   topology: str) -> None:
    """30 robot processes and the world at 10 Hz: every robot's command arrived (at all,
    early or late) for >= 95 % of the steps it was in. ``router``: a ``patternrl router``
    process, the world and every robot its Zenoh clients (what launch runs above 20)."""
    n, steps = 30, 40
    swarm, port, log = swarm_name(f"thirty-{topology}"), kit.free_port(), tmp_path / "thirty.mcap"
    star: tuple[str, ...] = ()
    if topology == "router":
        procs.start("router", "router", "--insecure", "--swarm", swarm, "--zenoh-port", str(port))
        kit.wait_for(lambda: "router ready:" in procs.log("router"), 60, "the router")
        star = ("--zenoh-mode", "client")
    world = procs.world(swarm, port, "--robots", str(n), "--patterns", "circle",
                        "--seed", "1", "--mode", "realtime", "--max-steps", str(steps),
                        "--record", str(log), "--wait-robots-s", "150", *star)
    for i in range(n):
        procs.robot(swarm, port, i, "--mode", "realtime", *star)
    assert world.wait(timeout=220) in (0, 1), procs.log("world")[-2000:]  # 1: not formed

    run = read_log(log)
    assert run.recovery.finished and run.malformed == 0
    (end,) = run.events_of("phase_end")
    assert end["steps"] == steps or end["formed"]
    last = end["end_step"]
    f = run.frames
    assert f.ids.tolist() == list(range(n))
    decided: dict[int, set[int]] = {i: set() for i in range(n)}
    for rid, s in zip(run.commands.robot_id.tolist(), run.commands.step.tolist(), strict=True):
        if s < last:
            decided[rid].add(s)
    share = {}
    for col, rid in enumerate(f.ids.tolist()):
        present = {int(s) for s, p in zip(f.steps, f.present[:, col], strict=True)
                   if p and s < last}
        share[rid] = len(decided[rid] & present) / len(present)
    assert min(share.values()) >= 0.95, sorted(share.items(), key=lambda kv: kv[1])[:5]
    assert end["collisions"] == 0
