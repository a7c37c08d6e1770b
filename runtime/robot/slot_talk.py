"""A robot process's side of the slot agreement over Zenoh: :class:`SlotTalk`.

``patternrl robot --agree slots`` under imperfect sensing tells its team, each step it
decides, the slot it goes by (a :class:`runtime.wire.messages.Slots` on
``robot/<id>/slots``; the team's leader, its lowest id, its whole assignment and under noise
its plan's frame too) and hears theirs (``robot/*/slots``). ``--agree frame``, the default,
under noise: only the leader tells (its assignment and frame), and every robot hears its
frame. What it hears goes through the same :class:`Hearing` as the robots of
``patternrl eval --agree`` (:mod:`runtime.decision.agreement`): the message told at step
``t - max(1, latency_steps)`` is heard at step ``t``, each lost with the simulated
conditions' chance, the last heard kept; a message that comes later than that over the
network is not heard at all. Only messages for the pattern the robot holds (its version)
and from its team of the step count; the leader's assignment only over the very same team.

Bounded before use: a payload decodes (:func:`runtime.wire.messages.decode_slots`: sizes,
values, meaning) and its sender is the robot of its key, or it is dropped and counted; at
most :data:`KEEP_STEPS` steps are kept per sender and :data:`MAX_SENDERS` senders, so no
peer can grow what a robot holds.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Final

import numpy as np

from runtime.conditions import Conditions
from runtime.decision.agreement import Heard, Hearing
from runtime.types import Array, IntArray
from runtime.wire import keys
from runtime.wire.messages import NO_SLOT, MessageError, Slots, decode_slots

__all__ = ["KEEP_STEPS", "MAX_SENDERS", "SlotTalk"]

KEEP_STEPS: Final = 8
"""Steps kept per sender past the newest: enough for the heard step (``latency_steps``,
within 20, lies behind the newest by at most the sender's lead, a step or two in lockstep)."""
MAX_SENDERS: Final = 4096
"""Senders kept at most (as many robots as a pose batch carries)."""


class SlotTalk:
    """What one robot tells and hears of its team's slots (see the module docstring).

    :meth:`take` runs on Zenoh's thread; :meth:`heard` and :meth:`told` on the decision's.
    """

    def __init__(self, robot_id: int, conditions: Conditions, seed: Sequence[int],
                 drop: Callable[[str, str], None], slots: bool = True) -> None:
        """``slots``: every robot tells its slot and hears its peers' claims and the leader's
        assignment (``--agree slots``); else only the leader tells, and only its frame is
        heard (``--agree frame``)."""
        self.robot_id = robot_id
        self.slots = slots
        self.conditions = conditions
        self.delay = max(1, conditions.latency_steps)
        self._seed = tuple(seed)
        self._drop = drop
        self._lock = threading.Lock()
        self._got: dict[int, dict[int, Slots]] = {}  # sender -> step -> its message
        self._team: tuple[int, ...] = ()
        self._version = -1  # the pattern version heard for
        self._hearing: Hearing | None = None
        self.heard_messages = 0
        """Messages from the team for the pattern held, found for the step each decision
        hears (before the simulated loss): the robot's exit line says it."""
        self.adopted_steps = 0
        """Steps the robot went by its leader's assignment (counted by the robot)."""
        self.frame_steps = 0
        """Steps the robot's plan went in its leader's frame, as heard (counted by the
        robot)."""

    def take(self, key: str, payload: bytes) -> None:
        """A payload on ``key`` (one robot's slots key): decoded, bounded and kept."""
        k = keys.parse_key(key)
        if k is None or k.robot_id is None or k.kind != keys.SLOTS:
            self._drop("slots", f"not a slots key: {key}")
            return
        if k.robot_id == self.robot_id:
            return  # its own
        try:
            msg = decode_slots(payload)
        except MessageError as e:
            self._drop("slots", str(e))
            return
        if msg.robot_id != k.robot_id:
            self._drop("slots", f"robot_id {msg.robot_id} on key {key}")
            return
        with self._lock:
            mine = self._got.get(msg.robot_id)
            if mine is None:
                if len(self._got) >= MAX_SENDERS:
                    self._drop("slots", f"more than {MAX_SENDERS} senders")
                    return
                mine = self._got[msg.robot_id] = {}
            mine[msg.step] = msg
            if len(mine) > KEEP_STEPS:
                newest = max(mine)
                for s in [s for s in mine if s <= newest - KEEP_STEPS or s > newest]:
                    del mine[s]

    def heard(self, step: int, ids: Sequence[int], me: int, version: int) -> Heard:
        """What the robot (row ``me`` of the team ``ids``, ascending) has heard at ``step``
        of its team's slots for the pattern of ``version``."""
        team = tuple(int(i) for i in ids)
        n = len(team)
        if team != self._team or version != self._version or self._hearing is None:
            # another team or pattern: nothing heard of it yet (the last pattern's frame and
            # claims mean nothing for this one)
            self._team, self._version = team, version
            self._hearing = Hearing(self.conditions, 1, n, seed=(*self._seed, n, version))
        src = step - self.delay
        claims = np.full((1, n), -1, dtype=np.int64)
        leader = np.full((1, n), -1, dtype=np.int64)
        frame = np.full((1, 2), np.nan)
        with self._lock:
            for k, rid in enumerate(team):
                msg = self._got.get(rid, {}).get(src)
                if msg is None or msg.pattern_version != version:
                    continue
                self.heard_messages += 1
                if self.slots and msg.slot != NO_SLOT and msg.slot < n:
                    claims[0, k] = msg.slot
                if k == 0 and msg.ids.shape[0] == n and tuple(msg.ids.tolist()) == team:
                    if self.slots:
                        leader[0] = msg.assignment
                    if msg.frame is not None:
                        frame[0] = msg.frame
        self._hearing.tell(src, claims, leader, frame)
        self._hearing.hear(step)
        return self._hearing.heard(me)

    def told(self, step: int, version: int, ids: Sequence[int], me: int,
             slots: IntArray | None, frame: Array | None = None) -> Slots | None:
        """The message the robot sends for its decision of ``step``: its slot (``slots``
        None or -1: none), and from the leader (row 0) the whole assignment and its plan's
        ``frame`` (2,) m (None: none). Telling only the frame, the leader's message where it
        has a frame, and None (nothing to send) from the others."""
        told = None if frame is None or not np.isfinite(frame).all() else (
            float(frame[0]), float(frame[1]))
        if not self.slots and (me != 0 or told is None):
            return None
        if slots is None or len(slots) != len(ids) or int(slots[me]) < 0:
            return None if not self.slots else Slots(self.robot_id, step, version, NO_SLOT)
        if me == 0:
            return Slots(self.robot_id, step, version, int(slots[0]), np.asarray(ids),
                         np.asarray(slots), told)
        return Slots(self.robot_id, step, version, int(slots[me]))
