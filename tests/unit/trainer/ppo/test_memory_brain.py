"""Brains with memory: the older rows go in as ``memory`` and come back as ``memory_out``;
the robot's controller carries them from step to step and forgets them where it must."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from runtime.brain.brain import (
    BrainError,
    BrainManifest,
    brain_digest,
    load_brain,
    validate_brain_bytes,
)
from runtime.decision.controller import Controller
from runtime.decision.observation import ObservationError, ObservationSpec
from runtime.decision.patterns import make_pattern
from trainer.checkpoints import load_init
from trainer.config import TrainConfig
from trainer.ppo.export import agent_from_onnx, write_brain
from trainer.ppo.networks import Agent, with_memory
from trainer.world.memory import RowMemory

FRAMES = 3
ROW = ObservationSpec("plan", travel_weight=0.25)
SPEC = ObservationSpec("plan", travel_weight=0.25, frames=FRAMES)


def trained_looking(agent: Agent, seed: int) -> Agent:
    torch.manual_seed(seed)
    agent.normaliser.update(np.random.default_rng(seed).normal(0.0, 0.3, (500, agent.obs_dim)))
    with torch.no_grad():
        for p in agent.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return agent


def memory_agent(algo: str = "pattern-rl", seed: int = 0) -> Agent:
    cfg = TrainConfig(algo=algo, obs="plan", residual=True, memory_frames=FRAMES)
    return trained_looking(Agent(SPEC.input_dim, cfg, 1.0), seed)


def test_the_spec_carries_its_frames_and_refuses_memory_where_it_has_none() -> None:
    assert SPEC.memory_dim == (FRAMES - 1) * SPEC.dim and SPEC.input_dim == FRAMES * SPEC.dim
    assert ObservationSpec.from_dict(SPEC.to_dict()) == SPEC
    assert "frames" not in ROW.to_dict()  # a brain without memory: its manifest as before
    assert ROW.memory_dim == 0
    with pytest.raises(ObservationError, match="paper observation has no memory"):
        ObservationSpec("paper", n_robots=10, frames=2)
    with pytest.raises(ObservationError, match="frames must be in"):
        ObservationSpec("general", frames=0)
    with pytest.raises(ValueError, match="no memory"):
        TrainConfig(obs="paper", memory_frames=2)


@pytest.mark.parametrize("algo", ["pattern-rl", "ppo"])
def test_the_graph_reads_the_row_and_its_memory_and_answers_the_next_memory(
        algo: str, tmp_path: Path) -> None:
    agent = memory_agent(algo)
    path = tmp_path / "mem.onnx"
    write_brain(agent, path, BrainManifest(observation=SPEC))
    brain = load_brain(str(path))  # validated (memory probed) and run by onnxruntime
    rng = np.random.default_rng(1)
    obs = rng.normal(0.0, 0.3, (16, SPEC.dim)).astype(np.float32)
    memory = rng.normal(0.0, 0.3, (16, SPEC.memory_dim)).astype(np.float32)
    act, nxt = brain.act_memory(obs, memory)  # type: ignore[attr-defined]
    stacked = np.concatenate([obs, memory], axis=1)
    with torch.no_grad():
        ref = agent.act_mps(torch.from_numpy(stacked)).numpy()
    np.testing.assert_allclose(act, ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(nxt, stacked[:, : SPEC.memory_dim])  # newest rows first
    zero = brain.act(obs)  # alone: from zeros
    np.testing.assert_allclose(zero, brain.act_memory(obs, np.zeros_like(memory))[0])  # type: ignore[attr-defined]
    assert not np.allclose(zero, act)  # the memory matters to this brain
    back = agent_from_onnx(path, TrainConfig(algo=algo, obs="plan", memory_frames=FRAMES), 1.0)
    assert back.obs_dim == SPEC.input_dim
    with torch.no_grad():
        np.testing.assert_allclose(back.act_mps(torch.from_numpy(stacked)).numpy(), ref,
                                   rtol=1e-5, atol=1e-5)


def test_a_brain_whose_graph_and_manifest_disagree_on_memory_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "mem.onnx"
    write_brain(memory_agent(), path, BrainManifest(observation=SPEC))
    data = path.read_bytes()
    with pytest.raises(BrainError, match="needs exactly \\['obs'\\]"):
        validate_brain_bytes(data, BrainManifest(observation=ROW), brain_digest(data))
    plain = tmp_path / "plain.onnx"
    cfg = TrainConfig(obs="plan", residual=True)
    write_brain(trained_looking(Agent(ROW.dim, cfg, 1.0), 2), plain, BrainManifest(
        observation=ROW))
    data = plain.read_bytes()
    with pytest.raises(BrainError, match="needs exactly \\['obs', 'memory'\\]"):
        validate_brain_bytes(data, BrainManifest(observation=SPEC), brain_digest(data))


def test_a_brain_without_memory_grows_one_and_acts_exactly_as_before(tmp_path: Path) -> None:
    cfg = TrainConfig(obs="plan", residual=True, travel_weight=0.25)
    plain = trained_looking(Agent(ROW.dim, cfg, 1.0), 3)
    grown = with_memory(plain, FRAMES, cfg.with_(memory_frames=FRAMES), 1.0)
    rng = np.random.default_rng(5)
    obs = rng.normal(0.0, 0.3, (32, ROW.dim)).astype(np.float32)
    memory = rng.normal(0.0, 1.0, (32, SPEC.memory_dim)).astype(np.float32)
    with torch.no_grad():
        a = plain.act_mps(torch.from_numpy(obs)).numpy()
        b = grown.act_mps(torch.from_numpy(np.concatenate([obs, memory], 1))).numpy()
    np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-6)
    # what `patternrl train --init plain.onnx --memory-frames 3` starts from
    path = tmp_path / "plain.onnx"
    write_brain(plain, path, BrainManifest(observation=ROW))
    init = load_init(str(path), cfg.with_(memory_frames=FRAMES), 1.0, SPEC.input_dim)
    with torch.no_grad():
        c = init.act_mps(torch.from_numpy(np.concatenate([obs, memory], 1))).numpy()
    np.testing.assert_allclose(c, a, rtol=1e-5, atol=1e-5)


def test_the_controller_carries_the_memory_from_step_to_step_and_forgets_it(
        tmp_path: Path) -> None:
    path = tmp_path / "mem.onnx"
    write_brain(memory_agent(), path, BrainManifest(observation=SPEC))
    brain = load_brain(str(path))
    d = SPEC.dim
    n = 6
    C = make_pattern("circle", n)
    rng = np.random.default_rng(7)
    pos = rng.uniform(0.0, 3.0, (n, 2))
    ctl = Controller(brain)
    assert not ctl.memory.any() and ctl.memory.shape == (1, SPEC.memory_dim)
    ctl.decide(2, pos, C, step=0)
    first = ctl.memory.copy()
    assert first[0, :d].any() and not first[0, d:].any()  # its row, then zeros
    pos2 = pos + 0.05
    ctl.decide(2, pos2, C, step=1)
    second = ctl.memory.copy()
    np.testing.assert_array_equal(second[0, d : 2 * d], first[0, :d])  # shifted by one row
    ctl.decide(2, pos2 + 0.01, C, step=1)  # the same step again (realtime): no shift
    np.testing.assert_array_equal(ctl.memory[0, d : 2 * d], first[0, :d])
    again = Controller(brain)  # a repeated step decides as a fresh first decision would
    again.decide(2, pos, C, step=0)
    v1 = again.decide(2, pos2, C, step=1).brain_velocity
    v2 = ctl.decide(2, pos2, C, step=1).brain_velocity
    np.testing.assert_allclose(v1, v2, rtol=1e-6, atol=1e-7)
    ctl.set_brain(brain)  # a hot swap: the old memory means nothing to the new brain
    assert not ctl.memory.any()
    ctl.decide(2, pos, C, step=2)
    assert ctl.memory.any()
    ctl.reset()
    assert not ctl.memory.any()
    ctl.decide(2, pos, C, step=3)
    ctl.decide(2, np.vstack([pos, [[5.0, 5.0]]]), make_pattern("circle", n + 1), step=4)
    assert not ctl.memory[0, d:].any()  # a new team: from zeros again


def test_row_memory_stacks_advances_and_starts_episodes_from_zeros() -> None:
    rows = RowMemory(3, 2, 2, 2)
    o1 = np.arange(8, dtype=np.float32).reshape(2, 2, 2) + 1
    x1 = rows.stack(o1)
    assert x1.shape == (2, 2, 6) and not x1[..., 2:].any()
    rows.advance(x1, np.array([False, True]))
    o2 = o1 + 10
    x2 = rows.stack(o2)
    np.testing.assert_array_equal(x2[0, :, 2:4], o1[0])
    assert not x2[1, :, 2:].any()  # world 1 started a new episode
    np.testing.assert_array_equal(rows.final(o2[:1], x1[:1])[..., 2:4], o1[:1])
    assert RowMemory(1, 2, 2, 2).stack(o1) is o1  # no memory: the row itself
