"""The training world: E independent envs of N disc robots, batch-first numpy.

Public arrays are ``(E, N, ...)`` (envs, robots, ...), in metres, seconds, m/s.
Inside, positions are ``(2, N, E)`` and pair arrays ``(N, N, E)``: the env axis
innermost gives numpy long inner loops (~5x faster than ``(E, N, N, 2)``). Steps
1-3, the move, are one call of :func:`trainer.world.contacts.move`; step 4 is
:func:`runtime.core.assignment.assign_teams` and the general observation
:class:`runtime.core.general_row.GeneralRows`, the very functions every robot runs:
each one source, compiled at install (else run as Python: the same numbers), one
loop over envs without numpy's per-call overhead or scipy's per-env call.

Step (``BatchWorld.step``), in order
    1. **Actions** ``(E, N, 2)`` are velocities in m/s. A robot whose action
       has a non-finite component holds still (NaN/inf -> 0); a faster action
       is scaled down to ``v_max`` (direction kept).
    2. **Kinematics** ``p += a dt`` (paper eq. 2).
    3. **Contact** (:mod:`trainer.world.contacts`): rigid discs of radius R; a pair
       whose straight swept paths come closer than 2R is a *collision*,
       counted once per pair per step and charged to both robots; overlaps
       are pushed apart, so after every step all centres are at least 2R
       apart (to 1e-6 m). Needs ``v_max dt <= R``; other worlds are refused.
       The plane has no walls: the arena only bounds the starts.
    4. **Shared assignment**, solved once per step and used for reward,
       termination and observation alike: ``assign_slots_batch(previous=...)``
       (centred, error-optimal, with hysteresis), every env every step. Slot
       positions, slot distances and the formation error follow from it
       (what ``slot_positions``, ``slot_distances`` and
       ``formation_error_batch`` give for that assignment; tested equal).
    5. **Reward**, per robot: paper eq. 6 plus a per-robot progress term and
       a bonus on the formed step (:func:`trainer.world.reward.step_reward`, which
       documents every term and constant); with ``rank_goals`` the progress is
       toward the rank matching's goals (:func:`trainer.ppo.rank.rank_goals`).
    6. **Termination.** *Formed*: every robot within ``formed_tol`` of its slot
       under the shared assignment (``slot_distances``; the assignment is the
       error-optimal one, up to the hysteresis margin). *Truncated*: the step
       limit is reached without forming. ``done = formed | truncated``.
    7. **Auto-reset.** Envs that are done are reset at once (as gymnasium's
       vector envs do): ``StepResult.obs`` holds the new episode's first
       observation, ``StepResult.episode`` the finished episodes' statistics
       and last observation (``final_obs``).

Starts and patterns
    Each env draws its pattern and starts from its own generator
    (:class:`trainer.world.episodes.EpisodeDraws`; that module says how), so env
    e's sequence of episodes depends on nothing else (not on E, nor on the other
    envs). What a step returns: :class:`trainer.world.episodes.StepResult`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from runtime.conditions import PERFECT, Conditions
from runtime.core.assignment import assign_teams
from runtime.decision.formation import assign_slots_batch, lower_bounds
from runtime.decision.kinematics import Wheels
from runtime.decision.observation import ObservationSpec, general_observation, observe
from runtime.decision.rules import plan_targets
from runtime.decision.settle import Settle, damp_landing, settle_for
from runtime.types import Array, BoolArray, F32Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from trainer.ppo.rank import rank_goals
from trainer.world.contacts import move
from trainer.world.episodes import (
    MAX_START_DENSITY,
    EpisodeDraws,
    EpisodeStats,
    StepResult,
    start_density,
)
from trainer.world.reward import DEFAULT_REWARD, PAPER_REWARD, RewardConfig, step_reward
from trainer.world.sensed import SensedRows


def _env_major(X: Array) -> Array:
    """(2, N, E) -> (E, N, 2), contiguous."""
    return np.ascontiguousarray(X.transpose(2, 1, 0))


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
        reward: RewardConfig = DEFAULT_REWARD,
        seed: int = 0,
        compute_bounds: bool = False,
        step_limit: int | None = None,
        build_obs: bool = True,
        first_env: int = 0,
        rank_goals: bool = False,
        conditions: Conditions = PERFECT,
        hold_steps: int = 0,
        start_pattern: str | Path | None = None,
        crowd: tuple[float, float] | None = None,
    ) -> None:
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        if n_robots < 2:
            raise ValueError(f"n_robots must be >= 2, got {n_robots}")
        if not obs_spec.accepts_team(n_robots):
            raise ValueError(f"observation '{obs_spec.name}' is for {obs_spec.n_robots} robots")
        if world.max_step_m > world.radius_m + 1e-12:  # no robot may cross a centre in a step
            raise ValueError(f"the contact model needs v_max * dt <= R, got {world.max_step_m}")
        if start_density(n_robots, world.arena_m, world) > MAX_START_DENSITY:
            raise ValueError(f"{n_robots} robots do not fit apart in a {world.arena_m} m arena")
        if first_env < 0:
            raise ValueError(f"first_env must be >= 0, got {first_env}")
        if hold_steps < 0:
            raise ValueError(f"hold_steps must be >= 0, got {hold_steps}")
        self.conditions = conditions
        self.hold_steps = int(hold_steps)
        # each env's generator and the pattern set (the starts' pattern checked now)
        self._draws = EpisodeDraws(n_envs, n_robots, world, seed, first_env, start_pattern,
                                   crowd)
        self.n_envs = n_envs
        self.first_env = first_env
        self.n_robots = n_robots
        self.obs_spec = obs_spec
        self.world = world
        self.reward_config = reward
        self.compute_bounds = compute_bounds
        self.step_limit = int(step_limit if step_limit is not None else world.step_limit)
        if self.step_limit < 1:
            raise ValueError(f"step_limit must be >= 1, got {self.step_limit}")
        self.build_obs, self.rank_goals = build_obs, rank_goals
        self.obs_dim: int = obs_spec.dim if build_obs else 0

        E, N = n_envs, n_robots
        self._reach = world.max_step_m
        self._formed_tol2 = world.formed_tol_m**2
        self._no_obs: F32Array = np.zeros((E, N, 0), dtype=np.float32)
        self._no_obs.flags.writeable = False
        self.wheels: Wheels | None = None  # the conditions' actuation, apart from the starts
        if not conditions.acting_perfect:
            wheel_seeds = np.random.SeedSequence((seed, 1)).spawn(first_env + n_envs)
            self.wheels = Wheels(conditions, n_envs, n_robots, wheel_seeds[first_env:],
                                 world.dt_s)
        self._sensed: SensedRows | None = None  # each robot's own view (imperfect sensing)
        self._landing: Settle | None = None
        if build_obs and not conditions.sensing_perfect:
            self._sensed = SensedRows(conditions, obs_spec, n_envs, n_robots, seed, first_env,
                                      world)
            self._landing = settle_for(conditions, True, world)
        self.first_formed: IntArray = np.full(n_envs, -1, dtype=np.int64)
        self.held_steps: IntArray = np.zeros(n_envs, dtype=np.int64)
        self.travel_at_formed: Array = np.zeros(n_envs)
        self.error_at_formed: Array = np.zeros(n_envs)
        self._draws.set_patterns(patterns)

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
        self._C: Array = np.zeros((2, N, E))  # each env's pattern (centred), robot-major
        self._Cc: Array = np.zeros((2, N, E))  # the same centred again, as the assignment does
        self._slots: IntArray = np.zeros((N, E), dtype=np.int64)  # ``slots``, robot-major
        self._potentials: Array = np.zeros((N, E))  # the assignment proof's warm start
        self._dist: Array = np.zeros((N, E))  # |position - slot|
        self._travel: Array = np.zeros((N, E))
        self.plan_steps_left: Array = np.ones(E)  # plan observation: each team's K, as observed
        self._hits: IntArray = np.zeros((N, E), dtype=np.int64)  # collisions of the last step
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

    @property
    def patterns(self) -> tuple[str, ...]:
        """The pattern set's names; ``pattern_ids`` index it."""
        return self._draws.patterns

    def set_patterns(self, patterns: Sequence[str | Path] | str, *, retarget: bool = True) -> None:
        """Switch the pattern set, e.g. to the next pattern of a sequence.

        With ``retarget`` (default) every env draws its new target from the new
        set now and goes on from where its robots stand: the assignment is
        solved afresh and the episode counters (steps, travel, collisions,
        return, bounds) restart, so the next leg is an episode of its own; read
        the new observations with :meth:`observe`. Without it, each env picks
        up the new set at its next reset.
        """
        self._draws.set_patterns(patterns)
        if not retarget:
            return
        ids = np.arange(self.n_envs)
        self.pattern = self.pattern.copy()
        self._draw_patterns(ids)
        self._begin_episodes(ids)
        if self.build_obs:
            self._obs = self._observe(ids)

    def _draw_patterns(self, ids: IntArray) -> None:
        """Each env of ``ids`` draws its next target, in place (the caller owns ``pattern``)."""
        for e in ids:
            e = int(e)
            self.pattern[e], self.pattern_ids[e] = self._draws.pattern(e)

    # ------------------------------------------------------------------ reset

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
            self._draws.reseed(ids, seed)
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
        self._draw_patterns(ids)
        self.frames[ids] = self._draws.starts(ids)[:, None]
        if self.wheels is not None:
            self.wheels.reset(ids)
        self._begin_episodes(ids)

    def _begin_episodes(self, ids: IntArray) -> None:
        """Fresh assignment and counters for ``ids`` from their current positions."""
        P = self.frames[ids, 0]
        slots = assign_slots_batch(P, self.pattern[ids])
        X = P.transpose(2, 1, 0)
        C = self.pattern[ids].transpose(2, 1, 0)
        self._C[:, :, ids] = C
        self._Cc[:, :, ids] = C - C.sum(axis=1, keepdims=True) / self.n_robots  # = centred(C)
        self._slots[:, ids] = slots.T
        self._potentials[:, ids] = 0.0
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
        self.first_formed[ids] = -1
        self.held_steps[ids] = 0
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
        spec = self.obs_spec
        if self._sensed is not None:  # each robot from its own view (trainer.world.sensed)
            if ids is None:
                rows, K = self._sensed.rows(self.frames[:, 0], self.pattern)
                self.plan_steps_left = K.max(axis=1)  # the team's filter: the longest horizon
                return rows
            self._sensed.restart(ids)  # a start: the roll call, the team as it is
        if spec.needs_slots:  # the rows every robot builds (runtime.core.general_row)
            P = self.frames[sel, 0]
            K = None
            if spec.name == "plan":  # the slots in the plan's frame, and its pace
                slots = self._slots.T if ids is None else self._slots[:, ids].T
                G, K = plan_targets(P, self.pattern[sel], slots, spec.travel_weight, self.world)
                self.plan_steps_left[sel] = K
            else:
                G = (self._G if ids is None else self._G[:, :, ids]).transpose(2, 1, 0)
            obs: F32Array = general_observation(P, self.frames[sel, 1], G, spec.k_neighbours,
                                                self.world, steps_left=K, dtype=np.float32)
            return obs
        return observe(self.obs_spec, self.frames[sel], None, None, self.world).astype(np.float32)

    def observe(self) -> F32Array:
        """The current observation of every robot, (E, N, D) float32."""
        return self._obs

    # ------------------------------------------------------------------- step

    def _assign(self, X: Array) -> tuple[IntArray, Array, Array]:
        """The shared assignment at positions ``X`` (2, N, E), once per step.

        Returns (slots (N, E), slot positions (2, N, E), squared slot distances
        (N, E)): what ``assign_slots_batch(previous=...)`` (transposed),
        ``slot_positions`` and ``slot_distances ** 2`` give. The assignment is
        :func:`runtime.core.assignment.assign_teams` on (E, N, 2) views of the
        robot-major arrays (no copy), warm from each env's slot potentials: most
        envs keep their slots, proven optimal, without a solve.
        """
        n = self.n_robots
        slots: IntArray = np.empty_like(self._slots)
        assign_teams(X.transpose(2, 1, 0), self._Cc.transpose(2, 1, 0), self._slots.T, True,
                     self._potentials.T, slots.T)
        total = X.sum(axis=1, keepdims=True)
        Q = np.take_along_axis(self._C, slots[None], axis=1)  # each robot's (centred) slot point
        G = Q + total * (1.0 / n)
        gap = X - G
        return slots, G, gap[0] * gap[0] + gap[1] * gap[1]

    def _advance(
        self,
        P: Array,
        X: Array,
        G: Array,
        dist2: Array,
        hits: IntArray,
        slots: IntArray,
        error: Array,
        reward: Array,
    ) -> None:
        """Make this step's state current: frames shifted, slots, error, counters."""
        frames = np.empty_like(self.frames)  # new array: views handed out stay as they were
        frames[:, 0] = P
        frames[:, 1:] = self.frames[:, :2]
        self.frames = frames
        self._X, self._G, self._dist, self._hits = X, G, np.sqrt(dist2), hits
        self._slots, self.slots, self.error = slots, np.ascontiguousarray(slots.T), error
        self.steps += 1
        self.episode_return += reward.sum(axis=0) * (1.0 / self.n_robots)

    def _done(self, formed: BoolArray) -> tuple[BoolArray, BoolArray]:
        """(truncated, done), (E,) each: the step limit reached unformed; formed or truncated.

        With ``hold_steps`` H, an episode that formed goes on for H more steps (the hold
        window, counted in ``held_steps``) and ends after them."""
        if self.hold_steps:
            ff = self.first_formed
            window = (ff >= 0) & (self.steps > ff)
            self.held_steps += window & formed
            first = np.flatnonzero((ff < 0) & formed)
            ff[first] = self.steps[first]
            self.travel_at_formed[first] = self._travel[:, first].sum(axis=0)
            self.error_at_formed[first] = self.error[first]
            truncated = (self.steps >= self.step_limit) & (ff < 0)
            return truncated, truncated | ((ff >= 0) & (self.steps - ff >= self.hold_steps))
        truncated = self.steps >= self.step_limit
        truncated &= ~formed
        return truncated, formed | truncated

    def _finish(self, ended: IntArray, formed: BoolArray, obs: F32Array) -> EpisodeStats:
        """Statistics of the episodes of ``ended`` (before their reset), from this step's state."""
        bounds = self.compute_bounds
        steps = self.steps[ended]
        travel = self._travel[:, ended].sum(axis=0)
        error = self.error[ended]
        first = held = None
        if self.hold_steps:  # formed: at the first passage; steps: up to it
            first = self.first_formed[ended]
            formed = np.zeros_like(formed)
            formed[ended] = first >= 0
            steps = np.where(first >= 0, first, steps)
            travel = np.where(first >= 0, self.travel_at_formed[ended], travel)
            error = np.where(first >= 0, self.error_at_formed[ended], error)
            held = self.held_steps[ended] / self.hold_steps
        return EpisodeStats(
            ended, formed[ended], steps, travel,
            self.episode_collisions[ended], error, self.episode_return[ended],
            self.pattern_ids[ended], obs[ended], self.frames[ended, 0],
            self.lower_bound_steps[ended] if bounds else None,
            self.lower_bound_travel[ended] if bounds else None,
            first, held,
        )  # fancy indexing copies: the statistics do not change with the world

    def step(self, actions: NDArray[np.floating]) -> StepResult:
        """Advance every env by one step: the steps of the module docstring, in order.

        Shapes inside: robot-major (2, N, E) and (N, E); returned (E, N, ...).
        """
        # 1-3. actions -> velocities (the damped landing of a robot that senses through
        # noise, the conditions' wheels), kinematics, contacts
        if self._landing is not None:
            to_slot = None if self._sensed is None or self.obs_spec.name != "plan" \
                else self._sensed.to_slot
            actions = damp_landing(actions, self._landing, self.world.dt_s, to_slot)
        if self.wheels is not None:
            actions = self.wheels.apply(actions)
        X1, hits, collisions, falls = move(actions, self._X, self._travel, self.world)
        self.episode_collisions += collisions
        self.contact_fallbacks += falls
        slots, G, dist2 = self._assign(X1)  # 4. shared assignment
        P1 = _env_major(X1)
        error = np.sqrt(dist2.sum(axis=0) * (1.0 / self.n_robots))  # = formation_error_batch
        formed = dist2.max(axis=0) <= self._formed_tol2
        cfg, reach = self.reward_config, self._reach  # 5. reward, (N, E)
        G0, d0, d1 = self._G, self._dist, None  # progress: toward the rank goals, if asked
        if self.rank_goals:
            (G0, d0), d1 = rank_goals(self._X, self._C), rank_goals(X1, self._C)[1]
        reward = step_reward(cfg, hits, self.error, error, X1, G0, d0, formed, reach, d1, self._X,
                             self.world.min_separation_m)
        self._advance(P1, X1, G, dist2, hits, slots, error, reward)
        truncated, done = self._done(formed)  # 6. termination

        obs = self._observe()
        episode = None
        ended = np.flatnonzero(done)
        if len(ended):  # 7. auto-reset of the finished envs
            episode = self._finish(ended, formed, obs)
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
    "BatchWorld",
    "RewardConfig",
]
