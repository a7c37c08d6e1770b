"""What a robot hears of its team: poses in from Zenoh callbacks, one step at a time out.

* **lockstep**: step t is ready as soon as the inbox holds the poses of step t
  of all ``Pose.n_live`` live robots (this robot's included), or once
  ``lockstep_deadline_s`` has passed since the first pose of step t (then with
  the freshest poses; peers older than ``stale_s`` are absent).
* **realtime**: a step is ready every ``1 / rate_hz`` seconds, with the latest
  poses; peers whose pose is older than ``stale_s`` are absent.

No step is ready without a fresh pose of this robot. A pose of this robot
whose step goes back means the world restarted: steps count again from there.

**All poses of a step in one message** (:class:`runtime.wire.messages.PoseBatch` on
``patternrl/<swarm>/poses``, what the simulated world sends): the step is ready
as soon as its message arrives, in both modes -- it holds every live robot, so
there is nothing to wait for, and deciding at once leaves the command the most
time to reach the world before the step's deadline. Only the newest step is
kept: a robot that fell behind decides on the newest poses and never on a
step the world has already left (a command for an old step would be discarded
by the world anyway: see :mod:`sim_bridge.world.world_link`). The per-robot pose keys
(a real swarm's localisation, replayed logs, tools) work as described above
until the first all-poses message comes; from then on those messages alone
make the steps.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np

from runtime.log import Log
from runtime.types import Array
from runtime.wire import keys
from runtime.wire.messages import MessageError, Pose, decode_pose
from runtime.wire.pose_batch import decode_positions

__all__ = ["MAX_COORD_M", "PoseInbox", "Step"]

MAX_COORD_M: Final = 1e6  # a pose farther from the origin is malformed (and would overflow costs)
ARRIVALS_KEPT: Final = 16  # arrival times of the last all-poses messages (runtime.robot.in_flight)


@dataclass(frozen=True)
class Step:
    """One step to decide: the live robots' ids (ascending) and positions."""

    step: int
    ids: list[int]
    positions: Array
    """(len(ids), 2) metres, rows in the order of ``ids`` (may be a read-only view)."""


