"""A robot's estimate of where its peers are now, from views that are noisy, late and gappy.

:class:`PeerTracker` is what a roboticist writes first: one alpha-beta filter (a
steady-state constant-velocity Kalman filter) per peer, with latency compensation.
Batched over B observers, (B, n) peers each; every brain and rule can use its output
in place of the raw view (``eval --estimator``, ``robot --estimator``).

Per observer b and peer j, each step:

1. **Predict** ``x += v dt`` (the estimate of the peer *now*).
2. **Update** when a new position ``z`` arrived (its age did not grow): it was sensed
   ``a`` steps ago, so it is compared with where the estimate says the peer was then,
   ``r = z - (x - a dt v)``; then ``x += alpha r`` and ``v += beta r / dt`` (speed
   clamped to ``v_max``). A lost update is a predict-only step.
3. The observer's own row is its own pose (fresh odometry): taken as sensed; its
   velocity is the difference of its last two poses.

``alpha`` and ``beta`` trade smoothing for lag; (0.4, 0.1) lie on Kalata's critically
damped curve, ``beta = 2 (2 - alpha) - 4 sqrt(1 - alpha)``, so the filter settles without
ringing. Measured against alpha 0.25 on ``benchmarks/conditions.py``'s cases: the smoother
filter held the realistic preset more often, but the safety filter, which works from this
estimate, let a robot running at 1 m/s through (`rule:assign`, heart, 5 cm noise: 10
collisions in 4 episodes at 0.25, none at 0.4); a second, smoother filter for the brain
alone formed and held 95 % of the realistic cases with 0.25 collisions per episode, and was
left out. Without noise nothing is smoothed: a peer's
velocity is its motion between its last two updates, and its position the last update
carried forward over its age (with fresh views, the view itself).

**Peers that keep still** (estimated slower than ``STILL_MPS``, 0.1 m/s) are averaged
longer, at gain ``STILL_ALPHA`` = 0.15 (Kalata's beta for it): a landed team holds its
formation only if each robot's picture of the others is steadier than the 2.5 cm
tolerance, and at 0.4 a still peer's estimate keeps half the noise. A peer that starts
moving leaves the still gains within a step or two (its velocity estimate passes 0.1 m/s),
and the safety filter's guard never reads the tracker (it reads the raw views), so the
longer average cannot hide a moving peer from it. Measured on ``benchmarks/conditions.py``'s
cases (n = 10, 4 episodes per shape, `rule:frame-balanced` + the tracker, with the landing
frame of :mod:`runtime.decision.settle`): 10 cm noise held 35 % -> 70 %, the realistic
preset 95 % -> 95 %, 5 cm 100 % -> 100 %; still gains 0.1, or a threshold of 0.25 m/s,
did worse on 5 cm (65-95 %). The price: a peer that starts from rest is followed late
until its velocity estimate passes 0.1 m/s (the tracker's error over the realistic preset's
episodes, n = 10: p95 0.13 m -> 0.20 m); keeping the still gains only while the residual
stays under 2.5-3 sigmas of the noise brought the error back but held 10 cm noise 46-64 %
instead of 73 % (100 episodes), and was left out.

**Peers out of view** (a robot that sees only its k nearest, or within a range) are not
lost, they are elsewhere, and a team that plans from where it last saw them plans from a
team that is not there: each robot's frame and assignment drift apart from the others'.
Every robot got the whole team at the start (the roll call) and every robot computes the
same synchronised plan from it (:class:`runtime.decision.rules.FrameRule`), so each also
knows where the plan sends the peers it cannot see: ``update(..., follow=)`` carries them
along the plan's velocities of the last step, and the plan reads them where they are now,
not where they were last seen. A peer that comes back into view is taken as sensed again.
The plan stays the same for all robots as long as their pictures agree; ORCA's detours and
the views of the nearest peers are what makes them differ, and what corrects them.

**Late views of a team on a plan.** A view ``a`` steps old shows a peer where it was
``a`` steps ago. Planning from it (``sensed``) makes the team's frame lag its own motion:
each robot's plan slides under it as the views catch up, and views 2 steps late cost
`rule:frame-balanced` + the tracker 1.22x the steps lower bound where the perfect world
takes 1.05x. Planning from the estimate now (``x``, carried at constant velocity) lands
sooner but overshoots every stop: the team formed and held 0 % (n = 10, 50 episodes).
Every robot computes the team's synchronised plan, so each knows how the plan moved every
peer over those ``a`` steps: ``update(..., follow=)`` keeps the plan's velocities of the
last ``latency + PLAN_HISTORY_STEPS`` steps, and ``planned`` is ``sensed`` carried along
them over its age. With exact views it is where a peer that followed the plan is now, the
stops included, and it is ``sensed`` for a brain without a plan. Measured on
``benchmarks/conditions.py`` (n = 10, 100 episodes per cell, `rule:frame-balanced` + the
tracker, the shipped general brain alike): 1, 2 and 3 steps late 1.14x / 1.22x / 1.34x ->
1.08x / 1.15x / 1.26x, 30 % loss 1.20x -> 1.12x, the realistic preset 1.63x -> 1.53x (92 %
success either way), the perfect world and the noise cases unchanged. Without the safety
filter, views 2 steps late land at the perfect world's 1.05x: what is left is the filter's
guard (:func:`runtime.decision.safety.guard_bound`).

``sigma_m`` (B, n) is the filter's own figure of its position error: the noise the
steady-state filter leaves, ``noise sqrt(alpha / (2 - alpha))``, plus half a step at
full speed for every step a peer went without an update beyond its latency. The safety
filter's margin is sized from the same steady-state figure for the conditions as a whole
(``runtime.decision.safety.uncertainty_margin``); ``sigma_m`` gives it per peer.
"""

