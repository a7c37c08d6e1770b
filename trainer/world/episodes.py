"""The training world's episodes: what each one starts from, and what the world reports.

Starts and patterns
    Each env owns a ``numpy.random.Generator`` spawned from ``SeedSequence(seed)``
    (child e for env e), used only by that env's resets: env e's sequence of
    episodes depends on nothing else (not on E, nor on the other envs). With
    ``first_env = a`` the envs are children a, a+1, ...: a world holding envs
    [a, b) of a larger batch (one Ray worker's share) draws what that batch's
    envs would. A reset draws the pattern (one of the set, uniformly) and then
    N starts uniform in the arena, pairwise >= ``start_separation`` apart
    (every robot too close to a lower-numbered one is redrawn), or, with
    ``start_pattern``, that pattern formed at the arena's centre (each robot within
    half the formed tolerance of its point: a transition, as from one pattern of a
    sequence to the next). Patterns are ``make_pattern(name, N)`` (cached);
    ``"random"`` draws a ``random_pattern``.

Crowded starts
    With ``crowd = (share, side)`` an env's reset first draws whether this episode starts
    crowded (with probability ``share``): its N starts are then drawn in a square of ``side``
    metres at the arena's centre, still pairwise >= ``start_separation`` apart. A crowded team
    has to pass its neighbours on the way, so the states where robots meet, rare from starts
    spread over the whole arena, come often: training only (the held-out evaluation and
    ``eval`` keep the arena). Without ``crowd`` no extra draw is made, so every seed draws
    what it drew before.

What the world reports
    :class:`StepResult` for every step of :class:`trainer.world.training_world.BatchWorld`,
    with :class:`EpisodeStats` for the envs whose episodes ended in it.

Arrays are ``(E, N, ...)`` or ``(k, N, ...)`` (envs, robots, ...), in metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from runtime.decision.patterns import make_pattern, random_pattern
from runtime.types import Array, BoolArray, F32Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "MAX_START_DENSITY",
    "RANDOM_PATTERN",
    "EpisodeDraws",
    "EpisodeStats",
    "StepResult",
    "check_crowd",
    "check_pattern",
    "pattern_list",
    "start_density",
]

RANDOM_PATTERN = "random"
"""Pattern name that draws a fresh random shape at every reset."""

_MAX_START_DRAWS = 10_000


def check_pattern(name: str | Path, n_robots: int, world: WorldConfig = DEFAULT_WORLD) -> None:
    """Raise PatternError (one line) unless ``name`` is usable: a built-in, a file, or "random"."""
    if str(name) != RANDOM_PATTERN:
        make_pattern(name, n_robots, world)


def pattern_list(patterns: Sequence[str | Path] | str | Path) -> tuple[str, ...]:
    """A pattern set as names: one name, or several (at least one)."""
    if isinstance(patterns, str | Path):
        return (str(patterns),)
    names = tuple(str(p) for p in patterns)
    if not names:
        raise ValueError("the pattern set is empty")
    return names


class EpisodeStats(NamedTuple):
    """Statistics of the k envs whose episodes ended this step (arrays of length k)."""

    env_ids: IntArray  # (k,) which envs
    formed: BoolArray  # (k,) formed (else truncated)
    steps: IntArray  # (k,) steps taken
    travel: Array  # (k,) total distance travelled by all robots (m)
    collisions: IntArray  # (k,) colliding pairs summed over the episode
    final_error: Array  # (k,) formation error at the end (m; with hold_steps, at the first passage)
    episode_return: Array  # (k,) sum over steps of the robots' mean reward
    pattern_ids: IntArray  # (k,) index into the pattern set
    final_obs: F32Array  # (k, N, D) last observation, before the reset
    final_positions: Array  # (k, N, 2) where the robots ended (m)
    lower_bound_steps: IntArray | None  # (k,) when compute_bounds
    lower_bound_travel: Array | None  # (k,) metres, when compute_bounds
    first_formed: IntArray | None = None  # (k,) step first formed (-1: never), with hold_steps
    held: Array | None = None  # (k,) share of the hold window's steps formed, with hold_steps


class StepResult(NamedTuple):
    """What one ``BatchWorld.step`` returns."""

    obs: F32Array  # (E, N, D), after auto-reset of the envs that finished
    reward: F32Array  # (E, N)
    done: BoolArray  # (E,) formed | truncated
    formed: BoolArray  # (E,)
    truncated: BoolArray  # (E,)
    collisions: IntArray  # (E,) colliding pairs this step
    episode: EpisodeStats | None  # the envs that finished this step, else None


class EpisodeDraws:
    """Each env's generator and the pattern set: what a reset of E envs x N robots draws.

    The world's resets call it; each env draws from its own generator alone (see the
    module docstring).
    """

    def __init__(
        self,
        n_envs: int,
        n_robots: int,
        world: WorldConfig,
        seed: int,
        first_env: int = 0,
        start_pattern: str | Path | None = None,
        crowd: tuple[float, float] | None = None,
    ) -> None:
        self.n_envs, self.n_robots, self.first_env, self.world = n_envs, n_robots, first_env, world
        self.crowd = check_crowd(crowd, n_robots, world)
        self.start: Array | None = None  # (N, 2) a formed pattern every episode starts in (m)
        if start_pattern is not None and str(start_pattern) != RANDOM_PATTERN:
            start = make_pattern(start_pattern, n_robots, world)
            self.start = start - start.mean(axis=0) + 0.5 * world.arena_m
        self._lower = np.tril(np.ones((n_robots, n_robots), dtype=bool), -1)  # [i, j]: j < i
        self.rngs = self._spawn_rngs(seed)
        self._cache: dict[str, Array] = {}
        self.patterns: tuple[str, ...] = ()

    def _spawn_rngs(self, seed: int) -> list[np.random.Generator]:
        # env e is child first_env + e: a share of a larger batch draws what that batch would
        children = np.random.SeedSequence(seed).spawn(self.first_env + self.n_envs)
        children = children[self.first_env :]
        return [np.random.default_rng(c) for c in children]

    def reseed(self, ids: IntArray, seed: int) -> None:
        """The generators of ``ids`` afresh: env e from child e of ``SeedSequence(seed)``."""
        fresh = self._spawn_rngs(seed)
        for e in ids:
            self.rngs[int(e)] = fresh[int(e)]

    def set_patterns(self, patterns: Sequence[str | Path] | str) -> None:
        """The pattern set the next draws choose from."""
        names = pattern_list(patterns)
        for name in names:  # validate every pattern now: a bad one fails here, not mid-run
            if name != RANDOM_PATTERN and name not in self._cache:
                C = make_pattern(name, self.n_robots, self.world)
                self._cache[name] = C - C.mean(axis=0)  # centred, as the assignment centres it
        self.patterns = names

    def pattern(self, e: int) -> tuple[Array, int]:
        """Env ``e``'s next target, centred (N, 2) m, and its index in the pattern set."""
        rng = self.rngs[e]
        k = int(rng.integers(len(self.patterns)))
        name = self.patterns[k]
        if name == RANDOM_PATTERN:
            C = random_pattern(rng, self.n_robots, self.world)
            return C - C.mean(axis=0), k
        return self._cache[name], k

    def starts(self, ids: IntArray) -> Array:
        """N starts per env of ``ids``, uniform in the arena, pairwise >= start_separation;
        with a start pattern, that pattern formed at the arena's centre, each robot within
        half the formed tolerance of its point (a team that has just formed it).

        Each env draws from its own generator only, and what it redraws depends
        only on its own points, so its starts do not depend on which other envs
        reset with it. Returns (k, N, 2).
        """
        rngs = [self.rngs[int(e)] for e in ids]
        if self.start is not None:
            half = 0.5 * self.world.formed_tol_m
            out = []
            for rng in rngs:
                r = half * np.sqrt(rng.uniform(0.0, 1.0, self.n_robots))
                a = rng.uniform(0.0, 2.0 * math.pi, self.n_robots)
                out.append(self.start + np.stack([r * np.cos(a), r * np.sin(a)], axis=1))
            return np.stack(out)
        N, arena = self.n_robots, self.world.arena_m
        side = np.full(len(rngs), arena)
        if self.crowd is not None:
            share, crowded = self.crowd
            side[[rng.uniform() < share for rng in rngs]] = crowded
        lo = (0.5 * (arena - side))[:, None, None]  # each env's square, centred in the arena
        sep2 = self.world.start_separation_m**2
        P = np.stack([rng.uniform(0.0, s, (N, 2)) for rng, s in zip(rngs, side, strict=True)])
        P = P + lo
        for _ in range(_MAX_START_DRAWS):
            diff = P[:, :, None, :] - P[:, None, :, :]
            close = np.einsum("eijk,eijk->eij", diff, diff) < sep2
            bad = (close & self._lower).any(axis=2)  # too close to a lower-numbered robot
            if not bad.any():
                return P
            for r in np.flatnonzero(bad.any(axis=1)):
                redraw = rngs[r].uniform(0.0, side[r], (int(bad[r].sum()), 2))
                P[r, bad[r]] = redraw + lo[r, 0]
        raise RuntimeError("could not draw separated starts; the arena is too crowded")


MAX_START_DENSITY = 0.3
"""The most of a start square that N discs of the start separation may cover."""


def start_density(n_robots: int, side_m: float, world: WorldConfig) -> float:
    """The share of a square of ``side_m`` that N discs of the start separation cover."""
    return n_robots * math.pi * (world.start_separation_m / 2.0) ** 2 / side_m**2


def check_crowd(crowd: tuple[float, float] | None, n_robots: int,
                world: WorldConfig) -> tuple[float, float] | None:
    """``crowd`` as (share, side) if usable, None for none; ValueError (one line) if not."""
    if crowd is None or crowd[0] == 0:
        return None
    share, side = float(crowd[0]), float(crowd[1])
    if not (math.isfinite(share) and 0 < share <= 1):
        raise ValueError(f"the crowded share must be in [0, 1], got {share}")
    if not (math.isfinite(side) and 0 < side <= world.arena_m):
        raise ValueError(f"the crowded square must be in (0, {world.arena_m}] m, got {side}")
    if start_density(n_robots, side, world) > MAX_START_DENSITY:
        raise ValueError(f"{n_robots} robots do not fit apart in a crowded square of {side} m")
    return share, side
