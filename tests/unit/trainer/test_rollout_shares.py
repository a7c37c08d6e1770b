"""Rollout workers' shares of the envs (a run on Ray: tests/integration/test_ray_rollouts.py)."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig
from trainer.rollout import env_shares, stage_world

TINY = TrainConfig(n_robots=4, n_envs=4, rollout_steps=8, minibatch=64, ae_steps=2,
                   policy_steps=2, value_steps=2, eval_every=2, eval_episodes=4, seed=3)


def test_shares_draw_the_starts_of_one_batch() -> None:
    """K workers' shares of the envs start where one process's envs start."""
    whole, _ = stage_world(TINY.with_(n_envs=5), DEFAULT_WORLD, "line", 0, 0)
    for a, b in env_shares(5, 2):
        part, _ = stage_world(TINY.with_(n_envs=5), DEFAULT_WORLD, "line", 0, 0, (a, b))
        assert np.array_equal(part.positions, whole.positions[a:b])
        assert np.array_equal(part.steps, whole.steps[a:b])
    with pytest.raises(ValueError):
        env_shares(2, 3)


def test_a_runs_crowded_starts_reach_its_worlds_and_its_shares() -> None:
    """``crowded_share`` / ``crowded_arena_m`` start the run's worlds in the small square, the
    shares of a batch as the whole."""
    cfg = TINY.with_(n_envs=6, crowded_share=1.0, crowded_arena_m=1.5)
    whole, _ = stage_world(cfg, DEFAULT_WORLD, "line", 0, 0)
    lo, hi = 0.5 * (DEFAULT_WORLD.arena_m - 1.5), 0.5 * (DEFAULT_WORLD.arena_m + 1.5)
    assert ((whole.positions >= lo) & (whole.positions <= hi)).all()
    part, _ = stage_world(cfg, DEFAULT_WORLD, "line", 0, 0, (2, 6))
    assert np.array_equal(part.positions, whole.positions[2:6])
    spread, _ = stage_world(TINY.with_(n_envs=6), DEFAULT_WORLD, "line", 0, 0)
    assert np.ptp(spread.positions, axis=1).max() > 1.5