from __future__ import annotations

import math

import numpy as np

from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["PLAN_HISTORY_STEPS", "PeerTracker", "steady_sigma"]

ALPHA = 0.4
BETA = 0.1
STILL_ALPHA = 0.15
"""The gain for a peer that keeps still (its estimated speed under :data:`STILL_MPS`)."""
STILL_BETA = 2.0 * (2.0 - STILL_ALPHA) - 4.0 * math.sqrt(1.0 - STILL_ALPHA)
"""Kalata's critically damped beta for :data:`STILL_ALPHA` (about 0.012)."""
STILL_MPS = 0.1
"""A peer estimated slower than this (m/s) is taken as keeping still."""
PLAN_HISTORY_STEPS = 8
"""Steps of the team's plan kept beyond the latency, for views made later by lost updates
(8 updates lost in a row: 7e-5 at 30 % loss); a view older than that is carried along the
steps kept."""


def steady_sigma(noise_m: float, alpha: float = ALPHA) -> float:
    """Position error (m, per axis) an alpha-beta filter leaves of white sensing noise."""
    return noise_m * math.sqrt(alpha / (2.0 - alpha))


class PeerTracker:
    """Per-peer alpha-beta filters of B observers; see the module docstring.

    ``observer`` (B,): each observer's own row. ``noise_m``, ``latency_steps``: what the
    observer knows of its sensing (for ``sigma_m``).
    """

    def __init__(self, observer: IntArray, noise_m: float = 0.0, latency_steps: int = 0,
                 alpha: float = ALPHA, beta: float = BETA,
                 world: WorldConfig = DEFAULT_WORLD, still: bool = True) -> None:
        self.observer = np.asarray(observer, dtype=np.int64)
        self.exact = noise_m == 0.0  # exact views: no smoothing (see the module docstring)
        self.alpha, self.beta = float(alpha), float(beta)
        self.still = bool(still)
        self.world = world
        self.latency_steps = int(latency_steps)
        self.noise_m = float(noise_m)
        self._sigma0 = steady_sigma(noise_m, alpha)
        self._restart: BoolArray | None = None
        self.plan_steps = self.latency_steps + PLAN_HISTORY_STEPS
        """How many steps of the team's plan are kept (see "Late views of a team on a plan")"""

        self.reset()

    def restart(self, observers: IntArray) -> None:
        """These observers start again (a new team or episode): their next update takes the
        view as it is, with no velocity, as at the very start."""
        rows = np.asarray(observers, dtype=np.int64)
        restart = np.zeros(len(self.observer), dtype=bool)
        if self._restart is not None:
            restart |= self._restart
        restart[rows] = True
        self._restart = restart

    def reset(self) -> None:
        self._restart = None
        self._x: Array | None = None
        self._v: Array | None = None
        self._age: IntArray | None = None
        self._own: Array | None = None
        self._z: Array | None = None
        self.sensed: Array = np.zeros((0, 0, 2))
        self._gap: IntArray = np.zeros((0, 0), dtype=np.int64)
        self._followed: BoolArray = np.zeros((0, 0), dtype=bool)
        """(B, n) peers carried along their plan since their last update"""
        self.planned: Array = np.zeros((0, 0, 2))
        self._plan: Array | None = None
        """(plan_steps, B, n, 2) m/s: the plan's velocities of the last steps, newest at
        ``_plan_at``, 0 where there was none"""
        self._plan_at = 0

    def update(self, view: Array, age: IntArray, follow: Array | None = None,
               carry: bool = True) -> tuple[Array, Array, Array]:
        """(positions now (B, n, 2) m, velocities (B, n, 2) m/s, sigma_m (B, n)) from this
        step's ``view`` (B, n, 2) and its ``age`` (B, n) steps. ``sensed`` then holds the
        smoothed positions as of when they were sensed (not carried forward), and
        ``planned`` those carried forward over their age along the team's plan (see the
        module docstring's "Late views of a team on a plan"; ``sensed`` without a plan).

        ``follow`` (B, n, 2) m/s, NaN where unknown: the velocity each peer's plan gave it
        last step, as the observer computed the team's plan. With ``carry`` a peer that
        sent nothing this step is carried along it (``x += follow dt``, ``v = follow``)
        instead of its last velocity, and ``sensed`` has it where it is now (see the module
        docstring's "Peers out of view")."""
        z = np.asarray(view, dtype=np.float64)
        a = np.asarray(age, dtype=np.int64)
        B = z.shape[0]
        dt, vmax = self.world.dt_s, self.world.v_max_mps
        rows = np.arange(B)
        own = z[rows, self.observer]
        if self._restart is not None and self._x is not None and self._x.shape == z.shape \
                and self._v is not None and self._age is not None and self._own is not None:
            r0 = self._restart  # these observers start again: their views taken as they are
            self._x[r0] = z[r0]
            self._v[r0] = 0.0
            self._age[r0] = a[r0]
            self._own[r0] = own[r0]
            self._gap[r0] = 0
            self._followed[r0] = False
            if self._z is not None:
                self._z[r0] = z[r0]
            if self._plan is not None:
                self._plan[:, r0] = 0.0
        self._restart = None
        if self._x is None or self._x.shape != z.shape or self._v is None \
                or self._age is None or self._own is None:
            self._x = z.copy()
            self._v = np.zeros_like(z)
            self._age = a.copy()
            self._own = own.copy()
            self._z = z.copy()
            self._gap = np.zeros(a.shape, dtype=np.int64)
            self._followed = np.zeros(a.shape, dtype=bool)
            self._plan = None
        else:
            x, v = self._x, self._v
            new = a <= self._age  # 2. (below) update where a position arrived
            if follow is not None:
                self._remember_plan(follow)
            if follow is not None and carry:  # 1'. a peer not heard from goes the plan's way
                followed = ~new & np.isfinite(follow[..., 0])
                v[followed] = follow[followed]
                self._followed |= followed
            x += v * dt  # 1. predict
            self._gap += 1
            if self.exact:  # the view's own motion since its last update, carried forward
                assert self._z is not None
                vz = (z - self._z) / (self._gap * dt)[..., None]
                v[new] = vz[new]
                x[new] = z[new] + ((a * dt)[..., None] * v)[new]
            else:  # alpha-beta
                r = z - (x - (a * dt)[..., None] * v)
                r[~new] = 0.0
                if self.still:  # a peer that keeps still is averaged longer
                    still = (v[..., 0] ** 2 + v[..., 1] ** 2 < STILL_MPS ** 2)[..., None]
                    x += np.where(still, STILL_ALPHA, self.alpha) * r
                    v += np.where(still, STILL_BETA / dt, self.beta / dt) * r
                else:
                    x += self.alpha * r
                    v += (self.beta / dt) * r
            self._gap[new] = 0
            self._followed &= ~new
            self._z = z.copy()
            speed = np.hypot(v[..., 0], v[..., 1])
            over = speed > vmax
            if over.any():
                v[over] *= (vmax / speed[over])[:, None]
            self._age = a.copy()
            # 3. the own row: the pose as sensed, its velocity from the last two
            v[rows, self.observer] = (own - self._own) / dt
            x[rows, self.observer] = own
            self._own = own.copy()
        back = np.where(self._followed, 0, a)
        self.sensed = self._x - (back * dt)[..., None] * self._v
        self.planned = self._along_plan(self.sensed, back)
        stale = np.maximum(a - self.latency_steps, 0)
        sigma = self._sigma0 + 0.5 * vmax * dt * stale
        sigma[rows, self.observer] = 0.0
        return self._x.copy(), self._v.copy(), sigma

    def _remember_plan(self, follow: Array) -> None:
        """Keep ``follow`` (B, n, 2), the plan's velocities of the step just gone (NaN, no
        plan: kept as 0, it carries nothing)."""
        f = np.nan_to_num(np.asarray(follow, dtype=np.float64), nan=0.0)
        if self._plan is None or self._plan.shape[1:] != f.shape:
            self._plan = np.zeros((self.plan_steps, *f.shape))
            self._plan_at = 0
        self._plan_at = (self._plan_at - 1) % self.plan_steps
        self._plan[self._plan_at] = f

    def _along_plan(self, sensed: Array, age: IntArray) -> Array:
        """``sensed`` (B, n, 2) carried over each one's ``age`` (B, n) steps along the plan's
        velocities of those steps; a step without a plan (or older than kept) carries
        nothing: a brain without a plan reads its peers as sensed. Only the steps some view
        is that old are read."""
        out: Array = sensed.copy()
        plan = self._plan
        steps = 0 if plan is None else min(int(age.max(initial=0)), self.plan_steps)
        if steps <= 0:
            return out
        assert plan is not None
        way = np.zeros_like(out)
        for k in range(steps):  # newest first
            way += np.where((age > k)[..., None], plan[(self._plan_at + k) % self.plan_steps],
                            0.0)
        out += way * self.world.dt_s
        return out
