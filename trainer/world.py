"""The training world: E independent envs of N disc robots, batch-first numpy.

Every array is shaped ``(E, N, ...)`` (envs, robots, ...); nothing loops over
robots, and the only loop over envs on the hot path is scipy's assignment
solver, and only for the envs whose previous assignment stopped being optimal
(see *Shared assignment* below). Units: metres, seconds, metres per second.

Step (``BatchWorld.step``), in order
    1. **Actions** ``(E, N, 2)`` are velocities in m/s. A robot whose action
       has a non-finite component holds still (NaN/inf -> 0); a faster action
       is scaled down to ``v_max`` (direction kept).
    2. **Kinematics** ``p += a dt`` (paper eq. 2).
    3. **Contact.** Robots are rigid discs of radius R: a pair whose straight
       swept paths come closer than 2R during the step (closest approach by
       :func:`runtime.formation.swept_pair_distance`, the function behind
       ``count_collisions``) is a *collision* and counted, one per pair per
       step, and charged to both robots. Overlaps left at the end of the move
       are resolved by a few vectorised Jacobi sweeps of pairwise projection:
       each overlapping pair is pushed apart symmetrically along its centre
       line to exactly 2R (sweeps after the first over-relax, so a jam of many
       discs clears in a few sweeps and may end with gaps slightly above 2R);
       a pair pushed apart in a later sweep (a robot shoved into a third one)
       is a collision too. This is what the pymunk world
       shows: discs that meet are pushed apart by the contact and never
       interpenetrate, and a robot that drives into another one stops at
       contact instead of passing. Should a jam not clear within
       ``CONTACT_SWEEPS`` sweeps, the robots still overlapping hold their
       previous (valid) positions (counted in ``BatchWorld.contact_fallbacks``).
       The projection needs ``v_max dt <= R`` (the default is exactly R):
       then no centre can cross another's within a step, so a push never
       swaps two robots; other worlds are refused. The plane has no walls:
       the arena only bounds the starts.
    4. **Shared assignment**, solved once per step and used for reward,
       termination and observation alike: ``assign_slots_batch(previous=...)``
       (centred, error-optimal, with hysteresis). Before calling scipy the
       world proves, for all envs at once, that the solver would keep the
       previous assignment (no cycle of slot exchanges beats it by the
       hysteresis margin: Bellman-Ford in numpy over the batch, see
       :func:`previous_assignment_kept`); only envs where that proof fails go
       to the solver. The result is identical to calling ``assign_slots_batch`` on
       every env (tested), at a fraction of the cost.
    5. **Reward**, per robot, paper eq. 6 plus two documented extras::

           r_i = R_g + R_c * c_i + beta * r_p + w_prog * prog_i + B * formed

       ``c_i``: collisions robot i took part in this step. ``r_p`` is the
       *change* of the formation error (eq. 7, the RMS distance under the best
       assignment and translation), ``r_p = (err_{t-1} - err_t) / (v_max dt)``:
       a potential-based form of eq. 7 (Ng et al. 1999), which telescopes over
       an episode to the error removed, so it cannot be farmed and does not
       change which policy is optimal; normalised so that the whole team
       moving at full speed straight at its slots scores about +1.
       ``prog_i = (|p_i(t-1) - g_i| - |p_i(t) - g_i|) / (v_max dt)`` in [-1, 1]:
       robot i's own progress toward ``g_i``, the slot it was shown in its
       observation at t-1 (the shared assignment's slot in world coordinates).
       A training-only, per-robot credit signal; 0 disables it.
       ``formed``: 1 on the step the pattern is formed (every robot).
    6. **Termination.** *Formed*: every robot within ``formed_tol`` of its slot
       under the shared assignment (``slot_distances``; the assignment is the
       error-optimal one, up to the hysteresis margin). *Truncated*: the step
       limit is reached without forming. ``done = formed | truncated``.
    7. **Auto-reset.** Envs that are done are reset at once (as gymnasium's
       vector envs do): ``StepResult.obs`` holds the first observation of the
       new episode for them, and ``StepResult.episode`` the finished episodes'
       statistics, including their last observation (``final_obs``, for
       bootstrapping the value of a truncated episode).

Starts and patterns
    Each env owns a ``numpy.random.Generator`` spawned from ``SeedSequence(seed)``
    (child e for env e), used only by that env's resets: env e's sequence of
    episodes depends on nothing else (not on E, nor on the other envs). A reset
    draws the pattern (one of the set, uniformly) and then N starts uniform in
    the arena with pairwise separation >= ``start_separation`` (rejection
    sampling: every robot too close to a lower-numbered one is redrawn, all at
    once). Patterns are ``make_pattern(name, N)`` (cached per name); the name
    ``"random"`` draws a fresh ``random_pattern`` from the env's generator.

Reward constants (``RewardConfig()``; per robot, per step)

    ================ ======= =====================================================
    constant         default why
    ================ ======= =====================================================
    step_penalty     -0.05   R_g, fatigue (paper: negative constant). Small next
                             to the dense terms (O(1) per step) so it does not
                             drown them, large enough that dawdling short of
                             "formed" costs: at gamma = 0.99 hovering forever is
                             worth -5, so finishing is always better.
    collision_penalty -1.0   R_c per collision the robot is part of. Equals 20
                             steps of fatigue and a full step of progress: a
                             detour of a few steps is always cheaper than
                             contact, and pushing into a neighbour (no progress,
                             -1 per step) is never worth it.
    beta             1.0     weight of r_p (team progress, change form, above).
                             Summed over an episode it is the initial error in
                             steps (about 20-40 here): a dense team signal.
    progress_weight  1.0     per-robot progress toward its own slot. The
                             training-only credit signal that lets a shared
                             policy learn in minutes (the calibration run behind
                             DESIGN.md learned a 10-robot circle in 2 min with it,
                             not in 12 without); 0 gives the paper's reward.
    formed_bonus     1.0     once, to every robot, on the formed step: marks
                             success in the return; the fatigue already makes
                             ending early pay, so it stays modest.
    ================ ======= =====================================================

    ``PAPER_REWARD`` is eq. 6 alone (no progress term, no bonus).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from runtime.formation import (
    HYSTERESIS_ABS_M2,
    HYSTERESIS_REL,
    assign_slots_batch,
    lower_bounds,
    slot_positions,
    swept_pair_distance,
)
from runtime.observation import ObservationSpec, general_observation, paper_observation
from runtime.patterns import make_pattern, random_pattern
from runtime.world import DEFAULT_WORLD, WorldConfig

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
F32Array = NDArray[np.float32]

RANDOM_PATTERN = "random"
"""Pattern name that draws a fresh random shape at every reset."""

CONTACT_TOL_M = 1e-6
"""Two centres closer than 2R - this are interpenetrating (count_collisions' default)."""

CONTACT_SWEEPS = 16
"""Jacobi projection sweeps before the hold-still fallback."""

CONTACT_OVER_RELAX = 1.7
"""Over-relaxation of the sweeps after the first. A jam of ten robots all driven at
their centroid needs a median of 19 plain Jacobi sweeps (99th percentile 31) but
6 (99th percentile 9, never more than 12) over-relaxed; an isolated pair is
resolved by the first, plain sweep to exactly 2R."""


_MAX_START_DRAWS = 10_000


@dataclass(frozen=True)
class RewardConfig:
    """Reward constants, per robot per step (see the module docstring's table)."""

    step_penalty: float = -0.05
    collision_penalty: float = -1.0
    beta: float = 1.0
    progress_weight: float = 1.0
    formed_bonus: float = 1.0


DEFAULT_REWARD = RewardConfig()
"""The documented defaults (the table above)."""

PAPER_REWARD = RewardConfig(progress_weight=0.0, formed_bonus=0.0)
"""The paper's eq. 6 alone: fatigue, collisions, team progress."""


class EpisodeStats(NamedTuple):
    """Statistics of the k envs whose episodes ended this step (arrays of length k)."""

    env_ids: IntArray  # (k,) which envs
    formed: BoolArray  # (k,) formed (else truncated)
    steps: IntArray  # (k,) steps taken
    travel: Array  # (k,) total distance travelled by all robots (m)
    collisions: IntArray  # (k,) colliding pairs summed over the episode
    final_error: Array  # (k,) formation error at the end (m)
    episode_return: Array  # (k,) sum over steps of the robots' mean reward
    pattern_ids: IntArray  # (k,) index into the pattern set
    final_obs: F32Array  # (k, N, D) last observation, before the reset
    lower_bound_steps: IntArray | None  # (k,) when compute_bounds
    lower_bound_travel: Array | None  # (k,) metres, when compute_bounds


class StepResult(NamedTuple):
    """What one ``BatchWorld.step`` returns."""

    obs: F32Array  # (E, N, D), after auto-reset of the envs that finished
    reward: F32Array  # (E, N)
    done: BoolArray  # (E,) formed | truncated
    formed: BoolArray  # (E,)
    truncated: BoolArray  # (E,)
    collisions: IntArray  # (E,) colliding pairs this step
    episode: EpisodeStats | None  # the envs that finished this step, else None


def _pattern_list(patterns: Sequence[str | Path] | str | Path) -> tuple[str, ...]:
    if isinstance(patterns, str | Path):
        return (str(patterns),)
    names = tuple(str(p) for p in patterns)
    if not names:
        raise ValueError("the pattern set is empty")
    return names


def previous_assignment_kept(P: Array, C: Array, previous: IntArray) -> BoolArray:
    """Per env, whether ``assign_slots_batch(P, C, previous)`` surely returns ``previous``, (E,).

    The solver keeps ``previous`` unless the optimum beats it by more than the
    hysteresis margin ``m = HYSTERESIS_REL * old + HYSTERESIS_ABS_M2``. Any
    other assignment differs from ``previous`` by disjoint cycles of slot
    exchanges ("robot i takes robot j's slot", weight
    ``cost[i, slot_j] - cost[i, slot_i]``), at most N robots in all. Bellman-Ford
    from a virtual source (vectorised over envs) that settles with no
    relaxation larger than ``m / (2N)`` proves every cycle of L robots weighs
    at least ``-L m / (2N)``, so no assignment beats ``previous`` by more than
    ``m / 2``: the solver would keep it. False means "not proven" (the caller
    solves those envs exactly), so the result always equals the solver's.
    """
    E, n = P.shape[0], P.shape[1]
    Pc = P - P.mean(axis=1, keepdims=True)
    Q = np.take_along_axis(C, previous[..., None], axis=1)  # Q[e, j]: robot j's slot point
    Q = Q - Q.mean(axis=1, keepdims=True)
    q2 = np.einsum("eik,eik->ei", Q, Q)
    PQ = Pc @ Q.transpose(0, 2, 1)  # PQ[e, i, j] = Pc_i . Q_j
    own = np.einsum("eii->ei", PQ)
    # W[e, i, j] = |Pc_i - Q_j|^2 - |Pc_i - Q_i|^2
    W = (q2[:, None, :] - q2[:, :, None]) - 2.0 * (PQ - own[:, :, None])
    gap = Pc - Q
    old = np.einsum("eik,eik->e", gap, gap)
    tol = (HYSTERESIS_REL * old + HYSTERESIS_ABS_M2) / (2.0 * n)
    kept = np.zeros(E, dtype=bool)
    active = np.arange(E)
    d = np.minimum(W.min(axis=1), 0.0)  # one sweep from the virtual source (d = 0)
    for _ in range(n):
        nd = (d[:, :, None] + W).min(axis=1)
        moving = (nd < d - tol[:, None]).any(axis=1)
        kept[active[~moving]] = True
        if moving.all():
            d = nd
            continue
        if not moving.any():
            break
        active, d, W, tol = active[moving], nd[moving], W[moving], tol[moving]
    return kept


class BatchWorld:
    """E envs x N robots forming patterns; see the module docstring."""

    def __init__(
        self,
        n_envs: int,
        n_robots: int,
        patterns: Sequence[str | Path] | str,
        obs_spec: ObservationSpec,
        *,
        world: WorldConfig = DEFAULT_WORLD,
        reward: RewardConfig = RewardConfig(),
        seed: int = 0,
        compute_bounds: bool = False,
        step_limit: int | None = None,
        build_obs: bool = True,
    ) -> None:
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        if n_robots < 2:
            raise ValueError(f"n_robots must be >= 2, got {n_robots}")
        if not obs_spec.accepts_team(n_robots):
            raise ValueError(
                f"observation '{obs_spec.name}' is for {obs_spec.n_robots} robots, not {n_robots}"
            )
        if world.max_step_m > world.radius_m + 1e-12:
            raise ValueError(
                "the contact model needs v_max * dt <= R (no robot may cross another's "
                f"centre in one step); got {world.max_step_m} > {world.radius_m}"
            )
        density = n_robots * math.pi * (world.start_separation_m / 2.0) ** 2 / world.arena_m**2
        if density > 0.3:
            raise ValueError(f"{n_robots} robots do not fit apart in a {world.arena_m} m arena")
        self.n_envs = n_envs
        self.n_robots = n_robots
        self.obs_spec = obs_spec
        self.world = world
        self.reward_config = reward
        self.compute_bounds = compute_bounds
        self.step_limit = int(step_limit if step_limit is not None else world.step_limit)
        if self.step_limit < 1:
            raise ValueError(f"step_limit must be >= 1, got {self.step_limit}")
        self.build_obs = build_obs
        self.obs_dim: int = obs_spec.dim if build_obs else 0

        E, N = n_envs, n_robots
        self._two_r = world.min_separation_m
        self._reach = world.max_step_m
        self._diag_inf = np.where(np.eye(N, dtype=bool), np.inf, 0.0)
        self._rngs = self._spawn_rngs(seed)
        self._cache: dict[str, Array] = {}
        self.patterns: tuple[str, ...] = ()
        self._set_pattern_names(_pattern_list(patterns))

        # state; frames[:, 0] is now, frames[:, 1] one step earlier, frames[:, 2] two
        self.frames: Array = np.zeros((E, 3, N, 2))
        self.pattern: Array = np.zeros((E, N, 2))
        self.pattern_ids: IntArray = np.zeros(E, dtype=np.int64)
        self.slots: IntArray = np.tile(np.arange(N, dtype=np.int64), (E, 1))
        self.goals: Array = np.zeros((E, N, 2))  # slot positions of the shared assignment
        self.error: Array = np.zeros(E)  # formation error now (m)
        self.steps: IntArray = np.zeros(E, dtype=np.int64)
        self.travel: Array = np.zeros((E, N))  # metres per robot this episode
        self.episode_collisions: IntArray = np.zeros(E, dtype=np.int64)
        self.episode_return: Array = np.zeros(E)
        self.lower_bound_steps: IntArray = np.zeros(E, dtype=np.int64)
        self.lower_bound_travel: Array = np.zeros(E)
        self.last_robot_collisions: IntArray = np.zeros((E, N), dtype=np.int64)  # last step
        self.contact_fallbacks = 0
        self._obs: F32Array = np.zeros((E, N, self.obs_dim), dtype=np.float32)
        self.reset()

    # ------------------------------------------------------------------ views

    @property
    def positions(self) -> Array:
        """(E, N, 2) positions now. A view of this step's frames: a later step
        writes new arrays and leaves it as it was."""
        return self.frames[:, 0]

    @property
    def prev_positions(self) -> Array:
        """(E, N, 2) positions one step earlier (equal to ``positions`` at a start)."""
        return self.frames[:, 1]

    # ------------------------------------------------------------ pattern set

    def _spawn_rngs(self, seed: int) -> list[np.random.Generator]:
        children = np.random.SeedSequence(seed).spawn(self.n_envs)
        return [np.random.default_rng(c) for c in children]

    def _set_pattern_names(self, names: tuple[str, ...]) -> None:
        for name in names:  # validate every pattern now: a bad one fails here, not mid-run
            if name != RANDOM_PATTERN and name not in self._cache:
                self._cache[name] = make_pattern(name, self.n_robots, self.world)
        self.patterns = names

    def set_patterns(self, patterns: Sequence[str | Path] | str, *, retarget: bool = True) -> None:
        """Switch the pattern set, e.g. to the next pattern of a sequence.

        With ``retarget`` (default) every env draws its new target from the new
        set now and goes on from where its robots stand: the assignment is
        solved afresh and the episode counters (steps, travel, collisions,
        return, bounds) restart, so the next leg is an episode of its own; read
        the new observations with :meth:`observe`. Without it, each env picks
        up the new set at its next reset.
        """
        self._set_pattern_names(_pattern_list(patterns))
        if not retarget:
            return
        ids = np.arange(self.n_envs)
        for e in ids:
            self._draw_pattern(int(e))
        self._begin_episodes(ids)
        if self.build_obs:
            self._obs = self._observe(ids)

    def _draw_pattern(self, e: int) -> None:
        rng = self._rngs[e]
        k = int(rng.integers(len(self.patterns)))
        name = self.patterns[k]
        if name == RANDOM_PATTERN:
            self.pattern[e] = random_pattern(rng, self.n_robots, self.world)
        else:
            self.pattern[e] = self._cache[name]
        self.pattern_ids[e] = k

    # ------------------------------------------------------------------ reset

    def _draw_starts(self, e: int) -> Array:
        """N starts uniform in the arena, pairwise >= start_separation, from env e's generator."""
        rng = self._rngs[e]
        N, side = self.n_robots, self.world.arena_m
        sep2 = self.world.start_separation_m**2
        P = rng.uniform(0.0, side, (N, 2))
        lower = np.tril(np.ones((N, N), dtype=bool), -1)  # j < i
        for _ in range(_MAX_START_DRAWS):
            diff = P[:, None, :] - P[None, :, :]
            close = (np.einsum("ijk,ijk->ij", diff, diff) < sep2) & lower
            bad = close.any(axis=1)  # too close to a lower-numbered robot
            if not bad.any():
                return P
            P[bad] = rng.uniform(0.0, side, (int(bad.sum()), 2))
        raise RuntimeError("could not draw separated starts; the arena is too crowded")

    def reset(
        self, env_ids: NDArray[np.integer] | None = None, *, seed: int | None = None
    ) -> F32Array:
        """Start new episodes in ``env_ids`` (all envs by default); returns obs (E, N, D).

        With ``seed`` the generators of the envs being reset are re-seeded first
        (env e from child e of ``SeedSequence(seed)``, as at construction).
        """
        ids = (
            np.arange(self.n_envs)
            if env_ids is None
            else np.asarray(env_ids, dtype=np.int64).reshape(-1)
        )
        if seed is not None:
            fresh = self._spawn_rngs(seed)
            for e in ids:
                self._rngs[int(e)] = fresh[int(e)]
        self.frames = self.frames.copy()  # leave views handed out before as they were
        self._reset_envs(ids)
        if self.build_obs:
            obs = self._obs.copy()
            obs[ids] = self._observe(ids)
            self._obs = obs
        return self._obs

    def reset_to(
        self, positions: NDArray[np.floating], env_ids: NDArray[np.integer] | None = None
    ) -> F32Array:
        """Start new episodes in ``env_ids`` from given positions (k, N, 2) (scripted scenarios).

        The envs keep their current patterns; their generators are not used.
        Returns obs (E, N, D).
        """
        ids = (
            np.arange(self.n_envs)
            if env_ids is None
            else np.asarray(env_ids, dtype=np.int64).reshape(-1)
        )
        P = np.asarray(positions, dtype=np.float64).reshape(len(ids), self.n_robots, 2)
        frames = self.frames.copy()
        frames[ids] = P[:, None]
        self.frames = frames
        self._begin_episodes(ids)
        if self.build_obs:
            obs = self._obs.copy()
            obs[ids] = self._observe(ids)
            self._obs = obs
        return self._obs

    def _reset_envs(self, ids: IntArray) -> None:
        if len(ids) == 0:
            return
        for e in ids:
            e = int(e)
            self._draw_pattern(e)
            self.frames[e] = self._draw_starts(e)[None]
        self._begin_episodes(ids)

    def _begin_episodes(self, ids: IntArray) -> None:
        """Fresh assignment and counters for ``ids`` from their current positions."""
        P = self.frames[ids, 0]
        C = self.pattern[ids]
        slots = assign_slots_batch(P, C)
        goals = slot_positions(P, C, slots)
        self.slots[ids] = slots
        self.goals[ids] = goals
        self.error[ids] = np.sqrt(((P - goals) ** 2).sum(-1).mean(-1))
        self.steps[ids] = 0
        self.travel[ids] = 0.0
        self.episode_collisions[ids] = 0
        self.episode_return[ids] = 0.0
        if self.compute_bounds:
            v, dt = self.world.v_max_mps, self.world.dt_s
            for e in ids:
                e = int(e)
                travel, steps = lower_bounds(self.frames[e, 0], self.pattern[e], v, dt)
                self.lower_bound_travel[e] = travel
                self.lower_bound_steps[e] = steps

    # ------------------------------------------------------------ observation

    def _observe(self, ids: IntArray | None = None) -> F32Array:
        sel = slice(None) if ids is None else ids
        if not self.build_obs:
            n = self.n_envs if ids is None else len(ids)
            return np.zeros((n, self.n_robots, 0), dtype=np.float32)
        if self.obs_spec.name == "paper":
            obs = paper_observation(self.frames[sel])
        else:
            obs = general_observation(
                self.frames[sel, 0],
                self.frames[sel, 1],
                self.goals[sel],
                k=self.obs_spec.k_neighbours,
                world=self.world,
            )
        return obs.astype(np.float32)

    def observe(self) -> F32Array:
        """The current observation of every robot, (E, N, D) float32."""
        return self._obs

    # ------------------------------------------------------------------- step

    def _clamp(self, actions: NDArray[np.floating]) -> Array:
        a = np.array(actions, dtype=np.float64)  # a copy: never alter the caller's array
        if a.shape != (self.n_envs, self.n_robots, 2):
            raise ValueError(f"actions must be {(self.n_envs, self.n_robots, 2)}, got {a.shape}")
        bad = ~np.isfinite(a).all(axis=-1)
        if bad.any():
            a[bad] = 0.0
        speed = np.sqrt(a[..., 0] ** 2 + a[..., 1] ** 2)
        v = self.world.v_max_mps
        fast = speed > v
        if fast.any():
            a[fast] *= (v / speed[fast])[:, None]
        return a

    def _contacts(self, P0: Array, P1: Array, step_len: Array) -> tuple[Array, BoolArray]:
        """Resolve overlaps after the move P0 -> P1; returns (positions, contact pairs (E,N,N))."""
        E, N = self.n_envs, self.n_robots
        limit = self._two_r - CONTACT_TOL_M
        contact = np.zeros((E, N, N), dtype=bool)
        # A pair can touch only if it starts closer than 2R plus both step lengths.
        dx = P0[:, :, None, 0] - P0[:, None, :, 0]
        dy = P0[:, :, None, 1] - P0[:, None, :, 1]
        reach = limit + step_len[:, :, None] + step_len[:, None, :]
        near = (dx * dx + dy * dy + self._diag_inf) < reach * reach
        cand = np.flatnonzero(near.any(axis=(1, 2)))
        if len(cand) == 0:
            return P1, contact
        swept = swept_pair_distance(P0[cand], P1[cand]) < limit
        hit = swept.any(axis=(1, 2))
        cand, swept = cand[hit], swept[hit]
        if len(cand) == 0:
            return P1, contact
        contact[cand] = swept
        P = P1.copy()
        Pc, P0c = P1[cand].copy(), P0[cand]
        touched = swept
        relax = 1.0
        for _ in range(CONTACT_SWEEPS):
            diff = Pc[:, :, None, :] - Pc[:, None, :, :]  # p_i - p_j
            d = np.sqrt((diff**2).sum(-1) + self._diag_inf)
            over = d < limit
            if not over.any():
                break
            touched = touched | over
            # direction i <- j; a pair on top of each other falls back to its start line
            start = P0c[:, :, None, :] - P0c[:, None, :, :]
            unit = np.where(
                (d > 1e-12)[..., None],
                diff / np.maximum(d, 1e-12)[..., None],
                start / np.maximum(np.linalg.norm(start, axis=-1, keepdims=True), 1e-12),
            )
            push = np.where(over, (0.5 * relax) * (self._two_r - d), 0.0)
            Pc = Pc + (push[..., None] * unit).sum(axis=2)
            relax = CONTACT_OVER_RELAX
        else:
            # jammed: robots still overlapping hold their previous (valid) positions
            for _ in range(N + 1):
                diff = Pc[:, :, None, :] - Pc[:, None, :, :]
                over = np.sqrt((diff**2).sum(-1) + self._diag_inf) < limit
                stuck = over.any(axis=2)
                if not stuck.any():
                    break
                self.contact_fallbacks += int(stuck.sum())
                touched = touched | over
                Pc[stuck] = P0c[stuck]
        P[cand] = Pc
        contact[cand] = touched
        return P, contact

    def _assign(self, P: Array) -> IntArray:
        """The shared assignment, hysteresis included, solving only where it may have changed."""
        keep = previous_assignment_kept(P, self.pattern, self.slots)
        slots = self.slots.copy()
        redo = np.flatnonzero(~keep)
        if len(redo):
            slots[redo] = assign_slots_batch(P[redo], self.pattern[redo], previous=self.slots[redo])
        return slots

    def step(self, actions: NDArray[np.floating]) -> StepResult:
        """Advance every env by one step; see the module docstring for the order of events."""
        cfg, w = self.reward_config, self.world
        a = self._clamp(actions)
        P0 = self.frames[:, 0]
        intended = P0 + a * w.dt_s
        step_len = np.sqrt(a[..., 0] ** 2 + a[..., 1] ** 2) * w.dt_s
        P1, contact = self._contacts(P0, intended, step_len)
        hits = contact.sum(axis=2)  # (E, N) collisions per robot
        collisions: IntArray = hits.sum(axis=1) // 2

        moved = P1 - P0
        self.travel += np.sqrt(moved[..., 0] ** 2 + moved[..., 1] ** 2)

        slots = self._assign(P1)
        goals = slot_positions(P1, self.pattern, slots)
        gap = P1 - goals
        dist = np.sqrt(gap[..., 0] ** 2 + gap[..., 1] ** 2)  # = slot_distances(P1, C, slots)
        error = np.sqrt((dist**2).mean(axis=1))  # = formation_error_batch(P1, C, slots)
        formed = dist.max(axis=1) <= w.formed_tol_m

        reward = cfg.step_penalty + cfg.collision_penalty * hits
        reward = reward + (cfg.beta / self._reach) * (self.error - error)[:, None]
        if cfg.progress_weight:
            before = P0 - self.goals
            after = P1 - self.goals
            prog = np.sqrt(before[..., 0] ** 2 + before[..., 1] ** 2) - np.sqrt(
                after[..., 0] ** 2 + after[..., 1] ** 2
            )
            reward = reward + (cfg.progress_weight / self._reach) * prog
        if cfg.formed_bonus:
            reward = reward + cfg.formed_bonus * formed[:, None]

        frames = np.empty_like(self.frames)  # new array: views handed out stay as they were
        frames[:, 0] = P1
        frames[:, 1:] = self.frames[:, :2]
        self.frames = frames
        self.slots, self.goals, self.error = slots, goals, error
        self.last_robot_collisions = hits
        self.steps += 1
        self.episode_collisions += collisions
        self.episode_return += reward.mean(axis=1)
        truncated = ~formed & (self.steps >= self.step_limit)
        done = formed | truncated

        obs = self._observe()
        episode = None
        ended = np.flatnonzero(done)
        if len(ended):
            episode = EpisodeStats(
                env_ids=ended,
                formed=formed[ended],
                steps=self.steps[ended].copy(),
                travel=self.travel[ended].sum(axis=1),
                collisions=self.episode_collisions[ended].copy(),
                final_error=error[ended].copy(),
                episode_return=self.episode_return[ended].copy(),
                pattern_ids=self.pattern_ids[ended].copy(),
                final_obs=obs[ended],
                lower_bound_steps=self.lower_bound_steps[ended].copy()
                if self.compute_bounds
                else None,
                lower_bound_travel=self.lower_bound_travel[ended].copy()
                if self.compute_bounds
                else None,
            )
            self._reset_envs(ended)
            if self.build_obs:
                obs[ended] = self._observe(ended)
        self._obs = obs
        return StepResult(
            obs=obs,
            reward=reward.astype(np.float32),
            done=done,
            formed=formed,
            truncated=truncated,
            collisions=collisions.astype(np.int64),
            episode=episode,
        )


__all__ = [
    "DEFAULT_REWARD",
    "PAPER_REWARD",
    "RANDOM_PATTERN",
    "BatchWorld",
    "EpisodeStats",
    "RewardConfig",
    "StepResult",
    "previous_assignment_kept",
]
