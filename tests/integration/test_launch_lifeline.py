"""A launcher killed with SIGKILL takes its robots, its router and its keys with it; a robot
that never hears its world leaves on its own."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from sim_bridge.launch.launch import ROBOT_SILENCE_EXIT_S, free_port

ROOT = Path(__file__).resolve().parents[2]
GONE_WITHIN_S = 0.75 * ROBOT_SILENCE_EXIT_S
"""Sooner than a robot's own silence exit: the launcher's death, not the robot, ends it."""
KEYS_LINE = re.compile(r"operator identity (\S+)/operator")


def _processes_naming(word: str) -> dict[int, str]:
    found = {}
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            args = (Path("/proc") / pid / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if word in args:
            found[int(pid)] = args
    return found


def _wait(cond: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.1)
    return cond()


@pytest.fixture
def swarm(request: pytest.FixtureRequest) -> Iterator[str]:
    """A swarm name of this test only; whatever still names it at the end is the test's."""
    name = f"lifeline{os.getpid()}{request.node.name[-12:].replace('_', '')}"
    try:
        yield name
    finally:
        for pid in _processes_naming(name):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _kill_launcher_once_up(tmp_path: Path, swarm: str, *extra: str,
                           router: bool = False) -> Path:
    """Start a 4-robot launch, SIGKILL it once its robots run; the run's keys directory."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    err_path = tmp_path / "launch.err"
    with open(err_path, "wb") as err:
        p = subprocess.Popen(
            [sys.executable, "-m", "patternrl.cli", "launch", "--robots", "4", "--mode",
             "realtime", "--rate-hz", "0.5", "--swarm", swarm, "--no-plot",
             "--record", str(tmp_path / "run.mcap"),
             "--zenoh-port", str(free_port()), *extra],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT,
            env=dict(os.environ, TMPDIR=str(tmp)), start_new_session=True)
    try:
        def up() -> bool:
            procs = _processes_naming(swarm).values()
            robots = sum("patternrl.cli robot " in a for a in procs)
            routers = sum("patternrl.cli router " in a for a in procs)
            return robots == 4 and routers == int(router)

        assert _wait(up, 60.0), (_processes_naming(swarm), err_path.read_text())
        m = KEYS_LINE.search(err_path.read_text())
        assert m is not None, err_path.read_text()
        keys = Path(m.group(1))
        assert keys.is_dir() and keys.parent == tmp, keys
    finally:
        p.kill()
        p.wait()
    return keys


def _assert_all_gone(swarm: str, keys: Path) -> None:
    gone = _wait(lambda: not _processes_naming(swarm) and not keys.exists(), GONE_WITHIN_S)
    assert _processes_naming(swarm) == {}, "left behind after the launcher's SIGKILL"
    assert not keys.exists(), f"the run's keys stayed: {sorted(keys.iterdir())}"
    assert gone


def test_a_killed_launcher_takes_its_robots_and_keys(tmp_path: Path, swarm: str) -> None:
    keys = _kill_launcher_once_up(tmp_path, swarm)
    _assert_all_gone(swarm, keys)


def test_a_killed_launcher_takes_its_router(tmp_path: Path, swarm: str) -> None:
    keys = _kill_launcher_once_up(tmp_path, swarm, "--topology", "router", router=True)
    _assert_all_gone(swarm, keys)


def test_a_launch_with_the_users_keys_leaves_them(tmp_path: Path, swarm: str) -> None:
    tls = tmp_path / "keys"
    subprocess.run([sys.executable, "-m", "patternrl.cli", "keys", "create", "--swarm", swarm,
                    "--robots", "4", "--out", str(tls)], cwd=ROOT, check=True,
                   capture_output=True)
    before = sorted(p.relative_to(tls) for p in tls.rglob("*"))
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    with open(tmp_path / "launch.err", "wb") as err:
        p = subprocess.Popen(
            [sys.executable, "-m", "patternrl.cli", "launch", "--robots", "4", "--mode",
             "realtime", "--rate-hz", "0.5", "--swarm", swarm, "--no-plot",
             "--record", str(tmp_path / "run.mcap"),
             "--zenoh-port", str(free_port()), "--tls-dir", str(tls)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT,
            env=dict(os.environ, TMPDIR=str(tmp)), start_new_session=True)
    try:
        def up() -> bool:
            return sum("patternrl.cli robot " in a for a in _processes_naming(swarm).values()) == 4

        assert _wait(up, 60.0), (tmp_path / "launch.err").read_text()
    finally:
        p.kill()
        p.wait()
    assert _wait(lambda: not _processes_naming(swarm), GONE_WITHIN_S), _processes_naming(swarm)
    assert sorted(p.relative_to(tls) for p in tls.rglob("*")) == before
    assert list(tmp.glob("patternrl-keys-*")) == []  # the keys are the user's: none made


def test_a_robot_that_never_hears_its_world_leaves(swarm: str) -> None:
    p = subprocess.Popen(
        [sys.executable, "-m", "patternrl.cli", "robot", "--swarm", swarm, "--id", "0",
         "--brain", "rule:assign", "--insecure", "--zenoh-port", str(free_port()),
         "--world-timeout-s", "2"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        cwd=ROOT)
    try:
        _, err = p.communicate(timeout=GONE_WITHIN_S)
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        pytest.fail("a robot with no world did not leave on its own")
    assert p.returncode == 1, err
    lines = [ln for ln in err.splitlines() if "--world-timeout-s 2" in ln]
    assert len(lines) == 1, err
    assert "Traceback" not in err
