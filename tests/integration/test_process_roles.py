"""Every process refuses, at start, an identity of another role: one line, exit 2.

Real processes: ``patternrl sim``, ``router``, ``robot``, ``swap`` and ``record``
given a real identity of the swarm that is not theirs stop before they speak.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from support import free_port

from sim_bridge.launch.swarm_keys import create_swarm_keys

SWARM = "roles"
ROOT = Path(__file__).resolve().parents[2]
BRAIN = ROOT / "exports" / "general.onnx"
pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def swarm_keys(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("keys") / SWARM
    create_swarm_keys(out, SWARM, 3)
    return out


CASES = [
    (["sim", "--robots", "3", "--max-steps", "1"], "robot-1", "cannot act as the world"),
    (["sim", "--robots", "3", "--max-steps", "1"], "operator", "cannot act as the world"),
    (["router"], "robot-1", "cannot act as the router"),
    (["router"], "world", "cannot act as the router"),
    (["robot", "--id", "1", "--brain", str(BRAIN)], "world", "cannot speak for robot 1"),
    (["robot", "--id", "1", "--brain", str(BRAIN)], "robot-2", "cannot speak for robot 1"),
    (["swap", "--brain", str(BRAIN), "--timeout-s", "1", "--discover-s", "1"], "robot-1",
     "cannot act as an operator's tool"),
    (["swap", "--brain", str(BRAIN), "--timeout-s", "1", "--discover-s", "1"], "world",
     "cannot act as an operator's tool"),
    (["record", "--duration-s", "1"], "robot-1", "cannot act as an operator's tool"),
]


@pytest.mark.parametrize("argv, name, match", CASES,
                         ids=[f"{c[0][0]}-as-{c[1]}" for c in CASES])
def test_a_process_refuses_another_roles_identity(swarm_keys: Path, tmp_path: Path,
                                                  argv: list[str], name: str,
                                                  match: str) -> None:
    if argv[0] == "record":
        argv = [*argv, "--out", str(tmp_path / "r.mcap")]
    cmd = [sys.executable, "-m", "patternrl.cli", *argv, "--swarm", SWARM,
           "--zenoh-port", str(free_port()), "--identity", str(swarm_keys / name)]
    # a process that (wrongly) started would run on: the timeout only ends such a run
    try:
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"{argv[0]} started with {name}'s identity: {e.stdout!r}")
    lines = r.stderr.splitlines()
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert len(lines) == 1 and match in lines[0], r.stderr
    assert lines[0].startswith(f"patternrl {argv[0]}: error: identity {name}"), lines[0]
    assert "ready" not in r.stdout, r.stdout
