"""Robots joining and leaving the world.

Robots are followed by their liveliness tokens (``patternrl/<swarm>/alive/<id>``):
Zenoh's thread reports each token to the :class:`Roster`; the world's thread then
applies the changes between steps (:class:`Membership`): the robots alive at the
start take the seeded starts (uniform in the arena, pairwise
>= ``world.start_separation_m``) in id order; a robot that joins later is placed
at a free seeded spot, one that leaves is removed; both are logged (``join`` and
``leave`` events). The world then resizes the pattern to the live count.

Phantoms: once the run has started, a liveliness token alone does not make a
robot: it joins when its robot has spoken on its own keys (a status or a
command whose id matches its key; every robot publishes a status as it starts
and once a second). A token nobody speaks for within :data:`UNHEARD_S`
(``alive/77`` from a peer that is no robot) is ignored, counted and logged once
(``robot_ignored``); one that was let in while the world waited for its team
is taken out again. The world never waits for a robot that does not answer
(:data:`sim_bridge.world.world_link.SILENT_STEPS`).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Protocol

import numpy as np

from runtime.world_config import WorldConfig
from sim_bridge.world.physics import PhysicsError, PhysicsWorld, sample_starts

if TYPE_CHECKING:
    from sim_bridge.world.world_log import WorldLog

ROSTER_POLL_S = 0.2
"""Longest wait between checks of a stop while waiting for robots."""
UNHEARD_S = 3.0
"""A token without a word from its robot for this long is reported as ignored."""


class Roster:
    """Which robots are alive, as their tokens say; fed from Zenoh's threads.

    Shares ``cond`` with the command collection, whose wait stops expecting a
    robot once it is :attr:`gone`.
    """

    def __init__(self, cond: threading.Condition) -> None:
        self._cond = cond
        self.alive: set[int] = set()
        """Robots whose token is up (read under ``cond``)."""
        self.gone: set[int] = set()
        """Robots whose token went down and did not come back (read under ``cond``)."""
        self._changes: queue.SimpleQueue[tuple[bool, int]] = queue.SimpleQueue()
        self._tokens: dict[int, float] = {}  # token up -> monotonic s it came up
        self._heard: set[int] = set()  # robots that spoke on their own keys
        self._ignored: set[int] = set()  # tokens without a robot, counted once each
        self.ignored = 0
        """Tokens ignored: up for UNHEARD_S without a word from their robot."""
        self.started = False
        """Once the run started, a token joins only when its robot has spoken."""

    def saw(self, rid: int, joined: bool) -> None:
        """A robot's token came up (``joined``) or went down."""
        with self._cond:
            if joined:
                self._tokens.setdefault(rid, time.monotonic())
                if self.started and rid not in self._heard:
                    return  # admitted once it speaks (heard)
                self._admit(rid)
            else:
                self._tokens.pop(rid, None)
                if rid in self.alive or not self.started:
                    self.alive.discard(rid)
                    self.gone.add(rid)
                    self._changes.put((False, rid))
                    self._cond.notify_all()

    def heard(self, rid: int) -> None:
        """Robot ``rid`` spoke on its own keys (a status or command that decoded)."""
        with self._cond:
            if rid in self._heard:
                return
            self._heard.add(rid)
            if rid in self._tokens:
                self._admit(rid)

    def _admit(self, rid: int) -> None:  # holding cond
        if rid in self.alive:
            return
        self.alive.add(rid)
        self.gone.discard(rid)
        self._changes.put((True, rid))
        self._cond.notify_all()

    def unheard(self) -> list[int]:
        """Tokens up UNHEARD_S without a word from their robot, each counted once.

        One that was let in at the start is taken out (a leave).
        """
        now = time.monotonic()
        with self._cond:
            out = sorted(r for r, t in self._tokens.items()
                         if r not in self._heard and r not in self._ignored
                         and now - t > UNHEARD_S)
            for r in out:
                self._ignored.add(r)
                if r in self.alive:
                    self.alive.discard(r)
                    self.gone.add(r)
                    self._changes.put((False, r))
                    self._cond.notify_all()
            self.ignored += len(out)
        return out

    def wait_for(self, n: int, timeout_s: float, stop: threading.Event) -> int:
        """Wait until ``n`` robots are alive, ``timeout_s`` passed or ``stop``; how many are."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while len(self.alive) < n and not stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(min(left, ROSTER_POLL_S))
            return len(self.alive)

    def alive_ids(self) -> list[int]:
        with self._cond:
            return sorted(self.alive)

    def changes(self) -> Iterator[tuple[bool, int]]:
        """(joined, robot) for every change not taken yet, oldest first."""
        while True:
            try:
                yield self._changes.get_nowait()
            except queue.Empty:
                return


class PoseKeys(Protocol):
    """Each live robot's own pose key, declared as it joins and undeclared as it leaves
    (the world's :class:`~sim_bridge.world.world_link.WorldLink`)."""

    def add_robot(self, rid: int, x: float, y: float) -> None: ...

    def remove_robot(self, rid: int) -> None: ...


class Membership:
    """Robots entering and leaving the world between steps: physics, pose keys and log."""

    def __init__(
        self,
        roster: Roster,
        physics: PhysicsWorld,
        pose_keys: PoseKeys,
        log: WorldLog,
        rng: np.random.Generator,
        arena_m: float,
        world: WorldConfig,
    ) -> None:
        self.roster = roster
        self.physics = physics
        self.pose_keys = pose_keys
        self.log = log
        self.rng = rng
        self.arena_m = arena_m
        self.w = world

    def wait_for_robots(self, n: int, timeout_s: float, stop: threading.Event) -> bool:
        """True once ``n`` robots are alive, or at least two when ``timeout_s`` passed."""
        alive = self.roster.wait_for(n, timeout_s, stop)
        if stop.is_set():  # stopped (Ctrl-C) while waiting: not a time-out
            self.log.say(f"interrupted while waiting for robots ({alive} of {n} alive)")
        elif alive < n:
            self.log.say(f"{alive} of {n} robots alive after {timeout_s:g} s")
        return alive >= 2 and not stop.is_set()

    def place_start(self, n: int) -> None:
        """The robots alive now take the seeded starts of ``n`` (or more) robots, in id order."""
        self.roster.started = True  # from now on a token joins once its robot speaks
        for _ in self.roster.changes():  # the joins already known: placed here
            pass
        ids = self.roster.alive_ids()
        starts = sample_starts(max(len(ids), n), self.arena_m, self.rng, self.w)
        for rid, (x, y) in zip(ids, starts, strict=False):
            self._add(rid, float(x), float(y), at_start=True)

    def _report_ignored(self) -> None:
        for rid in self.roster.unheard():
            self.log.event("robot_ignored", robot=rid,
                           reason=f"liveliness token without a word from robot {rid} "
                                  f"for {UNHEARD_S:g} s: ignored")
            self.log.say(f"robot {rid}: a token without a robot, ignored")

    def apply(self) -> tuple[int, int]:
        """The joins and leaves since the last step: (joined, left)."""
        self._report_ignored()
        joined = left = 0
        for came, rid in self.roster.changes():
            present = rid in self.physics.ids
            if came and not present:
                try:
                    avoid = self.physics.positions()
                    (x, y), = sample_starts(1, self.arena_m, self.rng, self.w, avoid=avoid)
                except PhysicsError as e:
                    self.log.say(f"robot {rid} cannot join: {e}")
                    continue
                self._add(rid, float(x), float(y), at_start=False)
                joined += 1
            elif not came and present:
                self._remove(rid)
                left += 1
        return joined, left

    def _add(self, rid: int, x: float, y: float, at_start: bool) -> None:
        self.physics.add_robot(rid, x, y)
        self.pose_keys.add_robot(rid, x, y)
        n = len(self.physics.ids)
        self.log.event("join", robot=rid, x=round(x, 6), y=round(y, 6), n_live=n)
        self.log.say(f"robot {rid} joined at ({x:.2f}, {y:.2f}); {n} live", at_start)

    def _remove(self, rid: int) -> None:
        self.physics.remove_robot(rid)
        self.pose_keys.remove_robot(rid)
        self.log.robot_removed(rid)
        self.log.event("leave", robot=rid, n_live=len(self.physics.ids))
        self.log.say(f"robot {rid} left; {len(self.physics.ids)} live")
