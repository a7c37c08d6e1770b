"""``safety_imitation``: the safety filter's lesson, taken raw on the brain's own states."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from runtime.decision.observation import ObservationSpec
from runtime.decision.pipeline import commands
from runtime.decision.safety import OrcaParams
from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig
from trainer.ppo.networks import Agent
from trainer.ppo.storage import RolloutBatch
from trainer.ppo.update import safety_lesson_loss
from trainer.rollout import attach_teacher, collect_rollout
from trainer.world.training_world import BatchWorld

SPEC = ObservationSpec("general")


def _crowd(seed: int) -> BatchWorld:
    """12 robots on a 4 x 3 grid 0.55 m apart, jittered by up to 4 cm, still: the filter has
    work for a command toward a neighbour to do, and no pair can touch within a step."""
    bw = BatchWorld(3, 12, "random", SPEC, seed=seed)
    rng = np.random.default_rng(seed)
    grid = 0.55 * np.stack(np.meshgrid(np.arange(4), np.arange(3)), -1).reshape(12, 2)
    for e in range(3):
        p = grid + rng.uniform(-0.04, 0.04, (12, 2))
        bw.positions[e] = p
        bw.prev_positions[e] = p
    return bw


def test_the_lesson_is_the_filters_command_for_the_teachers_and_the_teacher_stays() -> None:
    """Each step the rollout runs the robots' filter, with the lesson's wider margin, on the
    frozen teacher's command for every robot's row: its output, in units of v_max, is the
    policy's target, whatever the policy has become since; the teacher is in no state dict."""
    cfg = TrainConfig(algo="ppo", obs="general", n_robots=12, n_envs=3, rollout_steps=1,
                      init_std=0.3, seed=0, safety_imitation=1.0)
    torch.manual_seed(0)
    agent = Agent(SPEC.input_dim, cfg, DEFAULT_WORLD.v_max_mps)
    with torch.no_grad():  # a teacher that drives every robot the same way, at speed
        agent.policy.mean_head.bias.copy_(torch.tensor([1.0, 0.3]))
    attach_teacher(agent)
    keys = set(agent.state_dict())
    with torch.no_grad():  # the policy moves on; the teacher does not
        agent.policy.mean_head.bias.copy_(torch.tensor([-0.5, 0.0]))
    assert set(agent.state_dict()) == keys and not any("teacher" in k for k in keys)
    bw = _crowd(7)
    obs0 = bw.observe()
    pos0, prev0 = bw.positions.copy(), bw.prev_positions.copy()
    out = collect_rollout(agent, bw, obs0, cfg, torch.Generator().manual_seed(0), 1.0)
    b = out.batch
    assert b.safe_mean is not None
    teacher = agent.lesson_teacher
    with torch.no_grad():
        want = teacher.act_team_mps(torch.from_numpy(obs0.reshape(36, -1)), 12).numpy()
    want = want.reshape(3, 12, 2).astype(np.float64)
    assert np.allclose(want[..., 0], want[0, 0, 0], atol=0.05)  # the teacher's, not the policy's
    assert want[0, 0, 0] > 0.5
    safe = commands(want, pos0, prev0, OrcaParams(radius_margin_m=0.06), DEFAULT_WORLD, None)[0]
    changed = np.hypot(*(safe - want).transpose(2, 0, 1)) > 1e-3
    assert 0 < changed.sum() < changed.size  # the filter changed some commands, not all
    np.testing.assert_allclose(b.safe_mean.numpy().reshape(3, 12, 2), safe, atol=1e-6)


def test_without_the_lesson_the_rollout_keeps_no_targets() -> None:
    cfg = TrainConfig(algo="ppo", obs="general", n_robots=12, n_envs=3, rollout_steps=1,
                      seed=0)
    agent = Agent(SPEC.input_dim, cfg, DEFAULT_WORLD.v_max_mps)
    attach_teacher(agent)  # a teacher, but no lesson asked for
    bw = _crowd(3)
    out = collect_rollout(agent, bw, bw.observe(), cfg, torch.Generator().manual_seed(0), 1.0)
    assert out.batch.safe_mean is None


def _batch(mean: torch.Tensor, safe: torch.Tensor) -> RolloutBatch:
    z = torch.zeros(len(mean))
    return RolloutBatch(obs=torch.zeros(len(mean), 3), actions=mean, old_mean=mean,
                        old_std=torch.ones_like(mean), old_logprob=z, returns=z,
                        advantages=z, safe_mean=safe)


def test_the_lesson_pulls_the_mean_toward_its_target() -> None:
    """The loss is w times the minibatch mean of the squared error; a gradient step moves every
    row's mean toward its target, and only the rows of the minibatch count."""
    mean = torch.tensor([[1.0, 0.0], [0.5, 0.5], [0.0, -1.0]], requires_grad=True)
    safe = torch.tensor([[0.2, 0.1], [0.5, 0.5], [0.0, -0.4]])
    idx = torch.tensor([0, 2])
    cfg = TrainConfig(safety_imitation=2.0)
    b = _batch(mean.detach(), safe)
    loss = safety_lesson_loss(mean[idx], b, idx, cfg)
    assert float(loss.detach()) == pytest.approx(2.0 * (0.8**2 + 0.1**2 + 0.6**2) / 2)
    loss.backward()
    g = mean.grad
    assert g is not None and torch.equal(g[1], torch.zeros(2))
    after = mean.detach() - 0.1 * g
    assert ((after - safe).pow(2).sum(-1)[idx] < (mean.detach() - safe).pow(2).sum(-1)[idx]).all()
    off = TrainConfig()
    assert float(safety_lesson_loss(mean[idx], b, idx, off).detach()) == 0.0
    with pytest.raises(ValueError, match="safety_imitation"):
        TrainConfig(safety_imitation=-1.0)
    with pytest.raises(ValueError, match="lesson_margin_m"):
        TrainConfig(lesson_margin_m=-0.01)
