"""The world's side of the wire, over real Zenoh on loopback, and robot processes to drive.

``StubWorld`` plays the world's side of the wire contract (DESIGN.md section 3):
it listens on ``tcp/127.0.0.1:<free port>``, declares the world's liveliness
token, publishes every robot's pose per step with ``n_live``, the swarm's
pattern, and collects commands and statuses. ``RobotProc`` starts
``python -m patternrl.cli robot ...`` connected to it. Everything waits on
conditions with timeouts; nothing sleeps a fixed time.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from runtime.decision.patterns import make_pattern
from runtime.net.session import PORT_ENV, open_session
from runtime.wire import keys
from runtime.wire.messages import (
    Command,
    MessageError,
    PatternMsg,
    Pose,
    PoseBatch,
    Status,
    decode_command,
    decode_status,
    encode_pattern,
    encode_pose,
    encode_poses,
)
from runtime.world_config import DEFAULT_WORLD
from support import ROOT, free_port
from support.net import wait_notified

BLOCK = zenoh.CongestionControl.BLOCK
"""Every put waits for room in the session's queue. Zenoh's default drops a message that
finds the queue full, and one session putting a pose per robot in a burst (express: one
batch each) lost some on a busy machine, which a robot decided on a part of its team."""


TEAM_DEADLINE = ("--lockstep-deadline-s", "0.5")
"""For robots a test steps in lockstep: the stub world sends every pose of a step, and on a
busy machine the default deadline (20 ms) could pass before a robot's callbacks ran, which
then decided for a part of its team. Below the robots' watchdog (1 s), as it must be."""


