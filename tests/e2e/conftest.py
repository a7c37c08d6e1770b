"""Real processes over real Zenoh on loopback: worlds, robots, a watcher and a fake robot.

Every process is started in its own session and stopped by PID at teardown;
every wait is on a condition with a timeout (no fixed sleeps).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from runtime.brain.brain import RuleBrain
from runtime.decision.controller import Controller
from runtime.net.session import open_session
from runtime.wire import keys
from runtime.wire.messages import (
    Command,
    MessageError,
    PatternMsg,
    Pose,
    Status,
    decode_command,
    decode_pattern,
    decode_pose,
    encode_command,
    encode_status,
)
from sim_bridge.world.sim_world import SimConfig

ROOT = Path(__file__).resolve().parents[2]
OPEN_COMMANDS = ("sim", "robot", "swap")
"""Started with --insecure: the watchers here join on open TCP (launch keeps its own TLS)."""


# re-exported: tests import these from conftest
from support import ROBOT_SILENCE_EXIT_S, stop_processes  # noqa: E402
from support import free_port as free_port  # noqa: E402
from support import wait_for as wait_for  # noqa: E402
from support.brains import write_test_brain  # noqa: E402

assert float(ROBOT_SILENCE_EXIT_S) > SimConfig.first_step_deadline_ms / 1000.0


def pid_alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False


def children_of(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux /proc)."""
    out: list[int] = []
    try:
        for tid in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                out += [int(x) for x in f.read().split()]
    except FileNotFoundError:
        pass
    return out


