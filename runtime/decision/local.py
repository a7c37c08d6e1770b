"""E teams of robots, each robot deciding on its own view: the robot's path, E x n times.

Under imperfect sensing (:class:`runtime.conditions.Conditions`) no two robots see the
same team, so the batch path (one view per team, :func:`runtime.decision.pipeline.decide_batch`)
no longer says what a swarm does. :class:`LocalDecisions` runs, for every robot of every
team, what its robot process runs: its :class:`runtime.decision.sensing.Sensor` view,
optionally its :class:`runtime.decision.estimator.PeerTracker`, and its own
:class:`runtime.decision.controller.Controller` (its own assignment, hysteresis and plan),
with the safety filter's margin widened by the uncertainty it knows it has
(:func:`runtime.decision.safety.uncertainty_params`, the filter on the tracker's estimates,
its guard on the raw views paired with the robot's own pose of their age, :class:`Seen`).
``patternrl eval --conditions`` and
``benchmarks/conditions.py`` use it; ground truth is the world's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from runtime.brain.brain import Brain
from runtime.conditions import Conditions
from runtime.core.orca import GUARD_REF_COLUMNS
from runtime.decision.agreement import Hearing, agree_mode, hears, local_views
from runtime.decision.controller import Controller
from runtime.decision.estimator import PeerTracker
from runtime.decision.safety import (
    MARGIN_SIGMAS,
    OrcaParams,
    guard_shares,
    uncertainty_params,
)
from runtime.decision.sensing import Sensor
from runtime.decision.settle import settle_for
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["LocalDecisions", "Perception", "Seen"]

LOST_TAIL = 1e-3
"""A run of lost updates this unlikely is not guarded against: the guard counts a lost peer's
unseen way for at most ``log(LOST_TAIL) / log(loss)`` steps past the latency (6 at 30 %
loss). Without loss, a peer that is not updated is out of range or beyond the k nearest:
far, and not counted."""
GUARD_SHARE_RATE = 0.1
"""The most a pair's shares of the guard's room move in a step. Each step's guard bounds a
robot's approach since the pair was last seen, most of it already made under the shares of
the steps before: a robot whose share falls faster than its approach can follow has taken
room its peer is now given. Shares free to jump let the charging adversary of
``benchmarks/conditions.py`` (n = 10, 3 steps late, 600 episodes) collide 0.01 times per
episode; at 0.1 (and 0.25) a step it did not, and the team on a plan took the same steps."""
GUARD_HISTORY_STEPS = 32
"""How far back (steps) a robot keeps its own poses, to pair each peer's last view with where
the robot itself stood then (the safety filter's guard); a peer seen longer ago than this is
paired with its estimate now."""


@dataclass(frozen=True)
class Seen:
    """B robots' teams as each perceives them this step (see :meth:`Perception.perceive`)."""

    plan: Array
    """(B, n, 2) m: the team as the brain plans from it."""
    now: Array | None = None
    """(B, n, 2) m: the team as the safety filter takes it now (None: ``plan``)."""
    vel: Array | None = None
    """(B, n, 2) m/s: the team's velocities (None: frame differences)."""
    guard_ref: Array | None = None
    """(B, n, 6): each peer as last sensed and where the robot stood when it was (m; where
    the peer's last update was lost, older than the latency, where the robot stood the
    latency's age ago), the way the peer may have come unseen in between (m, at full speed
    for the steps its view is older; else 0), and the robot's share of the pair's room (0.5:
    half; :meth:`Perception.perceive`), for the filter's guard
    (:meth:`runtime.core.orca.OrcaFilter.robot`; None: both as they are now)."""
    moment: Array | None = None
    """(B, n, 2) m: the team of one moment, as the assignment reads it: each peer as sensed
    (the tracker's, not carried along the plan) and the robot where it stood the latency's
    age ago (:meth:`Perception.perceive`; None: ``plan``)."""
    in_view: BoolArray | None = None
    """(B, n): where a robot sees only part of its team (:func:`local_views`), which peers
    it has in view: seen within the steps a run of lost updates may last
    (:meth:`Perception.perceive`); the landing's frame reads those alone
    (:func:`runtime.decision.landing_frame.view_centroid`). None: every peer."""

    def row(self, b: int) -> Seen:
        """Robot ``b``'s team alone (its arrays without the B axis)."""
        return Seen(self.plan[b], None if self.now is None else self.now[b],
                    None if self.vel is None else self.vel[b],
                    None if self.guard_ref is None else self.guard_ref[b],
                    None if self.moment is None else self.moment[b],
                    None if self.in_view is None else self.in_view[b])


class Perception:
    """What B robots perceive of their teams: the :class:`Sensor` under ``conditions``,
    and each robot's :class:`PeerTracker`.

    :meth:`perceive` returns, per robot, the team as its brain plans from it (the raw views,
    or with ``estimator`` the tracker's positions as sensed), the team as its safety filter
    takes it now and the velocities. The filter always works from the tracker when sensing
    is imperfect, whatever the brain reads: frame differences of views with 5 cm of noise
    are velocities off by 0.7 m/s, and reciprocal avoidance on them collided 0.4 times per
    episode (``benchmarks/conditions.py``, `rule:frame-balanced`, n = 10). Under perfect
    sensing without ``estimator`` there is no tracker: (views, None, None), and the
    controller takes the views and their frame differences, exactly as before."""

    def __init__(self, conditions: Conditions, observer: IntArray,
                 seeds: list[np.random.SeedSequence], estimator: bool = False,
                 world: WorldConfig = DEFAULT_WORLD, naive: bool = False) -> None:
        self.conditions = conditions
        self.sensor = Sensor(conditions, observer, seeds)
        self.estimator = estimator
        tracked = estimator or not (conditions.sensing_perfect or naive)
        self.tracker = PeerTracker(observer, conditions.noise_m, conditions.latency_steps,
                                   world=world) if tracked else None
        self.observer = np.asarray(observer, dtype=np.int64)
        self.world = world
        self.reach_m = world.v_max_mps * world.dt_s
        c = conditions
        self._lost_steps = 0 if c.loss <= 0 else c.latency_steps + math.ceil(
            math.log(LOST_TAIL) / math.log(c.loss))
        self._unseen_step_m = (self.reach_m * (1.0 + c.gain_noise)
                               + MARGIN_SIGMAS * c.act_noise_mps * world.dt_s)
        """The most a peer may move in a step (m): a full step, what the wheels' gain may add
        to it and their noise, bounded as the safety filter bounds it."""
        self._local = local_views(c)
        self.exact_pairs = (self.tracker is not None and c.noise_m <= 0.0 and c.loss <= 0.0
                            and c.own_latency_steps == 0)
        """Whether both robots of a pair know it exactly as it was last seen (no noise, no
        loss, the own pose fresh), and split the guard's room by need (:func:`guard_shares`)."""
        self._prev: tuple[Array, IntArray] | None = None  # last step's views and their ages
        self._share: Array | None = None  # (B, n) last step's shares of the guard's room
        self._share_hist: list[Array] = []  # the shares of the last latency + 1 steps
        self._step: int | None = None  # the world step of the last views, where given
        self._own: Array | None = None  # (GUARD_HISTORY_STEPS, B, 2), newest first
        self._own_restart: BoolArray = np.zeros(len(self.observer), dtype=bool)
        self.last_age: IntArray | None = None
        """(B, n) the age in steps of each position of the last views sensed."""

    def restart(self, observers: IntArray) -> None:
        """These observers start again (a new episode): the next step is their roll call,
        every peer received, and the tracker takes it as it is."""
        self.sensor.reset(observers)
        if self.tracker is not None:
            self.tracker.restart(observers)
        if self._own is not None:
            self._own_restart[np.asarray(observers, dtype=np.int64)] = True
        if self._prev is not None:  # no last step to take a peer's from
            self._prev[1][np.asarray(observers, dtype=np.int64)] = -1

    @property
    def follows_plans(self) -> bool:
        """Whether the tracker carries peers out of view along the team's plan
        (:meth:`perceive`'s ``follow``): views of the nearest peers or within a range."""
        c = self.conditions
        return self.tracker is not None and self.estimator and local_views(c)

    @property
    def uses_plans(self) -> bool:
        """Whether the tracker reads the team's plan (:meth:`perceive`'s ``follow``): the
        brain plans from each peer carried over its view's age along it."""
        return self.tracker is not None and self.estimator

    def perceive(self, truth: Array, follow: Array | None = None,
                 step: int | None = None) -> Seen:
        """Each robot's team this step, from the team as it truly is now, ``truth`` (B, n, 2).

        With a tracker, the filter's guard pairs each peer's last sensed position (the raw
        view: the tracker's smoothing lags a peer that turns or stops, by up to 10 cm in a
        step, more than the noise it removes) with the robot's own pose at that step (its
        age): both robots of a pair then bound their approach from the same moment,
        whatever happened since, unseen. A view older than the latency (its updates lost
        since) is paired with the robot's pose of the latency's age instead, the moment the
        peer's own bound counts from if its view of this robot came on time, and the peer
        may lie off that view by the way it could have come unseen in between (a full step,
        the wheels' gain and their noise, per step past the latency), by which the guard
        shrinks the pair's room and widens its cone. Before, such a peer was also bounded
        from where the robot stands now, as if it had come its whole age's way straight at
        it: the realistic preset at n = 25 (``benchmarks/conditions.py``, 100 episodes,
        `rule:frame-balanced` + the tracker) took 1.380x -> 1.364x the steps lower bound,
        0 collisions, the charging adversary's included. A peer out of view (beyond the k
        nearest, or out of range) with no update lost is known to lie farther than those in
        view: under :attr:`follows_plans` the guard bounds it from the tracker's estimate now
        (its last view carried along the plan) and the robot's own pose now, not from its
        stale view, a phantom where it stood long ago that held its near peers back
        (6 nearest seen at n = 25, the same benchmark: 84 %, 1.504x -> 100 %, 1.094x;
        docs/conditions.md, "Peers out of view: where the plan carried them"). Where the
        pair is known exactly (:attr:`exact_pairs`) they split its room by need
        (:func:`guard_shares`), else half each.

        ``follow`` (B, n, 2) m/s, NaN where none: each robot's plan of last step for its
        team (:attr:`runtime.decision.controller.Controller.team_velocity`): with the
        estimator the brain plans from each peer carried over its view's age along it
        (:attr:`runtime.decision.estimator.PeerTracker.planned`), and under
        :attr:`follows_plans` a peer out of view is carried along it. ``step``: the world's
        step number, where steps may be missed (a robot process): the shares read a peer's
        last step only from views of consecutive steps (None: every call is the next step)."""
        view, age = self.sensor.sense(truth)
        self.last_age = age
        if self.tracker is None:
            return Seen(view)
        now, vel, _ = self.tracker.update(view, age, follow if self.estimator else None,
                                          carry=self.follows_plans)
        B = view.shape[0]
        own = view[np.arange(B), self.observer]
        if self._own is None or self._own.shape[1] != B:
            self._own = np.repeat(own[None], GUARD_HISTORY_STEPS, axis=0)
            self._own_restart = np.zeros(B, dtype=bool)
        else:
            self._own = np.roll(self._own, 1, axis=0)
            self._own[0] = own
            if self._own_restart.any():
                self._own[:, self._own_restart] = own[self._own_restart]
                self._own_restart[:] = False
        ref = np.empty((*view.shape[:2], GUARD_REF_COLUMNS))
        ref[..., 5] = self._shares(view, age, step)
        # an update lost: the view is paired with the robot's own pose of the latency's age,
        # the moment the peer's own bound counts from where its view came on time, and the
        # peer may lie the way it could have come unseen in between off it (a peer out of
        # range, or beyond the k nearest, is far: only loss hides a near one)
        late = self.conditions.latency_steps
        lost = (age > late) & (self._lost_steps > 0) & ~self._beyond_view(age)
        ref[..., 4] = np.where(lost, (np.minimum(age, self._lost_steps) - late)
                               * self._unseen_step_m, 0.0)
        ref[..., 0:2] = view  # as sensed: noisier than the tracker, but never lagging
        a = np.clip(np.where(lost, late, age), 0, GUARD_HISTORY_STEPS - 1)
        ref[..., 2:4] = self._own[a, np.arange(B)[:, None]]
        old = age >= GUARD_HISTORY_STEPS  # seen too long ago: the estimate now, as it is
        if self.follows_plans:  # out of view, not lost: far, where the plan carried it
            old |= (age > late) & ~lost
        if old.any():
            ref[old, 0:2] = now[old]
            ref[old, 2:4] = np.broadcast_to(own[:, None], now.shape)[old]
        # in view: seen within the steps a run of lost updates may last (beyond the k nearest
        # or out of range, a peer's view only ages)
        in_view = None
        if self._local:
            in_view = age <= max(late, self._lost_steps)
            in_view[np.arange(B), self.observer] = True
        if not self.estimator:
            return Seen(view, now, vel, ref, in_view=in_view)
        moment = self.tracker.sensed.copy()  # the assignment's team of one moment
        moment[np.arange(B), self.observer] = self._own[min(late, GUARD_HISTORY_STEPS - 1)]
        return Seen(self.tracker.planned, now, vel, ref, moment,  # smoothed, along the plan
                    in_view)

    def _beyond_view(self, age: IntArray) -> BoolArray:
        """(B, n) the peers known to lie beyond the robot's k nearest in this step's view:
        every one not received where all k nearest were (k updates on time). The sensor
        sends the k nearest and loss drops some, so with k received no near peer was lost,
        and one not received lies farther than those k: out of view, not hidden by loss.
        Taken as lost, such a peer's stale view held the robot back by the way it might
        have come unseen (3 steps' under the realistic preset) toward a spot it had long
        left. A team of 8 that sees its 4 nearest, line -> heart: robots 0.58-0.64 m from
        a peer it saw long ago stood 6-9 cm short of their slots, held there for the rest
        of the episode (docs/conditions.md, "Peers beyond the nearest are not lost")."""
        k = self.conditions.k_nearest
        n = age.shape[1]
        if not 0 < k < n - 1:
            return np.zeros(age.shape, dtype=bool)
        on_time = age == self.conditions.latency_steps
        on_time[np.arange(age.shape[0]), self.observer] = False
        full = on_time.sum(axis=1) >= k
        out: BoolArray = full[:, None] & ~on_time
        out[np.arange(age.shape[0]), self.observer] = False
        return out

    def _shares(self, view: Array, age: IntArray, step: int | None = None) -> Array:
        """(B, n) each robot's share of the guard's room with each peer: by need
        (:func:`guard_shares`) where the pair is known exactly (:attr:`exact_pairs`) and the
        peer's last two views came on time, one step apart; else half; moving from last
        step's by at most :data:`GUARD_SHARE_RATE` (both robots of the pair move theirs
        alike, so the two still sum to 1); then the least of the last ``latency_steps + 1``
        steps' shares, what the robot takes. The guard bounds a robot's approach since the
        pair's view, ``latency_steps`` old, most of it made under the shares of the steps
        between; a robot whose share has since fallen below what it took must give the rest
        back, and where it cannot (a retreat from two sides at once scales it to a stop) its
        peer, which takes no more than the complement of the most the robot held over that
        age, still leaves them the room. With the share of each step taken (the charging
        adversary, n = 25, 3 steps late, 200 episodes on two seeds): 2 colliding pairs; with
        the least of them, none (docs/conditions.md, "Shares held for the views' age"). Call
        it after this step's own pose joined the history."""
        share = np.full(view.shape[:2], 0.5)
        if not self.exact_pairs:  # half each: no history to keep
            return share
        prev, self._prev = self._prev, (view.copy(), np.array(age, dtype=np.int64))
        last_step, self._step = self._step, step
        late = self.conditions.latency_steps
        if prev is None or prev[0].shape != view.shape \
                or late + 1 >= GUARD_HISTORY_STEPS:
            return share
        assert self._own is not None
        then, before = self._own[late][:, None], self._own[late + 1][:, None]
        fresh = (age == late) & (prev[1] == late)
        if step is not None and (last_step is None or step != last_step + 1):
            fresh[:] = False  # a step missed: no last step to read
        want = np.where(fresh, guard_shares(then - before, view - prev[0], view - then,
                                            self.world), share)
        last = share if self._share is None or self._share.shape != want.shape \
            else np.where(prev[1] < 0, 0.5, self._share)  # restarted: from half
        out: Array = np.clip(want, last - GUARD_SHARE_RATE, last + GUARD_SHARE_RATE)
        self._share = out
        hist = self._share_hist
        if hist and hist[0].shape != out.shape:
            hist = []
        restarted = prev[1] < 0
        hist = [np.where(restarted, 0.5, h) for h in hist[-late:]] + [out] if late else [out]
        self._share_hist = hist
        held: Array = np.minimum.reduce(hist)  # the least of the views' age's shares
        return held


class LocalDecisions:
    """Every robot of ``n_envs`` teams of ``n_robots`` deciding on its own view.

    ``seed``: robot i of env e senses with generator ``SeedSequence((seed, e, i))``.
    ``safety`` None: the speed clamp only; else its margin is widened for ``conditions``.
    ``naive``: a robot that ignores what it knows of its sensing (no tracker for its filter,
    no widened margin, no damped landing): the pipeline as it ran before any of these, for
    comparison (``benchmarks/conditions.py``'s ``+naive`` brains). ``agree``, a mode of
    :data:`runtime.decision.agreement.AGREE_MODES` (True: ``slots``, False: ``off``): under
    noise the leader tells its plan's frame and every robot plans in it (``frame``); with
    ``slots`` under imperfect sensing every robot tells its slot and the leader its
    assignment too, and a robot that hears a peer claim its slot goes by the leader's; heard
    through :class:`runtime.decision.agreement.Hearing` (:mod:`runtime.decision.agreement`;
    ``off`` here, where the training world builds each robot's row; ``eval``, ``robot`` and
    ``launch`` agree on the frame unless told otherwise, ``--agree``).
    """

    def __init__(self, brain: Brain, n_envs: int, n_robots: int, conditions: Conditions,
                 *, estimator: bool = False, safety: OrcaParams | None = OrcaParams(),  # noqa: B008
                 seed: int = 0, world: WorldConfig = DEFAULT_WORLD,
                 naive: bool = False, agree: bool | str = "off") -> None:
        E, n = n_envs, n_robots
        self.n_envs, self.n_robots = E, n
        self.conditions = conditions
        observer = np.tile(np.arange(n), E)
        seeds = [np.random.SeedSequence((seed, e, i)) for e in range(E) for i in range(n)]
        self.perception = Perception(conditions, observer, seeds, estimator, world, naive)
        self.safety = safety if safety is None or naive else uncertainty_params(
            safety, conditions, world)
        settle = None if naive else settle_for(conditions, estimator, world)
        self.controllers = [Controller(brain, world, self.safety, settle,
                                       conditions.diff_turn_rps, local_views(conditions))
                            for _ in range(E * n)]
        mode = agree_mode(agree, conditions)
        self.hearing = (Hearing(conditions, E, n, seed)
                        if hears(mode, conditions) and not naive else None)
        self.tells_slots = self.hearing is not None and mode == "slots"
        """Whether every robot tells its slot and the leader its assignment (``slots``), or
        only the leader its frame (``frame``)."""
        self.step = 0
        self._follow: Array | None = None  # (E n, n, 2) each robot's plan of the last step
        self.last_view: Array | None = None
        """The last step's perceived team per robot, (E, n, n, 2) m (estimates when on)."""

    def decide(self, truth: Array, pattern: Array, live: BoolArray | None = None
               ) -> tuple[Array, IntArray, BoolArray]:
        """Every robot's command (E, n, 2) m/s, its slot (E, n) (-1 held) and whether the
        filter changed it (E, n), from the true positions ``truth`` (E, n, 2) and each
        team's ``pattern`` (E, n, 2). Teams not ``live`` get zeros (their robots still
        sense, so their views stay current)."""
        E, n = self.n_envs, self.n_robots
        P = np.asarray(truth, dtype=np.float64)
        seen = self.perception.perceive(np.repeat(P, n, axis=0), self._follow)
        self.last_view = seen.plan.reshape(E, n, n, 2)
        follow = self._follow = None if not self.perception.uses_plans else (
            np.full((E * n, n, 2), np.nan))
        out = np.zeros((E, n, 2))
        slots = np.full((E, n), -1, dtype=np.int64)
        changed = np.zeros((E, n), dtype=bool)
        hearing = self.hearing
        if hearing is not None:
            hearing.hear(self.step)
        leaders = np.full((E, n), -1, dtype=np.int64)
        frames = np.full((E, 2), np.nan)
        for e in range(E):
            if live is not None and not live[e]:
                continue
            C = pattern[e]
            for i in range(n):
                b = e * n + i
                mine = seen.row(b)
                d = self.controllers[b].decide(i, mine.plan, C, self.step, mine.vel, mine.now,
                                               mine.guard_ref, mine.moment,
                                               None if hearing is None else hearing.heard(b),
                                               mine.in_view)
                out[e, i] = d.velocity
                slots[e, i] = d.slot
                changed[e, i] = d.safety_changed
                team = self.controllers[b].team_velocity
                if follow is not None and team is not None:
                    follow[b] = team
            lead = self.controllers[e * n].previous_slots
            if lead is not None and len(lead) == n:
                leaders[e] = lead
            told = self.controllers[e * n].agreement.told_frame
            if told is not None:
                frames[e] = told
        if hearing is not None and self.tells_slots:
            hearing.tell(self.step, slots, leaders, frames)
        elif hearing is not None:  # the leader's frame alone
            none = np.full((E, n), -1, dtype=np.int64)
            hearing.tell(self.step, none, none, frames)
        self.step += 1
        return out, slots, changed
