"""The world's Zenoh plumbing: its declarations, and what their callbacks collect.

Every declaration lives in one :class:`contextlib.ExitStack`, entered by
:meth:`WorldLink.open` and undeclared in reverse order by :meth:`WorldLink.close`
(the per-robot pose publishers first, then the subscribers, the pattern's
queryable, the poses' and the pattern's publishers, the world's liveliness token
last). Callbacks run on
Zenoh's threads; what they share with the world's thread sits under one
:class:`threading.Condition` (:attr:`WorldLink.cond`), which the world's waits use:

* liveliness of the robots goes to the :class:`~sim_bridge.world.membership.Roster`;
* commands are kept for the step being collected (:meth:`WorldLink.exchange`);
* each robot's brain id, from its commands, statuses and accepted swaps;
* each robot's latest view (the team as it perceived it, under imperfect sensing);
* every sample under the swarm is written to the log as it came (``recorder``).

Poses go out as ONE :class:`~runtime.wire.messages.PoseBatch` per step on
``patternrl/<swarm>/poses`` (every robot receives one message a step, not one per
robot); the log holds them as per-robot poses (:mod:`sim_bridge.log.recorder`). Each
robot's own pose key is still published for whoever subscribes to it (tools, a
robot before its first all-poses message): a Zenoh matching listener per
publisher says who listens, so nobody listening costs nothing.

**A command is for the step it was computed from.** Robot i's command for step t
(the poses of t, which the world published) that arrived before step t's deadline
(lockstep: all in or ``deadline_s``; realtime: the step's tick) is applied at t,
*fresh* (age 0). A robot without one missed the step's deadline (counted as a
deadline miss; a command that arrives after its step's deadline as ``late``). With
``max_age_steps`` k > 0 (realtime's default, :data:`DEFAULT_MAX_AGE_STEPS`) such a
robot still moves on its newest command if that was decided from the poses of one of
the last k steps and has not been applied yet (*stale*, age t - s: a late command is
not thrown away, so a swarm whose round trip is longer than a period slows down
instead of standing still); otherwise it holds still. Each command moves its robot
for one step at most: applied twice, a command that brings its robot onto its slot
would carry it past (the robot's own account of its late commands,
:mod:`runtime.robot.in_flight`, follows the same rule). The age of every
applied command is returned (:class:`Collected`) and logged by the world; the world
guards stale motions (:mod:`sim_bridge.world.stale_guard`). With k = 0 (lockstep's
default) every velocity applied was decided from exactly the positions it is
applied to, as in a synchronous evaluation.

A sample that does not decode, or whose robot id disagrees with its key, is
dropped and counted (``malformed`` events, the first 100), never a crash.

``lockstep`` waits only for robots that speak: a robot from which no command
came in the last :data:`SILENT_STEPS` exchanges (a phantom that never answers,
a robot stuck) is not waited for; it holds still each step (counted as a
deadline miss) and is waited for again as soon as any command of it arrives.
When every robot is silent (the world cut off from its team), each step waits
its full deadline for all of them, so a cut link does not spend the step limit.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from typing import NamedTuple

import numpy as np
import zenoh

from runtime.decision.team_pattern import MAX_VERSION_STEP
from runtime.net.session import direct
from runtime.robot.in_flight import MAX_COMMAND_AGE_STEPS
from runtime.types import Array, IntArray
from runtime.wire import keys
from runtime.wire.messages import (
    Command,
    MessageError,
    Pose,
    PoseBatch,
    View,
    decode_command,
    decode_pattern,
    decode_status,
    decode_view,
    encode_pose,
    encode_poses,
)
from sim_bridge.log.budget import Budget, KeyBudget
from sim_bridge.log.recorder import Recorder
from sim_bridge.world.membership import Roster

MALFORMED_EVENTS = 100
"""Malformed samples logged one by one; enough to diagnose, the count goes on."""
SILENT_STEPS = 3
"""``lockstep``: a robot silent this many exchanges in a row is no longer waited for."""
DEFAULT_MAX_AGE_STEPS = MAX_COMMAND_AGE_STEPS
"""realtime: the oldest command (in steps since its poses) still applied, by default (the
robots' prediction of their own late motion, :mod:`runtime.robot.in_flight`, assumes it)."""


class Collected(NamedTuple):
    """The commands of one exchange, in the order of its ``ids``."""

    v: Array
    """(n, 2) velocities to apply (m/s); 0 for a robot that holds still."""
    missed: list[int]
    """Robots without a fresh command (none for the step before its deadline)."""
    age: IntArray
    """(n,) steps between the poses a command was decided from and this step: 0 fresh,
    1..max_age_steps stale, -1 none applied (the robot holds still)."""


class WorldLink:
    """The world's side of one swarm on an open Zenoh session."""

    def __init__(
        self,
        session: zenoh.Session,
        swarm: str,
        lockstep: bool,
        recorder: Recorder | None,
        event: Callable[..., None],
        max_age_steps: int = 0,
    ) -> None:
        self.session = session
        self.swarm = swarm
        self.lockstep = lockstep
        self.max_age_steps = int(max_age_steps)
        self.rec = recorder
        self._event = event
        self.malformed = 0
        self.budget = KeyBudget(self._over_budget)
        """What each key may cost per second (:mod:`sim_bridge.log.budget`); its drops."""
        self.latencies_ms: list[float] = []
        """Pose-to-command latency of every command that made its step."""
        self.decision_us: list[float] = []
        """Decision time as the robots report it, for benchmarks."""
        # --- shared with Zenoh callbacks, under self.cond
        self.cond = threading.Condition(threading.Lock())
        self.roster = Roster(self.cond)
        self.late = 0
        self._collect_step = -1
        self._wait_all = self.lockstep  # this exchange ends when every robot has answered
        self._expect: set[int] = set()
        self._cmds: dict[int, Command] = {}
        self._cmd_t: dict[int, float] = {}
        self._newest: dict[int, Command] = {}  # robot -> its command for the newest step
        self._applied: dict[int, int] = {}  # robot -> step of the last command applied
        self._last_step = -1  # the newest step whose poses went out
        self._brain_of: dict[int, str] = {}
        self._views: dict[int, View] = {}  # robot -> its latest view
        self._exchanges = 0  # exchanges begun
        self._spoke_at: dict[int, int] = {}  # robot -> exchange of its last command (or join)
        # --- the world's thread
        self._stack: ExitStack | None = None
        self._pattern_pub: zenoh.Publisher | None = None
        self._poses_pub: zenoh.Publisher | None = None
        self._pose_pubs: dict[int, tuple[zenoh.Publisher, zenoh.MatchingListener]] = {}
        self._listened: set[int] = set()  # robots whose pose key someone subscribes to
        self._prev_pos: dict[int, tuple[float, float]] = {}
        self._pattern_payload = b""
        self._own_version = 0  # the world's last pattern version
        self._operator_top = 0  # the highest operator pattern version since (0: none)
        self.pattern_sent_s = 0.0
        """``time.monotonic()`` of the last pattern put."""

    # ------------------------------------------------------------ lifetime

    def open(self) -> None:
        """Declare the world on the session; a second call does nothing."""
        if self._stack is not None:
            return
        s, sw = self.session, self.swarm
        with ExitStack() as stack:  # a declaration that fails undoes the ones before it
            stack.enter_context(s.liveliness().declare_token(keys.alive_key(sw, keys.WORLD_ID)))
            self._pattern_pub = stack.enter_context(
                s.declare_publisher(keys.pattern_key(sw), express=True))
            self._poses_pub = stack.enter_context(
                s.declare_publisher(keys.poses_key(sw), express=True))
            stack.enter_context(s.declare_subscriber(  # commands: on Zenoh's own thread
                keys.swarm_root(sw), direct(self._on_sample), allowed_origin=zenoh.Locality.REMOTE))
            if self.rec is not None:  # brains this session sends (swaps) are on the log too
                stack.enter_context(s.declare_subscriber(
                    keys.brain_key(sw), self._on_own_brain,
                    allowed_origin=zenoh.Locality.SESSION_LOCAL))
            stack.enter_context(s.declare_queryable(keys.pattern_key(sw), self._on_pattern_query))
            stack.enter_context(s.liveliness().declare_subscriber(
                keys.all_alive(sw), self._on_alive, history=True))
            stack.callback(self._undeclare_poses)  # last in, so the first undeclared
            self._stack = stack.pop_all()

    def close(self) -> None:
        """Undeclare everything, in reverse order; a second call does nothing."""
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()

    def __enter__(self) -> WorldLink:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def wake(self) -> None:
        """Wake every wait on :attr:`cond` (a stop was asked for)."""
        with self.cond:
            self.cond.notify_all()

    # ------------------------------------------------------------ callbacks

    def _on_alive(self, sample: zenoh.Sample) -> None:
        k = keys.parse_key(str(sample.key_expr))
        if k is None or k.robot_id is None:  # not a robot's token (the world's own, ...)
            return
        self.roster.saw(k.robot_id, joined=sample.kind == zenoh.SampleKind.PUT)

    def _on_own_brain(self, sample: zenoh.Sample) -> None:
        if self.rec is not None:
            self.rec.write_wire(str(sample.key_expr), sample.payload.to_bytes())

    def _on_pattern_query(self, query: zenoh.Query) -> None:
        payload = self._pattern_payload
        if payload:
            try:
                query.reply(keys.pattern_key(self.swarm), payload)
            except zenoh.ZError:  # the querier went away
                pass

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        if not self.budget.allow(key, len(payload)):  # a flood: not handled, not logged
            return
        if self.rec is not None:
            self.rec.write_wire(key, payload)
        k = keys.parse_key(key)
        if k is not None and k.kind == keys.OPERATOR_PATTERN:
            self._on_operator_pattern(key, payload)
            return
        if k is None or k.robot_id is None:
            return
        if k.kind == keys.CMD:
            self._on_cmd(key, k.robot_id, payload)
        elif k.kind == keys.STATUS:
            try:
                st = decode_status(payload)
            except MessageError as e:
                self._malformed(key, str(e))
                return
            if st.robot_id != k.robot_id:
                self._malformed(key, f"robot_id {st.robot_id} on key {key}")
                return
            self.roster.heard(k.robot_id)
            with self.cond:
                self._brain_of[st.robot_id] = st.brain_id
        elif k.kind == keys.VIEW:
            self._on_view(key, k.robot_id, payload)

    def _on_view(self, key: str, rid: int, payload: bytes) -> None:
        try:
            view = decode_view(payload)
        except MessageError as e:
            self._malformed(key, str(e))
            return
        if view.robot_id != rid:
            self._malformed(key, f"robot_id {view.robot_id} on key {key}")
            return
        with self.cond:
            old = self._views.get(rid)
            if old is None or view.step >= old.step:
                self._views[rid] = view

    def views(self) -> dict[int, View]:
        """Each robot's latest view (robots under imperfect sensing only)."""
        with self.cond:
            return dict(self._views)

    def _over_budget(self, key: str, budget: Budget) -> None:
        self._event("over_budget", key=key, messages_per_s=budget.messages,
                    bytes_per_s=budget.bytes)

    def _malformed(self, key: str, why: str) -> None:
        self.malformed += 1
        if self.malformed <= MALFORMED_EVENTS:
            self._event("malformed", key=key, reason=why[:200])

    def _on_cmd(self, key: str, rid: int, payload: bytes) -> None:
        now = time.monotonic()
        try:
            cmd = decode_command(payload)
        except MessageError as e:
            self._malformed(key, str(e))
            return
        if rid != cmd.robot_id:
            self._malformed(key, f"robot_id {cmd.robot_id} on key {key}")
            return
        self.roster.heard(rid)
        with self.cond:
            self._spoke_at[rid] = self._exchanges
            self._brain_of[rid] = cmd.brain_id
            newest = self._newest.get(rid)
            if cmd.step <= self._last_step and (newest is None or cmd.step > newest.step):
                self._newest[rid] = cmd
            if cmd.step == self._collect_step and rid in self._expect:
                if rid not in self._cmds:
                    self._cmds[rid] = cmd
                    self._cmd_t[rid] = now
                    self.decision_us.append(cmd.decision_us)
                    if self._wait_all and self._all_in():
                        self.cond.notify_all()
            elif cmd.step < self._collect_step or (
                    self._collect_step < 0 and cmd.step <= self._last_step):  # too late: unused
                self.late += 1

    def _all_in(self) -> bool:
        """Every expected robot still alive has answered (caller holds :attr:`cond`)."""
        return self._expect - self.roster.gone <= self._cmds.keys()

    # ------------------------------------------------------------ brains

    def brains(self) -> dict[int, str]:
        """Each robot's brain id, as it last said."""
        with self.cond:
            return dict(self._brain_of)

    def set_brain(self, rid: int, brain_id: str) -> None:
        with self.cond:
            self._brain_of[rid] = brain_id

    # ------------------------------------------------------------ pattern

    def _on_operator_pattern(self, key: str, payload: bytes) -> None:
        try:
            v = decode_pattern(payload).version
        except MessageError as e:
            self._malformed(key, str(e))
            return
        with self.cond:  # what robots may take: at most MAX_VERSION_STEP past the world's
            if self._own_version < v < self._own_version + MAX_VERSION_STEP:
                self._operator_top = max(self._operator_top, v)

    def next_pattern_version(self) -> int:
        """The version of the world's next pattern: above its last and above every operator
        pattern robots may hold, at most ``MAX_VERSION_STEP`` past its last (why:
        :mod:`runtime.decision.team_pattern`)."""
        with self.cond:
            self._own_version = max(self._own_version, self._operator_top) + 1
            self._operator_top = 0
            return self._own_version

    def put_pattern(self, payload: bytes | None = None) -> None:
        """Publish the pattern (a new one, or the current one again) and log it."""
        assert self._pattern_pub is not None, "open() first"
        if payload is not None:
            self._pattern_payload = payload  # what queries get from now on
        self._pattern_pub.put(self._pattern_payload)
        if self.rec is not None:
            self.rec.write_wire(keys.pattern_key(self.swarm), self._pattern_payload)
        self.pattern_sent_s = time.monotonic()

    # ------------------------------------------------------------ poses

    def add_robot(self, rid: int, x: float, y: float) -> None:
        """A robot placed at (x, y) metres: in the poses from the next step on."""
        pub = self.session.declare_publisher(keys.pose_key(self.swarm, rid), express=False)

        def matching(status: zenoh.MatchingStatus) -> None:
            if status.matching:
                self._listened.add(rid)
            else:
                self._listened.discard(rid)

        self._pose_pubs[rid] = (pub, pub.declare_matching_listener(matching))
        self._prev_pos[rid] = (x, y)
        with self.cond:  # a robot that joins is waited for, until it proves silent
            self._spoke_at[rid] = self._exchanges

    def remove_robot(self, rid: int) -> None:
        pub = self._pose_pubs.pop(rid, None)
        if pub is not None:
            pub[1].undeclare()  # type: ignore[no-untyped-call]
            pub[0].undeclare()  # type: ignore[no-untyped-call]
        self._listened.discard(rid)
        self._prev_pos.pop(rid, None)
        with self.cond:
            self._newest.pop(rid, None)
            self._views.pop(rid, None)
        self._applied.pop(rid, None)

    def _undeclare_poses(self) -> None:
        for rid in list(self._pose_pubs):
            self.remove_robot(rid)

    def moved(self, ids: list[int], pos: Array) -> None:
        """Where the robots were at the step just published: velocities are measured from it."""
        self._prev_pos = {rid: (float(x), float(y)) for rid, (x, y) in zip(ids, pos, strict=True)}

    def publish_poses(self, step: int, dt_s: float, ids: list[int], pos: Array) -> None:
        """Every robot's pose at ``step`` in one message; ``pos`` (n, 2) metres in ``ids``
        order (ascending ids)."""
        assert self._poses_pub is not None, "open() first"
        pos = np.asarray(pos, dtype=np.float64).reshape(-1, 2)
        prev = np.array([self._prev_pos.get(rid, (x, y))
                         for rid, (x, y) in zip(ids, pos.tolist(), strict=True)]).reshape(-1, 2)
        batch = PoseBatch(step, step * dt_s, ids, pos, (pos - prev) / dt_s)
        payload = encode_poses(batch)
        with self.cond:
            self._last_step = max(self._last_step, step)
        self._poses_pub.put(payload)
        if self.rec is not None:  # logged once, as per-robot poses
            self.rec.write_wire(keys.poses_key(self.swarm), payload)
        listened = self._listened
        if listened:  # the per-robot keys, only where someone listens
            n, t = len(ids), batch.time_s
            for k, rid in enumerate(ids):
                pub = self._pose_pubs.get(rid)
                if rid in listened and pub is not None:
                    (x, y), (vx, vy) = batch.xy[k].tolist(), batch.v[k].tolist()
                    pub[0].put(encode_pose(Pose(rid, step, t, x, y, vx, vy, n)))

    def publish_final(self, step: int, dt_s: float, ids: list[int], pos: Array) -> None:
        """The last poses of a run: published, logged, no command awaited."""
        with self.cond:
            self._collect_step = -1
        self.publish_poses(step, dt_s, ids, pos)

    # ------------------------------------------------------------ one exchange

    def exchange(
        self, step: int, dt_s: float, ids: list[int], pos: Array, deadline_s: float,
        stop: threading.Event, wait_all: bool = False,
        meanwhile: Callable[[], None] | None = None,
    ) -> Collected:
        """Publish the poses of ``step``, collect its commands.

        Waits until every live robot answered (``lockstep``, or ``wait_all``) or
        ``deadline_s`` seconds passed (``realtime``: otherwise always the full
        ``deadline_s``, the time to the step's tick). ``meanwhile``: the world's own work,
        done once the poses are out (the commands are collected all the same). Returns the
        velocities to apply in ``ids`` order, the robots without a fresh command and each
        command's age (:class:`Collected`).
        """
        with self.cond:
            self._exchanges += 1
            self._collect_step = step
            self._wait_all = self.lockstep or wait_all
            n = self._exchanges
            self._expect = {r for r in ids
                            if n - self._spoke_at.get(r, -SILENT_STEPS) <= SILENT_STEPS}
            if not self._expect:  # the whole team silent (a link cut): wait the full deadline,
                self._expect = set(ids)  # do not race to the step limit with nobody listening
            self._cmds = {}
            self._cmd_t = {}
        t0 = time.monotonic()
        self.publish_poses(step, dt_s, ids, pos)
        if meanwhile is not None:
            meanwhile()
        deadline = t0 + deadline_s
        with self.cond:
            while not stop.is_set():
                if self._wait_all and self._all_in():
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self.cond.wait(left)
            cmds = dict(self._cmds)
            arrived = dict(self._cmd_t)
            newest = {r: self._newest[r] for r in ids if r not in cmds and r in self._newest}
            self._collect_step = -1
        self.latencies_ms.extend((t - t0) * 1000.0 for t in arrived.values())
        return self._velocities(step, ids, cmds, newest)

    def _velocities(self, step: int, ids: list[int], cmds: dict[int, Command],
                    newest: dict[int, Command]) -> Collected:
        v = np.zeros((len(ids), 2))
        age = np.full(len(ids), -1, np.int64)
        missed: list[int] = []
        for k, rid in enumerate(ids):
            cmd = cmds.get(rid)
            if cmd is not None:
                age[k] = 0
            else:
                missed.append(rid)
                cmd = newest.get(rid)
                if (cmd is None or not 0 < step - cmd.step <= self.max_age_steps
                        or cmd.step <= self._applied.get(rid, -1)):
                    continue  # none, too old or applied already: the robot holds still
                age[k] = step - cmd.step
            self._applied[rid] = cmd.step
            v[k] = (cmd.vx, cmd.vy)
        return Collected(v, missed, age)
