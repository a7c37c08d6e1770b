"""Export: one ONNX graph from raw observation to action, parity with torch, manifest."""

from __future__ import annotations

import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from runtime.brain.brain import BrainManifest, load_brain
from runtime.decision.observation import ObservationSpec
from trainer.config import TrainConfig
from trainer.ppo.export import (
    BrainFileError,
    agent_from_onnx,
    build_onnx,
    read_manifest,
    write_brain,
)
from trainer.ppo.networks import Agent


def _agent(algo: str, obs_dim: int = 36, seed: int = 0) -> Agent:
    torch.manual_seed(seed)
    agent = Agent(obs_dim, TrainConfig(algo=algo), v_max_mps=1.0)
    rng = np.random.default_rng(seed)
    agent.normaliser.update(rng.normal(0.5, 2.0, size=(2000, obs_dim)))
    for p in agent.parameters():  # move away from the near-zero initial heads
        p.data += 0.05 * torch.randn_like(p)
    return agent


@pytest.mark.parametrize("algo", ["pattern-rl", "ppo"])
def test_onnx_matches_torch_on_1000_observations(algo: str) -> None:
    agent = _agent(algo)
    model = build_onnx(agent)
    onnx.checker.check_model(model, full_check=True)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    obs = np.random.default_rng(1).normal(0.0, 3.0, size=(1000, 36)).astype(np.float32)
    action, std = sess.run(["action", "std"], {"obs": obs})
    with torch.no_grad():
        t_obs = torch.from_numpy(obs)
        ref = agent.act_mps(t_obs).numpy()
        _, ref_std = agent.policy(agent.features(t_obs))
    assert action.shape == (1000, 2)
    np.testing.assert_allclose(action, ref, atol=1e-5, rtol=0)
    np.testing.assert_allclose(std, ref_std.numpy() * agent.v_max_mps, atol=1e-5, rtol=0)
    assert np.abs(action).max() <= agent.v_max_mps
    # dynamic batch axis
    one = sess.run(["action"], {"obs": obs[:1]})[0]
    np.testing.assert_allclose(one, action[:1], atol=1e-6)
    dims = model.graph.input[0].type.tensor_type.shape.dim
    assert dims[0].dim_param == "batch" and dims[1].dim_value == 36


def test_brain_file_manifest_sidecar_and_round_trip(tmp_path) -> None:
    agent = _agent("pattern-rl")
    spec = ObservationSpec("general")
    manifest = BrainManifest(
        observation=spec,
        pattern="circle",
        n_robots=10,
        training={"algorithm": "pattern-rl", "episodes": 1, "seed": 0, "wall_time_s": 0.1},
        evaluation={"episodes": 0},
    )
    path = tmp_path / "b.onnx"
    written = write_brain(agent, path, manifest)
    size = path.stat().st_size
    assert 50_000 < size < 1_000_000  # a few hundred KB
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["brain_id"] == written.brain_id and side["format"] == "patternrl-brain"
    assert side["file"] == "b.onnx" and side["observation"] == spec.to_dict()
    embedded = read_manifest(path)
    assert embedded.brain_id == written.brain_id
    assert embedded.training["algorithm"] == "pattern-rl"
    props = {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props}
    assert "brain_id" not in props["patternrl_manifest"]
    # the runtime loads it as a robot would and agrees with torch
    brain = load_brain(str(path))
    obs = np.random.default_rng(2).normal(size=(5, spec.dim))
    with torch.no_grad():
        ref = agent.act_mps(torch.from_numpy(obs.astype(np.float32))).numpy()
    np.testing.assert_allclose(brain.act(obs), ref, atol=1e-5)
    # and the trainer reads it back for fine-tuning
    back = agent_from_onnx(path, TrainConfig(algo="pattern-rl"), 1.0)
    with torch.no_grad():
        np.testing.assert_allclose(
            back.act_mps(torch.from_numpy(obs.astype(np.float32))).numpy(), ref, atol=1e-6
        )


def test_agent_from_onnx_refuses_the_wrong_algorithm_and_garbage(tmp_path) -> None:
    path = tmp_path / "ppo.onnx"
    write_brain(_agent("ppo"), path, BrainManifest(observation=ObservationSpec("general")))
    with pytest.raises(BrainFileError, match="ppo brain"):
        agent_from_onnx(path, TrainConfig(algo="pattern-rl"), 1.0)
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not an onnx file")
    with pytest.raises(BrainFileError):
        agent_from_onnx(bad, TrainConfig(), 1.0)


def test_read_manifest_reads_the_embedded_manifest_only(tmp_path) -> None:
    path = tmp_path / "b.onnx"
    manifest = BrainManifest(observation=ObservationSpec("general"))
    written = write_brain(_agent("ppo"), path, manifest)
    side = json.loads(path.with_suffix(".json").read_text())
    side["pattern"] = "heart"  # a sidecar that disagrees is not what the file embeds
    path.with_suffix(".json").write_text(json.dumps(side))
    embedded = read_manifest(path)
    assert embedded.pattern is None and embedded.brain_id == written.brain_id
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not an onnx file")
    for ref in (bad, tmp_path / "absent.onnx", "rule:assign"):
        with pytest.raises(BrainFileError):
            read_manifest(ref)
