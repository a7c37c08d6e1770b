"""A swarm's keys grow linearly with the team: a robot's access rules name the roles only,
the world's name every robot; a team beyond the largest is refused at once, in one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from support import ROOT

from runtime.net.identity import access_control
from sim_bridge.launch.swarm_keys import MAX_ROBOTS, create_swarm_keys


def _size(d: Path, name: str) -> int:
    return (d / name / "zenoh.json5").stat().st_size


def test_a_robots_rules_do_not_grow_with_the_team_the_worlds_grow_linearly(
        tmp_path: Path) -> None:
    small = create_swarm_keys(tmp_path / "s", "grow", 4).out
    large = create_swarm_keys(tmp_path / "l", "grow", 40).out
    sizes = [_size(small, "robot-0"), _size(large, "robot-0"), _size(large, "robot-39")]
    assert max(sizes) - min(sizes) < 64 and max(sizes) < 4000, sizes  # paths aside, equal
    for role in ("world", "operator", "router"):  # they take what robots publish
        per_robot = (_size(large, role) - _size(small, role)) / 36
        assert 300 < per_robot < 1000, (role, per_robot)
    robot_acl = json.loads((large / "robot-3" / "zenoh.json5").read_text())["access_control"]
    assert not [s for s in robot_acl["subjects"] if s["id"].startswith("robot-")]
    world_acl = json.loads((large / "world" / "zenoh.json5").read_text())["access_control"]
    assert world_acl == access_control("grow", 40)
    assert len([s for s in world_acl["subjects"] if s["id"].startswith("robot-")]) == 40


@pytest.mark.parametrize("argv", [
    ["keys", "create", "--swarm", "big", "--robots", str(MAX_ROBOTS + 1), "--out", "{tmp}/k"],
    ["launch", "--robots", "5000", "--swarm", "big", "--no-plot", "--record", "{tmp}/r.mcap"],
    ["sim", "--robots", "5000", "--swarm", "big", "--insecure"],
])
def test_a_team_beyond_the_largest_is_refused_at_once(tmp_path: Path, argv: list[str]) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "patternrl.cli",
                        *(a.replace("{tmp}", str(tmp_path)) for a in argv)],
                       capture_output=True, text=True, timeout=60, env=env, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{MAX_ROBOTS}" in lines[0], r.stderr
    assert not list(tmp_path.iterdir())  # refused before any key or file was made