class Procs:
    """Processes of one test; all stopped (by PID) at teardown."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[subprocess.Popen[bytes]] = []

    def start(self, name: str, *argv: str) -> subprocess.Popen[bytes]:
        log = open(self.tmp / f"{name}.log", "wb")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        if argv and argv[0] in OPEN_COMMANDS:  # these tests run open on loopback
            argv = (argv[0], "--insecure", *argv[1:])
        p = subprocess.Popen([sys.executable, "-m", "patternrl.cli", *argv], cwd=ROOT,
                             stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                             start_new_session=True, env=env)
        log.close()
        self.procs.append(p)
        return p

    def world(self, swarm: str, port: int, *argv: str) -> subprocess.Popen[bytes]:
        return self.start("world", "sim", "--swarm", swarm, "--zenoh-port", str(port), *argv)

    def robot(self, swarm: str, port: int, rid: int, *argv: str) -> subprocess.Popen[bytes]:
        return self.start(f"robot{rid}", "robot", "--swarm", swarm, "--id", str(rid),
                          "--zenoh-port", str(port), "--brain", "rule:assign",
                          "--exit-after-silence-s", ROBOT_SILENCE_EXIT_S, *argv)

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text(errors="replace")

    def stop_all(self) -> None:
        stop_processes(self.procs)


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Procs]:
    ps = Procs(tmp_path)
    try:
        yield ps
    finally:
        ps.stop_all()


class Watcher:
    """A Zenoh peer of the swarm in the test process: sees poses, commands, liveliness."""

    def __init__(self, swarm: str, port: int) -> None:
        self.swarm = swarm
        self.session = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"],
                                    listen=["tcp/127.0.0.1:0"])
        self.lock = threading.Lock()
        self.max_step = -1
        self.cmds: dict[int, list[Command]] = {}
        self.cmd_wall: dict[int, float] = {}
        self.alive: set[str] = set()
        self._decls = [
            self.session.declare_subscriber(keys.all_poses(swarm), self._on_pose),
            self.session.declare_subscriber(keys.all_cmds(swarm), self._on_cmd),
            self.session.liveliness().declare_subscriber(keys.all_alive(swarm), self._on_alive,
                                                          history=True),
        ]

    def _on_pose(self, s: zenoh.Sample) -> None:
        try:
            p = decode_pose(s.payload.to_bytes())
        except MessageError:
            return
        with self.lock:
            self.max_step = max(self.max_step, p.step)

    def _on_cmd(self, s: zenoh.Sample) -> None:
        try:
            c = decode_command(s.payload.to_bytes())
        except MessageError:
            return
        with self.lock:
            self.cmds.setdefault(c.robot_id, []).append(c)
            self.cmd_wall[c.robot_id] = time.monotonic()

    def _on_alive(self, s: zenoh.Sample) -> None:
        key = str(s.key_expr).rsplit("/", 1)[-1]
        with self.lock:
            if s.kind == zenoh.SampleKind.PUT:
                self.alive.add(key)
            else:
                self.alive.discard(key)

    def step(self) -> int:
        with self.lock:
            return self.max_step

    def close(self) -> None:
        for d in self._decls:
            d.undeclare()
        self.session.close()


STATUS_EVERY_S = 1.0
"""How often a :class:`FakeRobot` tells its status, as a robot process does."""


class FakeRobot:
    """A robot in the test process: decides with ``rule:assign`` like a real one, and
    answers late on purpose for the steps ``late(step)`` names (by ``delay_s``). Like a real
    robot it tells its status as it starts and about once a second: a world that hears
    nothing from a token for 3 s takes it for a phantom, which on a loaded machine, where the
    robot processes beside it take longer than that to start, left it out of the run."""

    def __init__(self, swarm: str, port: int, rid: int, late: Callable[[int], bool],
                 delay_s: float) -> None:
        self.swarm, self.id = swarm, rid
        self.late, self.delay_s = late, delay_s
        self.session = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"],
                                    listen=["tcp/127.0.0.1:0"])
        self.controller = Controller(RuleBrain())
        self.cond = threading.Condition()
        self.poses: dict[int, dict[int, Pose]] = {}
        self.pattern: PatternMsg | None = None
        self.stop = threading.Event()
        self.answered_late: list[int] = []
        self.pub = self.session.declare_publisher(keys.cmd_key(swarm, rid))
        self.status_pub = self.session.declare_publisher(keys.status_key(swarm, rid))
        self.started = time.monotonic()
        self._told = -1.0
        self._decls: list[Any] = [
            self.pub,
            self.status_pub,
            self.session.declare_subscriber(keys.all_poses(swarm), self._on_pose),
            self.session.declare_subscriber(keys.pattern_key(swarm), self._on_pattern),
            self.session.liveliness().declare_token(keys.alive_key(swarm, rid)),
        ]
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _on_pose(self, s: zenoh.Sample) -> None:
        p = decode_pose(s.payload.to_bytes())
        with self.cond:
            self.poses.setdefault(p.step, {})[p.robot_id] = p
            self.cond.notify_all()

    def _on_pattern(self, s: zenoh.Sample) -> None:
        with self.cond:
            self.pattern = decode_pattern(s.payload.to_bytes())
            self.cond.notify_all()

    def _ready(self) -> tuple[int, dict[int, Pose]] | None:
        for step in sorted(self.poses, reverse=True):  # the newest complete step, as robots do
            got = self.poses[step]
            n_live = next(iter(got.values())).n_live
            if len(got) >= n_live and self.id in got and self.pattern is not None:
                return step, got
        return None

    def _tell_status(self) -> None:
        now = time.monotonic()
        if now - self._told < STATUS_EVERY_S:
            return
        self._told = now
        self.status_pub.put(encode_status(Status(
            robot_id=self.id, step=0, brain_id="rule:assign", decision_latency_us_p50=0.0,
            decision_latency_us_p99=0.0, loop_jitter_ms=0.0, messages_dropped=0, errors=0,
            safety_interventions=0, last_error="", uptime_s=now - self.started)))

    def _loop(self) -> None:
        while not self.stop.is_set():
            self._tell_status()
            with self.cond:
                ready = self.cond.wait_for(self._ready, timeout=0.1)
                if not ready:
                    continue
                step, got = ready
                self.poses = {s: v for s, v in self.poses.items() if s > step}
                pattern = self.pattern
            assert pattern is not None
            ids = sorted(got)
            pos = np.array([[got[r].x, got[r].y] for r in ids])
            if len(pattern.points) != len(ids):
                continue
            d = self.controller.decide(ids.index(self.id), pos, np.asarray(pattern.points), step)
            if self.late(step):
                self.stop.wait(self.delay_s)  # the fault under test: an answer after the deadline
                self.answered_late.append(step)
            cmd = Command(self.id, step, d.velocity[0], d.velocity[1], "rule:assign",
                          d.safety_changed, 0.0, d.decision_us)
            self.pub.put(encode_command(cmd))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5)
        for d in reversed(self._decls):
            d.undeclare()
        self.session.close()


class Kit:
    """The helpers above, for tests (conftest modules are not importable by name)."""

    free_port = staticmethod(free_port)
    wait_for = staticmethod(wait_for)
    pid_alive = staticmethod(pid_alive)
    children_of = staticmethod(children_of)
    Watcher = Watcher
    FakeRobot = FakeRobot
    # a small random linear brain: it passes the runtime's validation but forms nothing (for
    # tests of brain choice and swaps, not of formation)
    write_test_brain = staticmethod(partial(write_test_brain, hidden=(), out_std=0.1, gain=1.0))


@pytest.fixture
def kit() -> type[Kit]:
    return Kit
