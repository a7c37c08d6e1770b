"""The training world under imperfect sensing: every robot's observation from its own view.

In the perfect world one view per team serves every robot, and :class:`BatchWorld` builds
the rows from it. Under noisy, late, gappy or local sensing no two robots see the same
team, and a policy that is to cope must train on what a robot perceives. :class:`SensedRows`
gives each robot of each env what its robot process gives its brain
(:class:`runtime.decision.controller.Controller` behind
:class:`runtime.decision.local.Perception` with the estimator on):

1. its view under the conditions, through its own peer tracker (the positions as sensed,
   smoothed, late views carried along the robot's plan of the team for the plan
   observation, and the tracker's velocities);
2. its own assignment of the pattern to that team (with hysteresis and warm potentials,
   per robot);
3. its slot: the centroid frame (general) or the synchronised plan's frame (plan), which
   under noise lands in the centroid frame, averaged over the landing's steps, for the last
   ``Settle.centroid_steps`` steps (on exact late views in the plan's frame, kept for
   ``Settle.plan_frame_steps``, then the frame of the team's core); and its way left to that slot
   (``to_slot``), by which the world damps its landing;
4. its row, built by the rows every robot builds (:func:`general_observation`).

A robot whose episode starts (a reset) has its roll call: its first row is built from the
team as it is, and its sensing and tracker start again. The world's rewards, contacts and
"formed" stay ground truth. The paper's observation (fixed three frames of the whole team)
is not offered here.

Cost: E x n teams of n for the assignment and the rows, n times the perfect world's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from runtime.conditions import Conditions
from runtime.core.assignment import assign_teams
from runtime.decision.landing_frame import (
    CORE_M,
    centroid_targets,
    core_frame,
    seen_centroid,
    seen_team,
    shared_slots,
    smooth_centroid,
)
from runtime.decision.local import Perception
from runtime.decision.observation import ObservationSpec, general_observation
from runtime.decision.rules import pace_velocity, plan_targets
from runtime.decision.settle import landing_steps, settle_for
from runtime.types import Array, F32Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["SensedRows"]


class SensedRows:
    """Each robot's own observation row for ``n_envs`` teams of ``n_robots`` (see the module
    docstring). ``seed``, ``first_env``: robot i of env e senses with the generator of
    ``SeedSequence((seed, 2, first_env + e, i))``."""

    def __init__(self, conditions: Conditions, spec: ObservationSpec, n_envs: int,
                 n_robots: int, seed: int, first_env: int = 0,
                 world: WorldConfig = DEFAULT_WORLD) -> None:
        if not spec.needs_slots:
            raise ValueError(f"training under imperfect sensing builds the general and plan "
                             f"observations, not the {spec.name} one")
        E, n = n_envs, n_robots
        self.spec, self.world, self.n_envs, self.n_robots = spec, world, E, n
        observer = np.tile(np.arange(n), E)
        seeds = [np.random.SeedSequence((seed, 2, first_env + e, i))
                 for e in range(E) for i in range(n)]
        self.perception = Perception(conditions, observer, seeds, estimator=True, world=world)
        self.settle = settle_for(conditions, True, world)
        self._slots: IntArray = np.tile(np.arange(n, dtype=np.int64), (E * n, 1))
        self._potentials: Array = np.zeros((E * n, n))
        self._has_prev = np.zeros(E * n, dtype=bool)
        self._eye = np.arange(n)
        self._follow: Array | None = None  # (E n, n, 2) each robot's plan of the last step
        self._centroid = np.zeros((E * n, 2))  # each robot's landing centroid (settle.Lander)
        self._landing = np.zeros(E * n, dtype=bool)  # who landed in it last step
        self._land_k = np.zeros(E * n, dtype=np.int64)  # and for how many steps before
        self._plan_frame = np.zeros((E * n, 2))  # the plan's frame kept from its first step
        self.to_slot: Array = np.full((E, n), np.inf)
        """(E, n) m: each robot's way left to its slot under its plan, as of the last rows
        (inf: none), which the training world's damped landing reads."""

    def restart(self, env_ids: IntArray) -> None:
        """These envs start new episodes: their robots' roll call, and no hysteresis."""
        n = self.n_robots
        rows = (np.asarray(env_ids, dtype=np.int64)[:, None] * n + self._eye).reshape(-1)
        self.perception.restart(rows)
        self._has_prev[rows] = False
        self._potentials[rows] = 0.0
        self._landing[rows] = False
        self.to_slot.reshape(-1)[rows] = np.inf

    def _frame(self, land: Any, cont: Any, m: Array, P: Array, C: Array, Cc: Array,
               slots: IntArray, ref: Array | None, pts: Array) -> tuple[Array, Array]:
        """The landing frames' centroids (landing rows, 2) m and the slot points (landing
        rows, n, 2) they hold: ``m``, their centroids, at the robots' slots (``pts``, the
        landing rows' slot points, which it may change); or on exact late
        views for a landing's first ``plan_frame_steps`` steps the centroid of the targets
        the plan gives the team of one moment as the robot sees it on the landing's first
        step, kept, then the frame of the team's core at the slots every robot assigns alike
        from that moment (:meth:`runtime.decision.settle.Lander.frame`)."""
        assert self.settle is not None
        keep = self.settle.plan_frame_steps
        if keep <= 0:
            return m, pts
        first = land & ~cont
        team = seen_team(P[land], np.tile(self._eye, self.n_envs)[land],
                         None if ref is None else ref[land])
        if first.any():
            at = first[land]
            target, _ = plan_targets(team[at], C[first], slots[first], self.spec.travel_weight,
                                     self.world)
            self._plan_frame[first] = target.mean(axis=1)
        frame: Array = self._plan_frame[land]
        late = self._land_k[land] >= keep
        if late.any():  # the landing goes on: one moment's slots, the team's core's frame
            cc = Cc[land][late]
            pts[late] = np.take_along_axis(cc, shared_slots(team[late], cc)[..., None], axis=1)
            frame[late] = core_frame(team[late], pts[late], CORE_M)
        return frame, pts

    def rows(self, truth: Array, pattern: Array) -> tuple[F32Array, Array]:
        """Every robot's row (E, n, dim) float32 from the teams as they truly are now,
        ``truth`` (E, n, 2), and each env's centred ``pattern`` (E, n, 2); and each robot's
        plan steps left K (E, n) (1 for the general observation)."""
        E, n = self.n_envs, self.n_robots
        seen = self.perception.perceive(np.repeat(np.asarray(truth, dtype=np.float64), n, 0),
                                        self._follow)
        P = np.ascontiguousarray(seen.plan)  # (E n, n, 2) each robot's team
        A = P if seen.moment is None else np.ascontiguousarray(seen.moment)  # one moment's
        V = np.zeros_like(P) if seen.vel is None else seen.vel
        C = np.repeat(np.asarray(pattern, dtype=np.float64), n, 0)
        Cc = np.ascontiguousarray(C - C.mean(axis=1, keepdims=True))
        prev = self._slots
        slots = prev.copy()
        for warm in (True, False):  # with hysteresis, and the teams that start without
            sel = self._has_prev == warm
            if sel.all():
                assign_teams(A, Cc, prev, warm, self._potentials, slots)
            elif sel.any():
                pot, out = self._potentials[sel], prev[sel].copy()
                assign_teams(A[sel], Cc[sel], prev[sel], warm, pot, out)
                self._potentials[sel], slots[sel] = pot, out
        self._slots, self._has_prev[:] = slots, True
        K: Array = np.ones(E * n)
        pace: Array = K
        if self.spec.name == "plan":
            G, K = plan_targets(P, C, slots, self.spec.travel_weight, self.world)
            land = (np.zeros(len(K), dtype=bool) if self.settle is None
                    else self.settle.lands_in_centroid(K))  # under noise: the centroid frame
            if land.any():  # averaged over the landing's steps (runtime.decision.settle)
                assert self.settle is not None
                cont = land & self._landing
                self._land_k[land] = np.where(cont[land], self._land_k[land] + 1, 0)
                m = P[land].mean(axis=1)  # a landing starts from the tracker's centroid
                pts = np.take_along_axis(C[land], slots[land][..., None], axis=1)  # then, in
                iv = seen.in_view  # a local view, the one the peers in view show at their slots
                ref = None if seen.guard_ref is None else seen.guard_ref[cont]
                raw = seen_centroid(P[cont], np.tile(self._eye, E)[cont], ref, pts[cont[land]],
                                    None if iv is None else iv[cont])
                m[cont[land]] = smooth_centroid(
                    self._centroid[cont], raw,
                    self.settle.centroid_weight(self._land_k[cont]),
                    self.settle.centroid_gate(n))
                self._centroid[land] = m
                frame, pts = self._frame(land, cont, m, P, C, Cc, slots, seen.guard_ref, pts)
                G[land], K[land] = centroid_targets(P[land], pts, frame, self.world)
            self._landing = land
            each = np.repeat(K[:, None], n, axis=1)  # each robot's steps left: the team's,
            if land.any():  # or in a landing at its own pace its own
                assert self.settle is not None
                each[land] = landing_steps(G[land], P[land], K[land], self.settle, self.world)
            # each robot's plan for its whole team: peers out of view go along it next step
            self._follow = pace_velocity(G, P, each, self.world)
            mine = np.arange(E * n), np.tile(self._eye, E)
            self.to_slot = np.hypot(*(G[mine] - P[mine]).T).reshape(E, n)
            pace = each[mine]  # the robot's own row reads its own
        else:
            G = np.take_along_axis(Cc, slots[..., None], axis=1) + P.mean(axis=1, keepdims=True)
        obs = general_observation(P, P - V * self.world.dt_s, G, self.spec.k_neighbours,
                                  self.world, steps_left=pace if self.spec.name == "plan"
                                  else None, dtype=np.float32)
        own = obs.reshape(E, n, n, -1)[:, self._eye, self._eye]  # robot i's row of its team
        return np.ascontiguousarray(own), K.reshape(E, n)
