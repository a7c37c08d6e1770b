"""Short real training runs, in-process: the same seed gives the same curve, a tiny model
trains, exports, evaluates, resumes and fine-tunes, lambda adapts, a plan brain trains."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from support.training import TINY, TINY_WORLD

from runtime.brain.brain import BrainManifest, load_brain
from runtime.decision.observation import ObservationSpec
from trainer.config import TrainConfig, obs_spec_for
from trainer.evaluate import evaluate_brain
from trainer.ppo.export import write_brain
from trainer.train import RunPlan, artefact_paths, train

PLAN_WEIGHT = 0.25
PLAN_SPEC = ObservationSpec("plan", travel_weight=PLAN_WEIGHT)


def _tiny_run(tmp_path, cfg: TrainConfig = TINY, **plan_kw):
    plan = RunPlan(
        patterns=plan_kw.pop("patterns", ["circle"]),
        out=tmp_path / "tiny.onnx",
        episodes=plan_kw.pop("episodes", 16),
        progress=False,
        world=TINY_WORLD,
        **plan_kw,
    )
    return train(cfg, plan)


def _curve_without_wall(rows):
    def same(v):  # nan != nan: compare it as a marker
        return "nan" if isinstance(v, float) and math.isnan(v) else v

    return [{k: same(v) for k, v in r.items() if k != "wall_s"} for r in rows]


@pytest.mark.parametrize("algo", ["pattern-rl", "ppo"])
def test_same_seed_gives_the_same_learning_curve(tmp_path, algo: str) -> None:
    cfg = TINY.with_(algo=algo, seed=7)
    a = _tiny_run(tmp_path / "a", cfg, write_files=False)
    b = _tiny_run(tmp_path / "b", cfg, write_files=False)
    assert len(a.curve) >= 4
    assert _curve_without_wall(a.curve) == _curve_without_wall(b.curve)
    c = _tiny_run(tmp_path / "c", cfg.with_(seed=8), write_files=False)
    assert _curve_without_wall(c.curve) != _curve_without_wall(a.curve)


def test_tiny_model_trains_exports_and_evaluates(tmp_path) -> None:
    res = _tiny_run(tmp_path, patterns=["circle", "line"], episodes=4)
    files = artefact_paths(tmp_path / "tiny.onnx")
    header = files["curve_csv"].read_text().splitlines()[0].split(",")
    assert header[:4] == ["iteration", "stage", "pattern", "episodes"]
    assert files["curve_png"].stat().st_size > 0
    assert {r["pattern"] for r in res.curve} == {"circle", "line"}
    assert res.episodes >= 8
    # export, parity with torch through the runtime's loader, then evaluate as a robot runs it
    spec = ObservationSpec("general")
    out = tmp_path / "tiny.onnx"
    write_brain(res.agent, out, BrainManifest(observation=spec, pattern="line", n_robots=4))
    brain = load_brain(str(out))
    obs = np.random.default_rng(0).normal(size=(1000, spec.dim))
    with torch.no_grad():
        ref = res.agent.act_mps(torch.from_numpy(obs.astype(np.float32))).numpy()
    np.testing.assert_allclose(brain.act(obs), ref, atol=1e-5)
    ev = evaluate_brain(brain, "line", 4, episodes=3, seed=5, world=TINY_WORLD, progress=False)
    assert ev.episodes == 3 and 0.0 <= ev.success_rate <= 1.0
    assert ev.safety == "orca"
    # resume from the checkpoint and fine-tune from the brain: both run
    more = _tiny_run(
        tmp_path,
        patterns=["circle", "line"],
        episodes=4,
        resume=str(files["checkpoint"]),
        write_files=False,
    )
    assert more.curve[-1]["iteration"] > res.curve[-1]["iteration"]
    tuned = _tiny_run(tmp_path / "ft", init=str(out), write_files=False)
    assert tuned.episodes >= 8
    # a fine-tune with the normaliser frozen reads its inputs exactly as the brain it started
    # from did; without, the new rollouts' statistics move them
    shipped = res.agent.normaliser
    frozen = _tiny_run(tmp_path / "fz", TINY.with_(freeze_normaliser=True), init=str(out),
                       write_files=False)
    for tuned_, same in ((frozen, True), (tuned, False)):
        norm = tuned_.agent.normaliser
        assert torch.equal(norm.shift, shipped.shift) is same
        assert torch.equal(norm.scale, shipped.scale) is same


def test_lambda_adapts_during_training(tmp_path) -> None:
    res = _tiny_run(tmp_path, TINY.with_(kl_target=1e-6), write_files=False)
    coefs = [r["kl_coef"] for r in res.curve]
    assert coefs[0] == pytest.approx(2.0)  # KL far above a tiny target: lambda doubles
    assert coefs == sorted(coefs)


def test_a_short_plan_run_trains_and_exports(tmp_path: Path) -> None:
    cfg = TrainConfig(algo="ppo", obs="plan", residual=True, travel_weight=PLAN_WEIGHT,
                      train_safety=True, n_robots=5, n_envs=4, rollout_steps=8, minibatch=64,
                      policy_steps=2, value_steps=2, eval_every=1, eval_episodes=4, seed=0,
                      init_std=0.1,
                      reward={"travel_penalty": 0.05, "progress_weight": 0.0})
    plan = RunPlan(patterns=["random"], out=tmp_path / "b.onnx", episodes=8, progress=False,
                   write_files=False)
    res = train(cfg, plan)
    assert res.episodes >= 8
    write_brain(res.agent, tmp_path / "b.onnx", BrainManifest(observation=obs_spec_for(cfg)))
    brain = load_brain(str(tmp_path / "b.onnx"))
    assert brain.spec == PLAN_SPEC
    assert evaluate_brain(brain, "circle", 5, 2, seed=1, progress=False).success_rate > 0.0


def test_a_plan_brain_trains_under_realistic_sensing_with_a_hold_window(tmp_path: Path) -> None:
    """Each robot of the training world on its own noisy, late, gappy view (the robot's own
    pipeline), episodes that go on 5 steps after forming: the run trains, evaluates held out
    and exports a brain that runs."""
    cfg = TrainConfig(algo="ppo", obs="plan", residual=True, travel_weight=PLAN_WEIGHT,
                      train_safety=True, n_robots=5, n_envs=4, rollout_steps=8, minibatch=64,
                      policy_steps=2, value_steps=2, eval_every=1, eval_episodes=4, seed=0,
                      init_std=0.1, conditions="realistic", hold_steps=5)
    plan = RunPlan(patterns=["random"], out=tmp_path / "b.onnx", episodes=8, progress=False,
                   write_files=False)
    res = train(cfg, plan)
    assert res.episodes >= 8 and np.isfinite(res.curve[-1]["mean_reward"])
    assert any(not math.isnan(r["eval_success"]) for r in res.curve)
    write_brain(res.agent, tmp_path / "b.onnx", BrainManifest(observation=obs_spec_for(cfg)))
    brain = load_brain(str(tmp_path / "b.onnx"))
    assert brain.spec == PLAN_SPEC
    assert evaluate_brain(brain, "circle", 5, 2, seed=1, progress=False,
                          conditions=cfg.world_conditions, estimator=True).collisions == 0
    with pytest.raises(ValueError, match="hold_steps"):
        TrainConfig(hold_steps=-1)


def test_a_brain_with_memory_trains_reading_its_older_rows_and_runs_robot_by_robot(
        tmp_path: Path) -> None:
    """Memory of 3 rows under realistic sensing: the rollouts carry each robot's older rows
    (zeros only where an episode starts), the exported brain carries them in and out, and
    eval runs it robot by robot (each robot's controller holds its memory)."""
    cfg = TrainConfig(algo="ppo", obs="plan", residual=True, travel_weight=PLAN_WEIGHT,
                      train_safety=True, n_robots=5, n_envs=4, rollout_steps=8, minibatch=64,
                      policy_steps=2, value_steps=2, eval_every=1, eval_episodes=4, seed=0,
                      init_std=0.1, conditions="realistic", hold_steps=5, memory_frames=3)
    spec = obs_spec_for(cfg)
    assert spec.frames == 3
    from trainer.ppo.networks import Agent
    from trainer.rollout import InProcessRollouts
    src = InProcessRollouts(cfg, TINY_WORLD, "random", 0, 0)
    agent = Agent(spec.input_dim, cfg, TINY_WORLD.v_max_mps)
    ro = src.collect(agent, torch.Generator().manual_seed(0))
    obs = ro.batch.obs.reshape(cfg.rollout_steps, cfg.n_envs, cfg.n_robots, -1).numpy()
    d = spec.dim
    assert obs.shape[-1] == 3 * d
    # step t's second row is step t-1's first, unless an episode started at t (zeros)
    carried = (obs[1:, :, :, d : 2 * d] == obs[:-1, :, :, :d]).all(axis=(2, 3))
    started = (obs[1:, :, :, d:] == 0).all(axis=(2, 3))
    assert (carried | started).all() and carried.sum() > started.sum() > 0
    assert not obs[0, :, :, d:].any()  # the first step of every world: zeros
    plan = RunPlan(patterns=["random"], out=tmp_path / "b.onnx", episodes=8, progress=False,
                   write_files=False)
    res = train(cfg, plan)
    assert res.episodes >= 8 and any(not math.isnan(r["eval_success"]) for r in res.curve)
    write_brain(res.agent, tmp_path / "b.onnx", BrainManifest(observation=spec))
    brain = load_brain(str(tmp_path / "b.onnx"))
    assert brain.spec == spec
    perfect = evaluate_brain(brain, "circle", 5, 2, seed=1, progress=False)
    real = evaluate_brain(brain, "circle", 5, 2, seed=1, progress=False,
                          conditions=cfg.world_conditions, estimator=True)
    assert perfect.episodes == real.episodes == 2 and real.collisions == 0


def test_a_run_that_takes_the_filters_lesson_keeps_its_teacher_and_exports_the_student(
        tmp_path: Path) -> None:
    """``safety_imitation``: the run keeps the brain it started from as a frozen teacher and
    exports the student alone, which the robot runs as the trained agent acts."""
    res = _tiny_run(tmp_path, TINY.with_(safety_imitation=5.0), write_files=False)
    assert res.episodes >= 16 and any(not math.isnan(r["eval_success"]) for r in res.curve)
    teacher = res.agent.lesson_teacher
    moved = [not torch.equal(a, b) for a, b in zip(res.agent.policy.parameters(),
                                                   teacher.policy.parameters(), strict=True)]
    assert any(moved) and not any(p.requires_grad for p in teacher.parameters())
    write_brain(res.agent, tmp_path / "b.onnx", BrainManifest(observation=obs_spec_for(TINY)))
    brain = load_brain(str(tmp_path / "b.onnx"))
    obs = np.random.default_rng(0).normal(size=(4, obs_spec_for(TINY).input_dim))
    with torch.no_grad():
        ref = res.agent.act_mps(torch.from_numpy(obs.astype(np.float32))).numpy()
    np.testing.assert_allclose(brain.act(obs.astype(np.float32)), ref, atol=1e-5)
