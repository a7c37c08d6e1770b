"""Rollouts on a local Ray instance: one worker trains the in-process brain, bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig
from trainer.rollout import RolloutMode, env_shares, stage_world
from trainer.train import RunPlan, train

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


def test_one_ray_worker_trains_the_in_process_brain(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray")
    plan = dict(patterns=["line"], out=tmp_path / "b.onnx", episodes=1, write_files=False,
                progress=False)
    here = train(TINY, RunPlan(**plan))  # type: ignore[arg-type]
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False,
             object_store_memory=100 * 1024 * 1024)
    try:
        there = train(TINY, RunPlan(**plan, rollouts=RolloutMode(ray=True, workers=1)))  # type: ignore[arg-type]
    finally:
        ray.shutdown()
    assert not ray.is_initialized()
    assert len(here.curve) >= 2 and len(there.curve) == len(here.curve)
    assert there.rollouts == {"mode": "ray", "workers": 1, "address": "local"}
    for k, v in here.agent.state_dict().items():
        assert torch.equal(v, there.agent.state_dict()[k]), k
    assert [r["episodes"] for r in here.curve] == [r["episodes"] for r in there.curve]
