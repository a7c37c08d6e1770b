"""The training world: E independent envs of N disc robots, batch-first numpy.

Every public array is shaped ``(E, N, ...)`` (envs, robots, ...); nothing loops
over robots, and the only loop over envs on the hot path is the one inside
``assign_slots_batch`` (scipy has no batched assignment solver). Units: metres,
seconds, metres per second.

Inside, the step keeps positions as ``(2, N, E)`` (component, robot, env) and
pair arrays as ``(N, N, E)``: at these sizes numpy's cost is its inner loops,
and with the env axis innermost a pairwise difference runs ~5x faster than
over ``(E, N, N, 2)`` (whose innermost axis has length 2), and a reduction
over robots ~7x faster than over a short trailing axis (measured here).

Step (``BatchWorld.step``), in order
    1. **Actions** ``(E, N, 2)`` are velocities in m/s. A robot whose action
       has a non-finite component holds still (NaN/inf -> 0); a faster action
       is scaled down to ``v_max`` (direction kept).
    2. **Kinematics** ``p += a dt`` (paper eq. 2).
    3. **Contact.** Robots are rigid discs of radius R: a pair whose straight
       swept paths come closer than 2R during the step (the closest approach of
       :func:`runtime.formation.swept_pair_distance`, the definition behind
       ``count_collisions``, computed here in the layout above; a test holds
       the two equal) is a *collision* and counted, one per pair per step, and
       charged to both robots. Overlaps left at the end of the move
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
       previous (valid) positions (counted in ``BatchWorld.contact_fallbacks``);
       so after every step all centres are at least 2R apart (to 1e-6 m).
       The projection needs ``v_max dt <= R`` (the default is exactly R):
       then no centre can cross another's within a step, so a push never
       swaps two robots; other worlds are refused. The plane has no walls:
       the arena only bounds the starts.
    4. **Shared assignment**, solved once per step and used for reward,
       termination and observation alike: ``assign_slots_batch(previous=...)``
       (centred, error-optimal, with hysteresis), every env every step. Slot
       positions, slot distances and the formation error follow from it
       (what ``slot_positions``, ``slot_distances`` and
       ``formation_error_batch`` give for that assignment; tested equal).
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
    collision_penalty -1.0   R_c per collision the robot is part of: 20 steps of
                             fatigue, one full-speed step of the robot's own
                             progress. A detour of a few steps is cheaper than a
                             contact, and pushing into a neighbour (no progress,
                             -1 every step) never pays.
    beta             1.0     weight of r_p (team progress, change form, above).
                             Summed over an episode it is the initial error in
                             steps (about 30-40 from uniform starts here): a
                             dense team signal on the paper's own term.
    progress_weight  1.0     per-robot progress toward its own slot: the
                             training-only credit signal that, in the experiment
                             quoted in issue 2, made the difference between a
                             circle formed within 2 minutes of training and one
                             not formed after 12. 0 gives the paper's reward.
    formed_bonus     1.0     once, to every robot, on the formed step: marks
                             success in the return; the fatigue already makes
                             ending early pay, so it stays modest.
    ================ ======= =====================================================

    ``PAPER_REWARD`` is eq. 6 alone (no progress term, no bonus).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from runtime.formation import assign_slots_batch, lower_bounds
from runtime.observation import ObservationSpec, general_observation, paper_observation
from runtime.patterns import make_pattern, random_pattern
from runtime.types import Array, BoolArray, F32Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

RANDOM_PATTERN = "random"


def check_pattern(name: str | Path, n_robots: int, world: WorldConfig = DEFAULT_WORLD) -> None:
    """Raise PatternError (one line) unless ``name`` is usable: a built-in, a file, or "random"."""
    if str(name) != RANDOM_PATTERN:
        make_pattern(name, n_robots, world)
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
    final_positions: Array  # (k, N, 2) where the robots ended (m)
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


def _robot_major(P: Array) -> Array:
    """(E, N, 2) -> (2, N, E), contiguous."""
    return np.ascontiguousarray(P.transpose(2, 1, 0))


def _env_major(X: Array) -> Array:
    """(2, N, E) -> (E, N, 2), contiguous."""
    return np.ascontiguousarray(X.transpose(2, 1, 0))


# ------------------------------------------------------------------- contacts


@functools.lru_cache(maxsize=8)
def robot_pairs(n: int) -> tuple[IntArray, IntArray, Array]:
    """The n(n-1)/2 pairs i < j in ``np.triu_indices(n, 1)`` order: (i, j, D) with
    ``D`` (P, n) the difference operator, ``(D @ x)[p] = x[j_p] - x[i_p]`` exactly
    (each row holds one +1 and one -1, so the product rounds once, like ``-``)."""
    i, j = np.triu_indices(n, 1)
    D = np.zeros((len(i), n))
    D[np.arange(len(i)), j] = 1.0
    D[np.arange(len(i)), i] = -1.0
    D.flags.writeable = False
    return i.astype(np.int64), j.astype(np.int64), D


def swept_contacts(X0: Array, U: Array, limit_m: float) -> BoolArray:
    """Pairs whose closest approach during the straight moves X0 -> X0 + U is below ``limit_m``.

    ``X0``, ``U``: (2, N, E) positions and displacements. Returns (P, E) over
    the pairs of :func:`robot_pairs`. The closest approach is that of
    :func:`runtime.formation.swept_pair_distance` (relative motion
    ``d(s) = d0 + s dd``, ``s`` in [0, 1]), computed pair-major.
    """
    D = robot_pairs(X0.shape[1])[2]
    d0 = D @ X0  # (2, P, E): x_j - x_i
    dd = D @ U
    a = d0[0] * d0[0] + d0[1] * d0[1]
    b = d0[0] * dd[0] + d0[1] * dd[1]
    c = dd[0] * dd[0] + dd[1] * dd[1]
    s = np.divide(-b, c, out=np.zeros_like(b), where=c > 0.0)  # the time of closest approach
    np.clip(s, 0.0, 1.0, out=s)
    hit: BoolArray = a + s * (2.0 * b + s * c) < limit_m * limit_m
    return hit


# ----------------------------------------------------------------------- world


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
        self._formed_tol2 = world.formed_tol_m**2
        self._diag = np.arange(N)
        self._lower = np.tril(np.ones((N, N), dtype=bool), -1)  # [i, j]: j < i
        self._env_col = np.arange(E)[:, None]
        self._no_obs: F32Array = np.zeros((E, N, 0), dtype=np.float32)
        self._no_obs.flags.writeable = False
        self._rngs = self._spawn_rngs(seed)
        self._cache: dict[str, Array] = {}
        self.patterns: tuple[str, ...] = ()
        self._set_pattern_names(_pattern_list(patterns))

        # public state, (E, ...) first; frames[:, 0] now, [:, 1] one step earlier, [:, 2] two
        self.frames: Array = np.zeros((E, 3, N, 2))
        self.pattern: Array = np.zeros((E, N, 2))  # each env's target, centred
        self.pattern_ids: IntArray = np.zeros(E, dtype=np.int64)
        self.slots: IntArray = np.tile(np.arange(N, dtype=np.int64), (E, 1))
        self.error: Array = np.zeros(E)  # formation error now (m)
        self.steps: IntArray = np.zeros(E, dtype=np.int64)
        self.episode_collisions: IntArray = np.zeros(E, dtype=np.int64)
        self.episode_return: Array = np.zeros(E)
        self.lower_bound_steps: IntArray = np.zeros(E, dtype=np.int64)
        self.lower_bound_travel: Array = np.zeros(E)
        self.contact_fallbacks = 0  # robots held still because a jam did not clear
        # hot-path state, robot-major: (2, N, E) and (N, E)
        self._X: Array = np.zeros((2, N, E))  # positions now
        self._G: Array = np.zeros((2, N, E))  # each robot's slot in world coordinates
        self._dist: Array = np.zeros((N, E))  # |position - slot|
        self._travel: Array = np.zeros((N, E))
        # shared "no contact this step" results, read-only so they can be handed out
        self._no_hits: IntArray = np.zeros((N, E), dtype=np.int64)
        self._no_collisions: IntArray = np.zeros(E, dtype=np.int64)
        self._no_hits.flags.writeable = False
        self._no_collisions.flags.writeable = False
        self._hits: IntArray = self._no_hits
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

    @property
    def goals(self) -> Array:
        """(E, N, 2) each robot's slot in world coordinates (the shared assignment's)."""
        return _env_major(self._G)

    @property
    def travel(self) -> Array:
        """(E, N) distance each robot travelled this episode (m)."""
        return np.ascontiguousarray(self._travel.T)

    @property
    def last_robot_collisions(self) -> IntArray:
        """(E, N) collisions each robot took part in during the last step."""
        return np.ascontiguousarray(self._hits.T)

    # ------------------------------------------------------------ pattern set

    def _spawn_rngs(self, seed: int) -> list[np.random.Generator]:
        children = np.random.SeedSequence(seed).spawn(self.n_envs)
        return [np.random.default_rng(c) for c in children]

    def _set_pattern_names(self, names: tuple[str, ...]) -> None:
        for name in names:  # validate every pattern now: a bad one fails here, not mid-run
            if name != RANDOM_PATTERN and name not in self._cache:
                C = make_pattern(name, self.n_robots, self.world)
                self._cache[name] = C - C.mean(axis=0)  # centred, as the assignment centres it
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
        self.pattern = self.pattern.copy()
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
            C = random_pattern(rng, self.n_robots, self.world)
            self.pattern[e] = C - C.mean(axis=0)
        else:
            self.pattern[e] = self._cache[name]
        self.pattern_ids[e] = k

    # ------------------------------------------------------------------ reset

    def _draw_starts(self, ids: IntArray) -> Array:
        """N starts per env of ``ids``, uniform in the arena, pairwise >= start_separation.

        Each env draws from its own generator only, and what it redraws depends
        only on its own points, so its starts do not depend on which other envs
        reset with it. Returns (k, N, 2).
        """
        rngs = [self._rngs[int(e)] for e in ids]
        N, side = self.n_robots, self.world.arena_m
        sep2 = self.world.start_separation_m**2
        P = np.stack([rng.uniform(0.0, side, (N, 2)) for rng in rngs])
        for _ in range(_MAX_START_DRAWS):
            diff = P[:, :, None, :] - P[:, None, :, :]
            close = np.einsum("eijk,eijk->eij", diff, diff) < sep2
            bad = (close & self._lower).any(axis=2)  # too close to a lower-numbered robot
            if not bad.any():
                return P
            for r in np.flatnonzero(bad.any(axis=1)):
                P[r, bad[r]] = rngs[r].uniform(0.0, side, (int(bad[r].sum()), 2))
        raise RuntimeError("could not draw separated starts; the arena is too crowded")

    def _ids(self, env_ids: NDArray[np.integer] | None) -> IntArray:
        if env_ids is None:
            return np.arange(self.n_envs)
        return np.asarray(env_ids, dtype=np.int64).reshape(-1)

    def reset(
        self, env_ids: NDArray[np.integer] | None = None, *, seed: int | None = None
    ) -> F32Array:
        """Start new episodes in ``env_ids`` (all envs by default); returns obs (E, N, D).

        With ``seed`` the generators of the envs being reset are re-seeded first
        (env e from child e of ``SeedSequence(seed)``, as at construction).
        """
        ids = self._ids(env_ids)
        if seed is not None:
            fresh = self._spawn_rngs(seed)
            for e in ids:
                self._rngs[int(e)] = fresh[int(e)]
        self.frames = self.frames.copy()  # leave arrays handed out before as they were
        self.pattern = self.pattern.copy()
        self._reset_envs(ids)
        return self._refresh_obs(ids)

    def reset_to(
        self, positions: NDArray[np.floating], env_ids: NDArray[np.integer] | None = None
    ) -> F32Array:
        """Start new episodes in ``env_ids`` from given positions (k, N, 2) (scripted scenarios).

        The envs keep their current patterns; their generators are not used.
        Returns obs (E, N, D).
        """
        ids = self._ids(env_ids)
        P = np.asarray(positions, dtype=np.float64).reshape(len(ids), self.n_robots, 2)
        frames = self.frames.copy()
        frames[ids] = P[:, None]
        self.frames = frames
        self._begin_episodes(ids)
        return self._refresh_obs(ids)

    def _refresh_obs(self, ids: IntArray) -> F32Array:
        if self.build_obs:
            obs = self._obs.copy()
            obs[ids] = self._observe(ids)
            self._obs = obs
        return self._obs

    def _reset_envs(self, ids: IntArray) -> None:
        """New pattern and starts for ``ids``, in place (the caller owns fresh arrays)."""
        if len(ids) == 0:
            return
        for e in ids:
            self._draw_pattern(int(e))
        self.frames[ids] = self._draw_starts(ids)[:, None]
        self._begin_episodes(ids)

    def _begin_episodes(self, ids: IntArray) -> None:
        """Fresh assignment and counters for ``ids`` from their current positions."""
        P = self.frames[ids, 0]
        slots = assign_slots_batch(P, self.pattern[ids])
        X = P.transpose(2, 1, 0)
        Q = self.pattern[ids[:, None], slots].transpose(2, 1, 0)  # the (centred) slot points
        G = Q + X.sum(axis=1, keepdims=True) * (1.0 / self.n_robots)  # = slot_positions(...)
        gap = X - G
        dist2 = gap[0] * gap[0] + gap[1] * gap[1]
        self.slots = self.slots.copy()  # arrays handed out stay as they were
        self.slots[ids] = slots
        self.error = self.error.copy()
        self.error[ids] = np.sqrt(dist2.sum(axis=0) * (1.0 / self.n_robots))
        self._X[:, :, ids] = X
        self._G[:, :, ids] = G
        self._dist[:, ids] = np.sqrt(dist2)
        self._travel[:, ids] = 0.0
        self.steps[ids] = 0
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
            return self._no_obs if ids is None else self._no_obs[: len(ids)]
        if self.obs_spec.name == "paper":
            obs = paper_observation(self.frames[sel])
        else:
            goals = self._G.transpose(2, 1, 0)
            obs = general_observation(
                self.frames[sel, 0],
                self.frames[sel, 1],
                goals[sel],
                k=self.obs_spec.k_neighbours,
                world=self.world,
            )
        return obs.astype(np.float32)

    def observe(self) -> F32Array:
        """The current observation of every robot, (E, N, D) float32."""
        return self._obs

    # ------------------------------------------------------------------- step

    def _velocities(self, actions: NDArray[np.floating]) -> Array:
        """Actions as robot-major velocities (2, N, E), scaled down to v_max where faster.

        A robot whose action is not finite (or so large its square overflows) holds still.
        """
        shape = (self.n_envs, self.n_robots, 2)
        a = np.asarray(actions)
        if a.shape != shape:
            raise ValueError(f"actions must be {shape}, got {a.shape}")
        V = _robot_major(a.astype(np.float64, copy=False))  # a copy: the caller's is untouched
        speed2 = V[0] * V[0] + V[1] * V[1]
        finite = np.isfinite(speed2)
        if not finite.all():
            V[:, ~finite] = 0.0
            speed2[~finite] = 0.0
        v = self.world.v_max_mps
        V *= v / np.fmax(np.sqrt(speed2), v)  # min(1, v_max / |a|): direction kept
        return V

    def _resolve(self, X0: Array, X1: Array, hit: BoolArray) -> tuple[Array, BoolArray]:
        """Push overlapping discs apart in the envs of ``hit`` (N, N, k); (2, N, k) arrays.

        Returns the resolved positions and every pair that touched. Two centres
        exactly on top of each other have no centre line to push along; they are
        left to the hold-still fallback (it never happens with real-valued motion).
        """
        limit2 = (self._two_r - CONTACT_TOL_M) ** 2
        X = X1.copy()
        touched = hit.copy()
        d_idx = self._diag
        half_push = 0.5
        for _ in range(CONTACT_SWEEPS):
            diff = X[:, :, None, :] - X[:, None, :, :]  # [k, i, j]: x_i - x_j
            d2 = diff[0] * diff[0] + diff[1] * diff[1]
            d2[d_idx, d_idx] = 1e18  # no robot pushes itself
            over = d2 < limit2
            if not over.any():
                return X, touched
            touched |= over
            # each robot of an overlapping pair moves (2R - d) / 2 along the centre line
            push = over * (half_push * (self._two_r / np.sqrt(np.fmax(d2, 1e-24)) - 1.0))
            X += np.einsum("kije,ije->kie", diff, push)
            half_push = 0.5 * CONTACT_OVER_RELAX
        # jammed: robots still overlapping hold their previous (valid) positions
        for _ in range(self.n_robots + 1):
            diff = X[:, :, None, :] - X[:, None, :, :]
            d2 = diff[0] * diff[0] + diff[1] * diff[1]
            d2[d_idx, d_idx] = 1e18
            over = d2 < limit2
            stuck = over.any(axis=1)
            if not stuck.any():
                break
            self.contact_fallbacks += int(stuck.sum())
            touched |= over
            X[:, stuck] = X0[:, stuck]
        return X, touched

    def step(self, actions: NDArray[np.floating]) -> StepResult:
        """Advance every env by one step; see the module docstring for the order of events."""
        cfg, w = self.reward_config, self.world
        V = self._velocities(actions)
        X0 = self._X
        U = V * w.dt_s
        X1 = X0 + U

        # contacts: collisions from the swept paths, overlaps pushed apart
        hit = swept_contacts(X0, U, self._two_r - CONTACT_TOL_M)  # (P, E)
        touched_envs = np.flatnonzero(hit.any(axis=0))
        hits, collisions = self._no_hits, self._no_collisions
        if len(touched_envs):
            k = touched_envs
            pi, pj, _ = robot_pairs(self.n_robots)
            pairs = np.zeros((self.n_robots, self.n_robots, len(k)), dtype=bool)
            pairs[pi, pj] = pairs[pj, pi] = hit[:, k]
            Xk, touched = self._resolve(X0[:, :, k], X1[:, :, k], pairs)
            X1[:, :, k] = Xk
            hits = np.zeros_like(self._no_hits)
            hits[:, k] = touched.sum(axis=1)
            collisions = hits.sum(axis=0) // 2
            self.episode_collisions += collisions
        moved = X1 - X0
        self._travel += np.sqrt(moved[0] * moved[0] + moved[1] * moved[1])

        # the shared assignment, solved once; it gives slots, slot distances, error, formed
        P1 = _env_major(X1)
        slots = assign_slots_batch(P1, self.pattern, previous=self.slots)
        Q = _robot_major(self.pattern[self._env_col, slots])  # each robot's (centred) slot point
        G = Q + X1.sum(axis=1, keepdims=True) * (1.0 / self.n_robots)  # = slot_positions(...)
        gap = X1 - G
        dist2 = gap[0] * gap[0] + gap[1] * gap[1]  # = slot_distances(...) ** 2, (N, E)
        error = np.sqrt(dist2.sum(axis=0) * (1.0 / self.n_robots))  # = formation_error_batch
        formed = dist2.max(axis=0) <= self._formed_tol2
        dist = np.sqrt(dist2)

        # reward, (N, E): R_g + R_c * hits + beta * r_p + w * progress (+ bonus)
        reward = cfg.collision_penalty * hits + cfg.step_penalty
        reward += (cfg.beta / self._reach) * (self.error - error)
        if cfg.progress_weight:
            after = X1 - self._G  # to the slot shown in the last observation
            after_len = np.sqrt(after[0] * after[0] + after[1] * after[1])
            reward += (cfg.progress_weight / self._reach) * (self._dist - after_len)
        if cfg.formed_bonus and formed.any():
            reward[:, formed] += cfg.formed_bonus

        frames = np.empty_like(self.frames)  # new array: views handed out stay as they were
        frames[:, 0] = P1
        frames[:, 1:] = self.frames[:, :2]
        self.frames = frames
        self._X, self._G, self._dist, self._hits = X1, G, dist, hits
        self.slots, self.error = slots, error
        self.steps += 1
        self.episode_return += reward.sum(axis=0) * (1.0 / self.n_robots)
        truncated = self.steps >= self.step_limit
        truncated &= ~formed
        done = formed | truncated

        obs = self._observe()
        episode = None
        ended = np.flatnonzero(done)
        if len(ended):
            episode = EpisodeStats(
                env_ids=ended,
                formed=formed[ended],
                steps=self.steps[ended].copy(),
                travel=self._travel[:, ended].sum(axis=0),
                collisions=self.episode_collisions[ended].copy(),
                final_error=error[ended].copy(),
                episode_return=self.episode_return[ended].copy(),
                pattern_ids=self.pattern_ids[ended].copy(),
                final_obs=obs[ended],
                final_positions=P1[ended],
                lower_bound_steps=self.lower_bound_steps[ended].copy()
                if self.compute_bounds
                else None,
                lower_bound_travel=self.lower_bound_travel[ended].copy()
                if self.compute_bounds
                else None,
            )
            self.pattern = self.pattern.copy()  # arrays handed out stay as they were
            self._reset_envs(ended)
            if self.build_obs:
                obs[ended] = self._observe(ended)
        self._obs = obs
        return StepResult(
            obs=obs,
            reward=np.ascontiguousarray(reward.T, dtype=np.float32),
            done=done,
            formed=formed,
            truncated=truncated,
            collisions=collisions,
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
    "check_pattern",
    "robot_pairs",
    "swept_contacts",
]