class PoseInbox:
    """The poses of one swarm as one robot sees them, and when a step is ready.

    :meth:`take` runs on Zenoh threads; everything else on the robot's loop.
    ``cond`` is the condition the loop sleeps on: poses wake it, and so may
    others (the swap worker) by notifying it.
    """

    def __init__(
        self,
        robot_id: int,
        swarm: str,
        *,
        realtime: bool,
        rate_hz: float,
        lockstep_deadline_s: float,
        stale_s: float,
        log: Log,
        drop: Callable[[str, str], None],
        on_restart: Callable[[], None] | None = None,
        decide_on_own_pose: bool = False,
    ) -> None:
        """``drop(what, why)`` counts a malformed pose; ``on_restart()`` runs (on the
        loop's thread) when the world restarted. ``decide_on_own_pose`` (realtime): a new
        pose of this robot makes a step ready at once, not at the next tick (a robot whose
        own pose comes from its localisation decides at that pose's rate)."""
        self.id = robot_id
        self.swarm = swarm
        self.realtime = realtime
        self.period_s = 1.0 / rate_hz
        self.deadline_s = lockstep_deadline_s
        self.stale_s = stale_s
        self._log = log
        self._drop = drop
        self._on_restart = on_restart
        self._own_ticks = realtime and decide_on_own_pose
        self.cond = threading.Condition(threading.Lock())
        # written by callbacks, under cond
        self._poses: dict[int, tuple[Pose, float]] = {}  # robot -> (pose, monotonic s received)
        self._last_pose_t: float | None = None
        self._col_step = -1  # the newest step seen, collected in _col_ids since _col_t0
        self._col_ids: set[int] = set()
        self._col_t0 = 0.0
        self._col_n_live = 0
        self._restart = False
        self._batch: Step | None = None  # the newest all-poses message holding this robot
        self._batch_step = -1  # its step (any batch, ours or not)
        self._arrived: dict[int, float] = {}  # step -> when its batch came (the last few)
        self.batches = 0
        """All-poses messages taken (for status and tests)."""
        self.per_robot = True
        """Steps may be made of per-robot poses (before any all-poses message); False while
        the robot listens to its own pose only (:meth:`runtime.robot.robot.Robot.start`),
        until :meth:`listen_per_robot`."""
        # the loop's, under cond
        self._last_decided = -1
        self._next_tick = time.monotonic()

    # -------------------------------------------------------------- Zenoh side

    def take(self, key: str, payload: bytes) -> None:
        """A pose sample: stored, or dropped (counted) when malformed."""
        try:
            pose = decode_pose(payload)
        except MessageError as e:
            self._drop("pose", str(e))
            return
        k = keys.parse_key(key)
        if k is None or k.kind != keys.POSE or k.robot_id != pose.robot_id:
            self._drop("pose", f"robot_id {pose.robot_id} on key {key}")
            return
        if pose.n_live < 1:
            self._drop("pose", f"n_live {pose.n_live}")
            return
        if max(abs(pose.x), abs(pose.y)) > MAX_COORD_M:
            self._drop("pose", f"position ({pose.x:g}, {pose.y:g}) beyond {MAX_COORD_M:g} m")
            return
        rid = pose.robot_id
        now = time.monotonic()
        with self.cond:
            self._poses[rid] = (pose, now)
            self._last_pose_t = now
            s = pose.step
            if s > self._col_step:
                self._col_step, self._col_ids, self._col_t0 = s, {rid}, now
            elif s == self._col_step:
                self._col_ids.add(rid)
            elif rid == self.id:  # our own step went back: the world restarted
                self._col_step, self._col_ids, self._col_t0 = s, {rid}, now
                self._restart = True
            if s == self._col_step:
                self._col_n_live = pose.n_live
                if self.id in self._col_ids and len(self._col_ids) >= pose.n_live:
                    self.cond.notify()
            if self._own_ticks and rid == self.id:
                self._next_tick = now  # decide on this pose now
                self.cond.notify()

    def listen_per_robot(self) -> None:
        """Every robot's per-robot pose is listened to from now on: steps are made of them,
        from the next step on (the one heard meanwhile lacks the poses sent before)."""
        with self.cond:
            self.per_robot = True
            self._last_decided = max(self._last_decided, self._col_step)

    def take_batch(self, payload: bytes, notify: bool = True) -> bool:
        """An all-poses sample: kept as the step to decide, or dropped (counted) when malformed.

        Returns True when it made a new step of this robot ready; ``notify`` False leaves
        waking the loop to the caller (:meth:`wake`), which may decide the step itself
        (:meth:`take_ready`)."""
        try:  # only what the robot uses: step, ids, positions (the same checks)
            s, ids, xy = decode_positions(payload, MAX_COORD_M)
        except MessageError as e:
            self._drop("poses", str(e))
            return False
        mine = self.id in ids
        now = time.monotonic()
        with self.cond:
            self._last_pose_t = now
            self.batches += 1
            if s <= self._batch_step:
                if not (mine and s < self._batch_step):
                    return False  # a duplicate or out of order: the newer one is kept
                self._restart = True  # our own step went back: the world restarted
                self._arrived.clear()
            self._batch_step = s
            self._arrived[s] = now
            if len(self._arrived) > ARRIVALS_KEPT:
                del self._arrived[min(self._arrived)]
            self._batch = Step(s, ids, xy) if mine else None
            if mine and notify:
                self.cond.notify()
        return mine

    def arrived(self, step: int) -> float | None:
        """When the all-poses message of ``step`` came (``time.monotonic()``; None if it has
        not, or long ago)."""
        with self.cond:
            return self._arrived.get(step)

    @property
    def newest_step(self) -> int:
        """The newest step of an all-poses message heard (-1 before the first)."""
        return self._batch_step

    def wake(self) -> None:
        """Wake the loop's wait in :meth:`next_step`."""
        with self.cond:
            self.cond.notify()

    def take_ready(self) -> Step | None:
        """The all-poses step ready now, marked decided (for a caller that decides it at
        once, off the loop); None when there is none or the world restarted (the loop
        handles a restart)."""
        with self.cond:
            if self._restart:
                return None
            step = self._ready_batch()
            if step is not None:
                self._last_decided = step.step
            return step

    # --------------------------------------------------------------- loop side

    def silence_s(self, now: float) -> float | None:
        """Seconds since the last pose of anyone; None before the first."""
        with self.cond:
            last = self._last_pose_t
        return None if last is None else now - last

    def next_step(
        self, now: float, wake_by: float, holding: bool, busy: Callable[[], bool]
    ) -> Step | None:
        """The step to decide now; else sleep until a step may be ready and return None.

        The sleep ends at ``wake_by`` (monotonic s) at the latest, at once when
        ``busy()`` (checked holding ``cond``). ``holding``: the robot does not
        act (watchdog): no step is ready, lockstep deadlines do not wake it.
        """
        with self.cond:
            if self._restart:
                self._restart = False
                self._last_decided = -1
                if self._on_restart is not None:
                    self._on_restart()
            step = None
            if not holding:
                step = self._ready_batch()
            if (step is None and not holding and self._batch_step < 0
                    and self.per_robot):  # per-robot poses only
                step = self._ready_realtime(now) if self.realtime else self._ready_lockstep(now)
            if step is not None:
                self._last_decided = step.step
                return step
            wake = wake_by
            if self._batch_step >= 0:
                pass  # batches wake the loop as they come: no tick, no deadline
            elif self.realtime:
                wake = min(wake, self._next_tick)
            elif self._col_step > self._last_decided and not holding:
                wake = min(wake, self._col_t0 + self.deadline_s)
            if not busy():
                self.cond.wait(max(0.0, wake - time.monotonic()))
            return None

    def _ready_batch(self) -> Step | None:
        b = self._batch
        if b is None or b.step <= self._last_decided:
            return None
        self._batch = None  # decided once
        return b

    def _team(self, now: float, step: int | None) -> tuple[list[int], Array] | None:
        """Ids and positions of the live robots (sorted by id); None without our own pose.

        With ``step``: the robots whose pose is of that step; else those whose
        pose is fresher than ``stale_s``.
        """
        ids: list[int] = []
        xy: list[tuple[float, float]] = []
        for rid in sorted(self._poses):
            pose, t = self._poses[rid]
            if step is not None:
                if pose.step != step:
                    continue
            elif now - t > self.stale_s:
                continue
            ids.append(rid)
            xy.append((pose.x, pose.y))
        if self.id not in ids:
            return None
        return ids, np.array(xy, dtype=np.float64)

    def _ready_lockstep(self, now: float) -> Step | None:
        s = self._col_step
        if s < 0 or s <= self._last_decided:
            return None
        complete = self.id in self._col_ids and len(self._col_ids) >= self._col_n_live
        if complete:
            team = self._team(now, s)
        elif now >= self._col_t0 + self.deadline_s:
            team = self._team(now, None)
            own = self._poses.get(self.id)
            if own is None or now - own[1] > self.stale_s:
                team = None
        else:
            return None
        if team is None:
            self._last_decided = s  # cannot act on this step without our own pose
            self._log("debug", "skip", f"step {s}: no fresh pose of this robot")
            return None
        return Step(s, team[0], team[1])

    def _ready_realtime(self, now: float) -> Step | None:
        if now < self._next_tick:
            return None
        self._next_tick += self.period_s
        if self._next_tick < now:
            self._next_tick = now + self.period_s
        team = self._team(now, None)
        if team is None:
            return None
        return Step(self._poses[self.id][0].step, team[0], team[1])
