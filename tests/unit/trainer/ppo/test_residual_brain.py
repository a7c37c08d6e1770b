"""Residual brains: rule:assign's velocity plus a learned part, all inside the ONNX graph."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch
from support import assert_same_episodes

from runtime.brain.brain import BrainManifest, RuleBrain, load_brain
from runtime.decision.observation import ObservationSpec
from runtime.decision.patterns import make_pattern
from runtime.decision.pipeline import decide_batch
from runtime.decision.safety import OrcaParams
from trainer.config import TrainConfig
from trainer.ppo.export import agent_from_onnx, build_onnx, write_brain
from trainer.ppo.networks import Agent

SPEC = ObservationSpec("general")


def residual_agent(algo: str, seed: int = 0) -> Agent:
    """A residual agent as training starts it: trained-looking trunk, zero mean head."""
    torch.manual_seed(seed)
    agent = Agent(SPEC.dim, TrainConfig(algo=algo, residual=True), v_max_mps=1.0)
    agent.normaliser.update(np.random.default_rng(seed).normal(0.0, 1.0, (500, SPEC.dim)))
    for name, p in agent.named_parameters():
        if not name.startswith("policy.mean_head"):
            p.data += 0.05 * torch.randn_like(p)
    return agent


def test_a_fresh_residual_agent_starts_with_a_zero_mean_head() -> None:
    agent = residual_agent("ppo")
    assert agent.residual
    assert not agent.policy.mean_head.weight.any()
    assert not agent.policy.mean_head.bias.any()
    assert not Agent(SPEC.dim, TrainConfig(), 1.0).residual  # off by default


@pytest.mark.parametrize("algo", ["pattern-rl", "ppo"])
@pytest.mark.parametrize("safety", [None, OrcaParams()])
def test_zero_residual_brain_equals_the_rule_number_for_number(
    algo: str, safety: OrcaParams | None, tmp_path: Path
) -> None:
    path = tmp_path / "residual.onnx"
    write_brain(residual_agent(algo), path, BrainManifest(observation=SPEC))
    brain = load_brain(str(path))  # validated and run by onnxruntime, as on a robot
    rule = RuleBrain()
    rng = np.random.default_rng(3)
    n, E = 9, 4
    pos = rng.uniform(0.0, 3.0, (E, n, 2))
    frames = np.stack([pos, pos - rng.uniform(-0.05, 0.05, pos.shape), pos], axis=1)
    C = make_pattern("heart", n)
    v_b, s_b, _ = decide_batch(brain, frames, C, None, safety)
    v_r, s_r, _ = decide_batch(rule, frames, C, None, safety)
    np.testing.assert_array_equal(s_b, s_r)
    # float32 in the graph, float64 in the rule: equal to float32 rounding
    np.testing.assert_allclose(v_b, v_r, rtol=1e-6, atol=1e-6)
    # whole episodes: the same steps, travel and success on the same starts
    assert_same_episodes(brain, rule, safety)


def test_the_graph_adds_the_learned_part_and_round_trips(tmp_path: Path) -> None:
    agent = residual_agent("ppo")
    with torch.no_grad():
        agent.policy.mean_head.bias.copy_(torch.tensor([0.3, -0.2]))
    obs = np.random.default_rng(4).normal(0.0, 1.0, (64, SPEC.dim)).astype(np.float32)
    sess = ort.InferenceSession(build_onnx(agent).SerializeToString(),
                                providers=["CPUExecutionProvider"])
    action = sess.run(["action"], {"obs": obs})[0]
    with torch.no_grad():
        ref = agent.act_mps(torch.from_numpy(obs)).numpy()
        base = agent.base_mps(torch.from_numpy(obs)).numpy()
    np.testing.assert_allclose(action, ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(base, RuleBrain().act(obs.astype(np.float64)), rtol=1e-6,
                               atol=1e-6)
    assert np.abs(action - base).max() > 0.1  # the learned part is there
    path = tmp_path / "r.onnx"
    write_brain(agent, path, BrainManifest(observation=SPEC))
    back = agent_from_onnx(path, TrainConfig(algo="ppo"), 1.0)
    assert back.residual
    with torch.no_grad():
        np.testing.assert_allclose(back.act_mps(torch.from_numpy(obs)).numpy(), ref,
                                   rtol=1e-5, atol=1e-5)
