"""A tiny training configuration: a few robots, envs and steps, for tests that build or run
the training loop."""

from __future__ import annotations

from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig

TINY = TrainConfig(
    n_robots=4,
    n_envs=4,
    rollout_steps=8,
    minibatch=64,
    ae_steps=2,
    policy_steps=3,
    value_steps=3,
    latent_dim=8,
    ae_hidden=16,
    eval_every=2,
    eval_episodes=3,
)

TINY_WORLD = DEFAULT_WORLD.with_(step_limit=12)

