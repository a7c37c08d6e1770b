"""End to end: a world and robot processes over real Zenoh, checked through the MCAP log.

Each test starts real ``patternrl sim`` / ``patternrl robot`` / ``patternrl launch``
processes on loopback with a free port and its own swarm name, and judges the
result from the log they leave (formation error recomputed here from the
recorded poses, not taken from the world's own metrics).
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from runtime.decision.formation import assign_slots, formation_error, slot_distances
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.reader import LogData, read_log

TOL = DEFAULT_WORLD.formed_tol_m
pytestmark = pytest.mark.timeout(120)


def swarm_name(tag: str) -> str:
    return f"e2e-{tag}-{os.getpid()}"


def phase_end_errors(run: LogData) -> list[tuple[int, float, float]]:
    """(robots, formation error, farthest robot from its slot) at the end of each phase,
    from the poses on the log and the pattern in force (the last one published)."""
    out = []
    pattern = None
    for e in run.events:
        if e["kind"] == "pattern":
            pattern = np.asarray(e["points"])
        if e["kind"] != "phase_end":
            continue
        _, P = run.frames.at(e["end_step"])
        assert pattern is not None and len(pattern) == len(P)
        far = float(slot_distances(P, pattern, assign_slots(P, pattern)).max())
        out.append((len(P), formation_error(P, pattern), far))
    return out


def test_world_and_robots_form_two_patterns_in_lockstep(
    procs: Any, tmp_path: Path, kit: Any
) -> None:
    swarm, port, log = swarm_name("two"), kit.free_port(), tmp_path / "two.mcap"
    world = procs.world(swarm, port, "--robots", "5", "--patterns", "circle,line", "--seed", "3",
                        "--record", str(log), "--json", "--wait-robots-s", "60")
    robots = [procs.robot(swarm, port, i) for i in range(5)]
    assert world.wait(timeout=90) == 0, procs.log("world")
    for r in robots:  # the robots notice the world is gone and leave on their own
        assert r.wait(timeout=30) == 0
    result = json.loads(procs.log("world").strip().splitlines()[-1])
    assert result["all_formed"] and [p["pattern"] for p in result["phases"]] == ["circle", "line"]

    run = read_log(log)
    assert run.recovery.finished and run.malformed == 0
    assert len(run.events_of("join")) == 5
    ends = run.events_of("phase_end")
    assert [e["formed"] for e in ends] == [True, True]
    for n, err, far in phase_end_errors(run):
        assert n == 5 and err <= TOL and far <= TOL, (err, far)
    # lockstep: every step has every robot's pose, and the robots answered the steps
    last = ends[-1]["end_step"]
    assert run.frames.steps.tolist() == list(range(last + 1))
    assert run.frames.present.sum(axis=1).tolist() == [5] * (last + 1)
    misses = sum(e["deadline_misses"] for e in ends)
    assert len(run.commands.step) >= 5 * last - misses
    assert run.topics["/world/scene"] == run.topics["/world/metrics"] == last
    assert run.events_of("run_end")[0]["outcome"] == "done"


def test_robot_killed_mid_run_others_reform(procs: Any, tmp_path: Path, kit: Any) -> None:
    swarm, port, log = swarm_name("kill"), kit.free_port(), tmp_path / "kill.mcap"
    world = procs.world(swarm, port, "--robots", "5", "--patterns", "circle,line", "--seed", "5",
                        "--record", str(log), "--wait-robots-s", "60")
    watcher = kit.Watcher(swarm, port)  # on the swarm before the first step
    kit.wait_for(lambda: "world" in watcher.alive, 30, "the watcher to see the world")
    robots = [procs.robot(swarm, port, i) for i in range(5)]
    try:
        kit.wait_for(lambda: watcher.step() >= 8, 60, "the world to run 8 steps")
        robots[2].send_signal(signal.SIGKILL)
        assert world.wait(timeout=90) == 0, procs.log("world")
    finally:
        watcher.close()
    run = read_log(log)
    (leave,) = run.events_of("leave")
    assert leave["robot"] == 2 and leave["n_live"] == 4
    resized = [e for e in run.events_of("pattern") if e["reason"] == "resize"]
    assert resized and resized[0]["n"] == 4 and resized[0]["step"] >= leave["step"]
    ends = run.events_of("phase_end")
    assert [e["formed"] for e in ends] == [True, True]
    assert ends[0]["leaves"] == 1 and ends[0]["n_robots"] == 4 and ends[1]["n_robots"] == 4
    assert leave["step"] < ends[0]["end_step"]  # killed mid-phase
    for n, err, far in phase_end_errors(run):
        assert n == 4 and err <= TOL and far <= TOL
    after = run.frames.steps > leave["step"]
    assert after.any() and not run.frames.present[after][:, run.frames.ids == 2].any()


def test_world_killed_robots_hold_still_and_exit_log_readable(procs: Any, tmp_path: Path,
                                                              kit: Any) -> None:
    swarm, port, log = swarm_name("wkill"), kit.free_port(), tmp_path / "wkill.mcap"
    rt = ("--mode", "realtime", "--rate-hz", "20")
    world = procs.world(swarm, port, "--robots", "3", "--patterns", "circle,line,circle,line",
                        "--record", str(log), *rt)
    robots = [procs.robot(swarm, port, i, *rt, "--watchdog-s", "0.5") for i in range(3)]
    watcher = kit.Watcher(swarm, port)
    try:
        kit.wait_for(lambda: watcher.step() >= 15, 60, "the world to run 15 steps")
        world.send_signal(signal.SIGKILL)
        assert world.wait(timeout=10) == -signal.SIGKILL
        for r in robots:
            assert r.wait(timeout=30) == 0  # exit on their watchdog, not by our hand
        with watcher.lock:  # each robot's last word was "hold still"
            last = {rid: c[-1] for rid, c in watcher.cmds.items()}
    finally:
        watcher.close()
    assert set(last) == {0, 1, 2}
    assert all(c.vx == 0.0 and c.vy == 0.0 for c in last.values()), last
    for i in range(3):
        assert "watchdog" in procs.log(f"robot{i}")
    run = read_log(log)
    assert not run.recovery.finished  # cut short, read up to its last complete chunk
    steps = run.frames.steps.tolist()
    assert steps and steps == list(range(len(steps)))
    assert run.events_of("run_start") and len(run.events_of("join")) == 3
    assert not run.events_of("run_end")


def test_late_robot_is_counted_and_never_hangs(procs: Any, tmp_path: Path, kit: Any) -> None:
    swarm, port, log = swarm_name("late"), kit.free_port(), tmp_path / "late.mcap"
    world = procs.world(swarm, port, "--robots", "4", "--patterns", "circle", "--seed", "2",
                        "--record", str(log), "--step-deadline-ms", "100", "--wait-robots-s", "60")
    for i in range(3):
        procs.robot(swarm, port, i)
    fake = kit.FakeRobot(swarm, port, 3, late=lambda step: 5 <= step < 15, delay_s=0.25)
    try:
        assert world.wait(timeout=90) == 0, procs.log("world")
    finally:
        fake.close()
    run = read_log(log)
    (end,) = run.events_of("phase_end")
    assert end["formed"]
    late_steps = {e["for_step"] for e in run.events_of("deadline_miss") if 3 in e["robots"]}
    assert set(range(5, 15)) & late_steps, late_steps  # its late steps were misses
    assert end["deadline_misses"] >= 4
    assert end["late_commands"] >= 1  # the late answers arrived and were counted, not used
    assert fake.answered_late


def test_launch_forms_and_reports(tmp_path: Path, procs: Any, kit: Any) -> None:
    log = tmp_path / "runs" / "demo.mcap"
    launch = procs.start("launch", "launch", "--robots", "4", "--patterns", "circle,line",
                         "--record", str(log), "--seed", "1", "--swarm", swarm_name("launch"),
                             "--brains", "rule:assign")
    assert launch.wait(timeout=90) == 0, procs.log("launch")
    out = procs.log("launch")
    assert "circle" in out and "line" in out and "every pattern formed" in out
    assert "rule:assign" in out
    assert log.with_suffix(".png").stat().st_size > 10_000
    run = read_log(log)
    assert run.recovery.finished
    assert [e["formed"] for e in run.events_of("phase_end")] == [True, True]


def test_launch_without_a_log_reports_the_worlds_cpu(tmp_path: Path, procs: Any) -> None:
    from sim_bridge.world.sim_world import CPU_SECTIONS, phase_step_limit

    log = tmp_path / "unrecorded.mcap"
    launch = procs.start("launch", "launch", "--robots", "4", "--patterns", "circle",
                         "--record", str(log), "--no-record", "--seed", "2", "--json",
                         "--swarm", swarm_name("nolog"), "--brains", "rule:assign")
    assert launch.wait(timeout=90) == 0, procs.log("launch")
    res = json.loads(procs.log("launch").strip().splitlines()[-1])
    assert res["all_formed"] and res["record"] is None and res["figure"] is None
    assert not log.exists() and log.with_suffix(".robots.log").exists()
    (ph,) = res["phases"]
    assert ph["step_limit"] == phase_step_limit(ph["lower_bound_steps"])
    cpu = res["world_cpu"]
    assert cpu["steps"] == res["steps"] == ph["steps"] > 0
    split = cpu["stepping_cpu_split_s"]
    assert list(split) == list(CPU_SECTIONS) and min(split.values()) >= 0.0
    assert sum(split.values()) == pytest.approx(cpu["stepping_cpu_s"], abs=1e-3)
    assert split["physics"] > 0.0 and split["exchange"] > 0.0
    assert cpu["writer_cpu_s"] == 0.0  # no log: no writer
    assert cpu["process_cpu_s"] >= cpu["stepping_cpu_s"] > 0.0


def test_launch_ctrl_c_stops_every_child(tmp_path: Path, procs: Any, kit: Any) -> None:
    log = tmp_path / "int.mcap"
    swarm, port = swarm_name("int"), kit.free_port()
    launch = procs.start("launch", "launch", "--robots", "3", "--patterns",
                         "circle,line,circle,line", "--mode", "realtime", "--rate-hz", "20",
                         "--record", str(log), "--swarm", swarm, "--zenoh-port", str(port),
                         "--insecure")  # the watcher joins on open TCP
    watcher = kit.Watcher(swarm, port)
    try:
        kit.wait_for(lambda: watcher.step() >= 5, 60, "the launched world to run 5 steps")
        kids = kit.children_of(launch.pid)
        assert len(kids) == 4  # 3 robots and the lifeline's reaper
        launch.send_signal(signal.SIGINT)  # what Ctrl-C delivers to the launcher
        assert launch.wait(timeout=30) == 130, procs.log("launch")
    finally:
        watcher.close()
    assert not [k for k in kids if kit.pid_alive(k)]  # no orphans
    run = read_log(log)
    assert run.recovery.finished  # the log was finished
    assert run.events_of("run_end")[0]["outcome"] == "interrupted"
    assert "interrupted" in procs.log("launch")


def test_brains_are_chosen_by_manifest(tmp_path: Path, kit: Any) -> None:
    from sim_bridge.world.brain_choice import choose_brains

    for name, obs, pattern, n in [("circle-10-paper", "paper", "circle", 10),
                                  ("line-10-paper", "paper", "line", 10),
                                  ("line-10-general", "general", "line", None),
                                  ("any-general", "general", None, None),
                                  ("heart-5-paper", "paper", "heart", 5)]:
        kit.write_test_brain(tmp_path, name, obs, pattern, n)
    pats = ["circle", "line", "heart", "cross"]
    paper, missing = choose_brains(tmp_path, pats, 10, prefer="paper")
    assert missing == []
    assert {p: Path(c.ref).stem for p, c in paper.items()} == {
        "circle": "circle-10-paper", "line": "line-10-paper",
        "heart": "any-general", "cross": "any-general"}  # heart's paper brain is for 5
    assert paper["circle"].kind == "paper" and len(paper["circle"].brain_id) == 64
    general, _ = choose_brains(tmp_path, pats, 10, prefer="general")
    assert Path(general["line"].ref).stem == "line-10-general"  # made for the pattern
    assert Path(general["circle"].ref).stem == "any-general"
    (tmp_path / "any-general.json").unlink()
    _, missing = choose_brains(tmp_path, pats, 10, prefer="paper")
    assert missing == ["heart", "cross"]


def test_world_swaps_the_patterns_brain_into_every_robot(procs: Any, tmp_path: Path,
                                                          kit: Any) -> None:
    swarm, port, log = swarm_name("swap"), kit.free_port(), tmp_path / "swap.mcap"
    wander = kit.write_test_brain(tmp_path, "wander")  # forms nothing
    world = procs.world(swarm, port, "--robots", "4", "--patterns", "circle,line", "--seed", "4",
                        "--record", str(log), "--brains", "rule:assign", "--wait-robots-s", "60")
    for i in range(4):
        procs.start(f"robot{i}", "robot", "--swarm", swarm, "--id", str(i), "--zenoh-port",
                    str(port), "--brain", str(wander))
    assert world.wait(timeout=90) == 0, procs.log("world")
    run = read_log(log)
    swaps = run.events_of("brain_swap")
    assert sorted(e["robot"] for e in swaps) == [0, 1, 2, 3]  # once: line keeps the brain
    assert all(e["accepted"] and e["brain"] == "rule:assign" for e in swaps)
    assert all(e["step"] == 0 and len(e["old_brain_id"]) == 64 for e in swaps)
    assert run.topics[f"patternrl/{swarm}/brain"] >= 1  # the swap itself is on the log
    ends = run.events_of("phase_end")
    assert [e["formed"] for e in ends] == [True, True]
    assert all(e["brain_ids"] == ["rule:assign"] for e in ends)


def test_robot_joins_mid_run_is_placed_and_the_pattern_grows(procs: Any, tmp_path: Path,
                                                              kit: Any) -> None:
    swarm, port, log = swarm_name("join"), kit.free_port(), tmp_path / "join.mcap"
    rt = ("--mode", "realtime", "--rate-hz", "20")
    world = procs.world(swarm, port, "--robots", "3", "--patterns", "circle,line", "--seed", "6",
                        "--record", str(log), "--wait-robots-s", "60", *rt)
    watcher = kit.Watcher(swarm, port)
    try:
        kit.wait_for(lambda: "world" in watcher.alive, 30, "the watcher to see the world")
        for i in range(3):
            procs.robot(swarm, port, i, *rt)
        kit.wait_for(lambda: watcher.step() >= 5, 60, "the world to run 5 steps")
        procs.robot(swarm, port, 3, *rt)
        assert world.wait(timeout=90) == 0, procs.log("world")
    finally:
        watcher.close()
    run = read_log(log)
    joins = run.events_of("join")
    assert [e["robot"] for e in joins] == [0, 1, 2, 3]
    late = joins[-1]
    assert late["step"] > 0 and late["n_live"] == 4
    resized = [e for e in run.events_of("pattern") if e["reason"] == "resize"]
    assert resized and resized[0]["n"] == 4
    ends = run.events_of("phase_end")
    assert [e["formed"] for e in ends] == [True, True]
    assert ends[-1]["n_robots"] == 4 and sum(e["joins"] for e in ends) == 1
    for n, err, far in phase_end_errors(run)[-1:]:
        assert n == 4 and err <= TOL and far <= TOL
