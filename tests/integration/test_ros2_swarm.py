"""A real swarm with no simulator: two ROS 2 bases (a plain rclpy node turning each one's
``cmd_vel`` into its ``odom``), a ``patternrl robot --ros2`` process for each, and
``patternrl coordinate`` publishing the patterns, judging formed and recording."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from support import ROOT
from support.ros2_fleet import DiffDriveFleet, ros2_isolated
from support.stub_world import RobotProc, StubWorld

from runtime.decision.formation import formation_error
from runtime.decision.patterns import make_pattern
from sim_bridge.log.reader import read_log


def test_coordinator_forms_a_ros2_swarm_and_records_it(
    world: StubWorld, robots: list[RobotProc], tmp_path: Path
) -> None:
    ros2_isolated()
    fleet = DiffDriveFleet({"robot_0": (0.0, 0.0, 0.0), "robot_1": (0.9, 0.7, 1.0)})
    log = tmp_path / "field.mcap"
    try:
        co = subprocess.Popen(
            [sys.executable, "-m", "patternrl.cli", "coordinate", "--swarm", world.swarm,
             "--robots", "2", "--patterns", "line,circle", "--record", str(log), "--json",
             "--phase-timeout-s", "40", "-e", world.endpoint, "-l", "tcp/127.0.0.1:0",
             "--insecure"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        robots += [RobotProc(world, i, "rule:assign", "--ros2", f"robot_{i}") for i in (0, 1)]
        try:
            out, err = co.communicate(timeout=90)
        finally:
            if co.poll() is None:
                co.kill()
                co.communicate()
        assert co.returncode == 0, err[-3000:]
        res = json.loads(out.strip().splitlines()[-1])
        assert [(p["pattern"], p["formed"], p["n_robots"]) for p in res["phases"]] == [
            ("line", True, 2), ("circle", True, 2)]
        with fleet.lock:  # the bases themselves stand in the last pattern
            P = np.array([[b.x, b.y] for b in fleet.bases.values()])
        assert formation_error(P, make_pattern("circle", 2)) < 0.1
    finally:
        fleet.close()
    data = read_log(log)  # the recorded swarm reads like a world's log
    assert list(data.frames.ids) == [0, 1] and len(data.frames.steps) > 5
    assert [e["formed"] for e in data.events_of("phase_end")] == [True, True]
    assert not data.skipped, data.skipped
    r = subprocess.run([sys.executable, "-m", "patternrl.cli", "replay", str(log), "--json"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert [p["formed"] for p in rep["phases"]] == [True, True], rep["phases"]