class StubWorld:
    """The world's side of the protocol, driven step by step from a test."""

    def __init__(self, swarm: str, port: int | None = None) -> None:
        self.swarm = swarm
        self.port = port if port is not None else free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.session = open_session("peer", connect=[], listen=[self.endpoint])
        self.cond = threading.Condition()
        self.cmds: dict[int, dict[int, Command]] = defaultdict(dict)  # step -> robot -> cmd
        self.cmd_times: dict[tuple[int, int], float] = {}
        self.status: dict[int, list[Status]] = defaultdict(list)
        self.alive: set[int] = set()
        self.bad_cmds = 0
        self.pose_times: dict[int, float] = {}
        # declarations live until close(), undeclared in reverse order before the session closes
        self._decls = contextlib.ExitStack()
        self._decls.enter_context(self.session)
        for d in (
            self.session.declare_subscriber(keys.all_cmds(swarm), self._on_cmd),
            self.session.declare_subscriber(keys.all_status(swarm), self._on_status),
            self.session.liveliness().declare_subscriber(
                keys.all_alive(swarm), self._on_alive, history=True
            ),
            self.session.liveliness().declare_token(keys.alive_key(swarm, keys.WORLD_ID)),
        ):
            self._decls.enter_context(d)
        self._pubs: dict[int, Any] = {}
        self.pattern_version = 0
        self.batches = False
        """True: every pose of a step in one all-poses message, as ``patternrl sim`` sends."""

    # -- callbacks
    def _on_cmd(self, sample: zenoh.Sample) -> None:
        now = time.monotonic()
        try:
            c = decode_command(sample.payload.to_bytes())
        except MessageError:
            with self.cond:
                self.bad_cmds += 1
            return
        with self.cond:
            self.cmds[c.step][c.robot_id] = c
            self.cmd_times.setdefault((c.step, c.robot_id), now)
            self.cond.notify_all()

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            st = decode_status(sample.payload.to_bytes())
        except MessageError:
            return
        with self.cond:
            self.status[st.robot_id].append(st)
            self.cond.notify_all()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        key = keys.parse_key(str(sample.key_expr))
        rid = None if key is None else key.robot_id
        if rid is None:  # the world's own token, or not a key of ours
            return
        with self.cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(rid)
            else:
                self.alive.discard(rid)
            self.cond.notify_all()

    # -- publishing
    def publish_pattern(self, name: str, n: int) -> np.ndarray:
        pts = make_pattern(name, n)
        self.pattern_version += 1
        msg = PatternMsg(self.pattern_version, name, pts, DEFAULT_WORLD.formed_tol_m)
        self.session.put(keys.pattern_key(self.swarm), encode_pattern(msg),
                         congestion_control=BLOCK)
        return pts

    def publish_poses(self, step: int, pos: np.ndarray, ids: list[int] | None = None) -> None:
        ids = list(range(len(pos))) if ids is None else ids
        t = time.monotonic()
        with self.cond:
            self.pose_times[step] = t
        if self.batches:
            xy = np.asarray(pos, dtype=np.float64).reshape(-1, 2)
            batch = PoseBatch(step, t, np.array(ids, np.uint32), xy, np.zeros_like(xy))
            self.session.put(keys.poses_key(self.swarm), encode_poses(batch),
                             congestion_control=BLOCK)
            return
        for rid, (x, y) in zip(ids, pos.tolist(), strict=True):
            pub = self._pubs.get(rid)
            if pub is None:
                pub = self._pubs[rid] = self._decls.enter_context(
                    self.session.declare_publisher(
                        keys.pose_key(self.swarm, rid), express=True,
                        congestion_control=BLOCK,
                    )
                )
            pub.put(encode_pose(Pose(rid, step, t, x, y, 0.0, 0.0, len(ids))))

    def put_raw(self, key: str, payload: bytes) -> None:
        self.session.put(key, payload, congestion_control=BLOCK)

    # -- waiting
    def wait(self, pred: Callable[[], Any], timeout: float, what: str) -> Any:
        return wait_notified(self.cond, pred, timeout, what)

    def wait_alive(self, ids: set[int], timeout: float = 20.0) -> None:
        self.wait(lambda: ids <= self.alive, timeout, f"robots {sorted(ids)} alive")

    def wait_cmds(self, step: int, ids: list[int], timeout: float = 30.0) -> dict[int, Command]:
        self.wait(lambda: set(ids) <= set(self.cmds[step]), timeout, f"commands of step {step}")
        with self.cond:
            return dict(self.cmds[step])

    def wait_status(
        self, rid: int, pred: Callable[[Status], bool], timeout: float, what: str
    ) -> Status:
        def find() -> Status | None:
            for st in reversed(self.status[rid]):
                if pred(st):
                    return st
            return None

        st: Status = self.wait(find, timeout, what)
        return st

    def lockstep(
        self, pos: np.ndarray, step: int, ids: list[int] | None = None, timeout: float = 30.0
    ) -> tuple[np.ndarray, dict[int, Command]]:
        """Publish the poses of ``step``, wait for every command of it, move the robots."""
        ids = list(range(len(pos))) if ids is None else ids
        self.publish_poses(step, pos, ids)
        cmds = self.wait_cmds(step, ids, timeout)
        v = np.array([[cmds[i].vx, cmds[i].vy] for i in ids])
        return pos + DEFAULT_WORLD.dt_s * v, cmds

    def close(self) -> None:
        self._decls.close()


class RobotProc:
    """``python -m patternrl.cli robot ...`` as a child process."""

    def __init__(
        self,
        world: StubWorld,
        rid: int,
        brain: str,
        *extra: str,
        default_endpoints: bool = False,
    ) -> None:
        """``default_endpoints``: no --connect/--listen; find the world by its swarm's port."""
        self.rid = rid
        cmd = [
            sys.executable,
            "-m",
            "patternrl.cli",
            "robot",
            "--swarm",
            world.swarm,
            "--id",
            str(rid),
            "--brain",
            brain,
            "--insecure",
        ]
        if not default_endpoints:
            cmd += ["--connect", world.endpoint, "--listen", "tcp/127.0.0.1:0"]
        cmd += list(extra)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env.pop(PORT_ENV, None)
        if default_endpoints:
            env[PORT_ENV] = str(world.port)
        self.t_start = time.monotonic()
        self.proc = subprocess.Popen(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )

    def interrupt(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)

    def finish(self, timeout: float = 10.0) -> tuple[int, str, str]:
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
            raise AssertionError(f"robot {self.rid} did not exit in {timeout} s: {err}") from None
        return self.proc.returncode, out, err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()
