"""Plan brains: the plan observation, and a learned part on top of the plan's step."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from support import assert_same_episodes

from runtime.brain.brain import BrainManifest, load_brain
from runtime.decision.controller import Controller
from runtime.decision.formation import assign_slots_batch
from runtime.decision.observation import ObservationError, ObservationSpec, observe
from runtime.decision.patterns import make_pattern
from runtime.decision.pipeline import commands, decide_batch
from runtime.decision.rules import FrameRule, PlanFrame, frame_plan, plan_targets
from runtime.decision.safety import OrcaParams, landing
from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig, obs_spec_for
from trainer.evaluate import evaluate_brain
from trainer.ppo.export import agent_from_onnx, write_brain
from trainer.ppo.networks import Agent
from trainer.rollout import collect_rollout
from trainer.world.training_world import BatchWorld

W = 0.25
SPEC = ObservationSpec("plan", travel_weight=W)


def plan_agent(seed: int = 0, algo: str = "ppo") -> Agent:
    """A residual plan agent as training starts it: a perturbed trunk, a zero mean head."""
    torch.manual_seed(seed)
    agent = Agent(SPEC.dim, TrainConfig(algo=algo, obs="plan", residual=True,
                                        travel_weight=W), v_max_mps=1.0)
    agent.normaliser.update(np.random.default_rng(seed).normal(0.0, 1.0, (500, SPEC.dim)))
    for name, p in agent.named_parameters():
        if not name.startswith("policy.mean_head"):
            p.data += 0.05 * torch.randn_like(p)
    return agent


def team(seed: int, E: int = 3, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0.0, 3.0, (E, n, 2))
    return np.stack([pos, pos - rng.uniform(-0.05, 0.05, pos.shape), pos], axis=1), pos


def test_the_spec_round_trips_and_checks_its_weight() -> None:
    assert ObservationSpec.from_dict(SPEC.to_dict()) == SPEC
    assert SPEC.dim == ObservationSpec("general").dim and SPEC.accepts_team(37)
    with pytest.raises(ObservationError, match="travel_weight"):
        ObservationSpec("plan", travel_weight=1.5)
    assert obs_spec_for(TrainConfig(obs="plan", travel_weight=W)) == SPEC


def test_plan_rows_hold_the_plan_frame_slot_and_the_rules_step() -> None:
    frames, pos = team(1)
    C = np.broadcast_to(make_pattern("heart", 9), pos.shape)
    slots = assign_slots_batch(pos, C)
    target, k = plan_targets(pos, C, slots, W)
    obs = observe(SPEC, frames, target, None, DEFAULT_WORLD, k)
    np.testing.assert_allclose(obs[..., 0:2], target - pos)
    # v_max * columns 2:4 is rule:frame's velocity at the same weight
    np.testing.assert_allclose(obs[..., 2:4] * DEFAULT_WORLD.v_max_mps,
                               frame_plan(pos, C, slots, W), atol=1e-12)
    assert np.linalg.norm(obs[..., 2:4], axis=-1).max() <= 1.0 + 1e-12
    with pytest.raises(ObservationError, match="steps left"):
        observe(SPEC, frames, target)


def test_the_training_world_builds_the_same_plan_rows_as_the_robots() -> None:
    bw = BatchWorld(4, 9, "heart", SPEC, seed=5)
    rng = np.random.default_rng(0)
    for _ in range(3):
        bw.step(rng.uniform(-1.0, 1.0, (4, 9, 2)))
    pos = bw.positions
    frames = np.stack([pos, bw.prev_positions, bw.prev_positions], axis=1)
    target, k = plan_targets(pos, bw.pattern, bw.slots, W)
    ref = observe(SPEC, frames, target, None, DEFAULT_WORLD, k)
    np.testing.assert_allclose(bw.observe(), ref, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("safety", [None, OrcaParams()])
def test_a_zero_residual_plan_brain_is_rule_frame(safety: OrcaParams | None,
                                                  tmp_path: Path) -> None:
    path = tmp_path / "plan.onnx"
    write_brain(plan_agent(), path, BrainManifest(observation=SPEC))
    brain = load_brain(str(path))  # validated and run by onnxruntime, as on a robot
    assert brain.spec == SPEC
    rule = FrameRule("rule:frame", travel_weight=W)
    frames, _ = team(3)
    C = make_pattern("heart", 9)
    v_b, s_b, _ = decide_batch(brain, frames, C, None, safety)
    v_r, s_r, _ = decide_batch(rule, frames, C, None, safety)
    np.testing.assert_array_equal(s_b, s_r)
    np.testing.assert_allclose(v_b, v_r, rtol=1e-6, atol=1e-6)  # float32 graph
    # the robot's own path gives the batch's numbers
    ctl = Controller(brain, safety=safety)
    for i in range(9):
        ctl.reset()
        for f in (frames[0, 2], frames[0, 1]):
            ctl.decide(i, f, C)
        d = ctl.decide(i, frames[0, 0], C)
        np.testing.assert_allclose(d.velocity, v_b[0, i], rtol=1e-6, atol=1e-6)
    # whole episodes: the same steps and success, and every robot lands on its slot
    assert assert_same_episodes(brain, rule, safety) == 1.0


def test_a_plan_brain_lands_exactly_on_its_slot(tmp_path: Path) -> None:
    """No filter, no neighbours in the way: every robot is on its slot to float32 rounding
    at the step the plan says, not merely within the formed tolerance."""
    path = tmp_path / "plan.onnx"
    write_brain(plan_agent(1), path, BrainManifest(observation=SPEC))
    brain = load_brain(str(path))
    rng = np.random.default_rng(9)
    C = make_pattern("circle", 6) * 2.0  # spaced wide: no pair comes near another
    pos = C + rng.uniform(-0.6, 0.6, (6, 2)) + np.array([3.0, -1.0])
    frames = np.stack([pos, pos, pos])[None]
    slots = assign_slots_batch(pos[None], C[None])
    k = int(plan_targets(pos[None], C[None], slots, W)[1][0])
    for _ in range(k):
        v, slots, _ = decide_batch(brain, frames, C, slots, None)
        nxt = frames[:, 0] + v * DEFAULT_WORLD.dt_s
        frames = np.stack([nxt, frames[:, 0], frames[:, 1]], axis=1)
    end = frames[0, 0]
    target = C[slots[0]]
    shift = (end - target).mean(axis=0)
    assert np.abs(end - target - shift).max() < 1e-5  # the pattern exactly, up to translation


def test_the_graph_round_trips_with_its_learned_part(tmp_path: Path) -> None:
    agent = plan_agent(2)
    with torch.no_grad():
        agent.policy.mean_head.bias.copy_(torch.tensor([0.3, -0.2]))
    path = tmp_path / "p.onnx"
    write_brain(agent, path, BrainManifest(observation=SPEC))
    obs = np.random.default_rng(4).normal(0.0, 0.3, (32, SPEC.dim))
    with torch.no_grad():
        ref = agent.act_mps(torch.from_numpy(obs.astype(np.float32))).numpy()
    np.testing.assert_allclose(load_brain(str(path)).act(obs), ref, rtol=1e-5, atol=1e-5)
    back = agent_from_onnx(path, TrainConfig(algo="ppo", obs="plan"), 1.0)
    assert back.residual and back.on_plan
    with pytest.raises(Exception, match="--obs plan"):
        agent_from_onnx(path, TrainConfig(algo="ppo"), 1.0)


def test_training_behind_the_filter_moves_robots_by_the_filtered_command() -> None:
    """``train_safety``: the world moves each robot by runtime.decision.pipeline.commands of the
    sampled action, as a robot would; a seeded short run then trains and exports."""
    cfg = TrainConfig(algo="ppo", obs="plan", residual=True, travel_weight=W, train_safety=True,
                      n_robots=12, n_envs=3, rollout_steps=1, init_std=0.5, seed=0)
    agent = plan_agent(3)
    bw = BatchWorld(3, 12, "random", SPEC, seed=11)
    obs0, pos0, prev0 = bw.observe(), bw.positions.copy(), bw.prev_positions.copy()
    slots0 = bw.slots.copy()
    k = plan_targets(pos0, bw.pattern, slots0, W)[1]  # the landing horizon's steps left
    np.testing.assert_array_equal(bw.plan_steps_left, k)  # what the world observed
    out = collect_rollout(agent, bw, obs0, cfg, torch.Generator().manual_seed(0), 1.0)
    with torch.no_grad():
        base = agent.base_mps(torch.from_numpy(obs0.reshape(36, -1))).numpy()
    vel = (out.batch.actions.numpy() + base).reshape(3, 12, 2)
    filtered = commands(vel, pos0, prev0, OrcaParams(), DEFAULT_WORLD, k)[0]
    np.testing.assert_allclose(bw.positions, pos0 + filtered * DEFAULT_WORLD.dt_s, atol=1e-6)


def test_a_run_that_pays_for_the_filters_changes_is_rewarded_less_by_exactly_that() -> None:
    """``reward.safety_penalty``: each robot pays w per v_max of what the filter changed of its
    command; the same rollout without the penalty differs by exactly that."""
    cfg = TrainConfig(algo="ppo", obs="plan", residual=True, travel_weight=W, train_safety=True,
                      n_robots=12, n_envs=3, rollout_steps=1, init_std=0.5, seed=0,
                      gamma=0.0, gae_lambda=0.0)
    paid = cfg.with_(reward={"safety_penalty": 2.0})
    agent = plan_agent(3)
    outs = []
    for c in (cfg, paid):
        bw = BatchWorld(3, 12, "random", SPEC, seed=11)
        obs0, pos0, prev0 = bw.observe(), bw.positions.copy(), bw.prev_positions.copy()
        k = bw.plan_steps_left.copy()  # the landing horizon's steps left, as observed
        outs.append(collect_rollout(agent, bw, obs0, c, torch.Generator().manual_seed(0), 1.0))
    with torch.no_grad():
        base = agent.base_mps(torch.from_numpy(obs0.reshape(36, -1))).numpy()
    vel = (outs[0].batch.actions.numpy() + base).reshape(3, 12, 2)
    filtered = commands(vel, pos0, prev0, OrcaParams(), DEFAULT_WORLD, k)[0]
    change = np.hypot(*(filtered - vel).transpose(2, 0, 1)).reshape(-1)
    assert (change > 1e-3).any()  # the filter had work to do
    diff = (outs[0].batch.returns - outs[1].batch.returns).numpy()
    np.testing.assert_allclose(diff, 2.0 * change, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("n", [9, 40])
def test_the_robots_plan_frame_equals_the_batch_one_step_after_step(n: int) -> None:
    """PlanFrame keeps the enclosing circle's support from step to step: the same frame and
    steps left as plan_targets, whether the support holds (the team follows the plan) or
    not (the team jumps)."""
    rng = np.random.default_rng(n)
    C = make_pattern("heart", n)
    frame = PlanFrame()
    pos = rng.uniform(0.0, 6.0, (n, 2))
    kept = 0
    for step in range(40):
        if step % 10 == 0:  # a jump: the old support no longer encloses
            pos = rng.uniform(0.0, 6.0, (n, 2))
        slots = assign_slots_batch(pos[None], C[None])
        target, k = plan_targets(pos[None], C[None], slots, W)
        before = frame._sup.copy()
        t, steps_left = frame.solve(pos, C[slots[0]], W)
        kept += bool(np.array_equal(before, frame._sup))
        np.testing.assert_allclose(C[slots[0]] + t, target[0], atol=1e-9)
        assert steps_left == k[0]
        pos = target[0] - (target[0] - pos) * (1.0 - 1.0 / (k[0] + 1.0))  # along the plan
    assert kept >= 30  # the support carried over on the plan's steps


def test_the_landing_horizon_is_the_plans_time_left() -> None:
    p = OrcaParams()
    assert landing(p, 20.0) == p.time_horizon_s  # 2 s left: the default 0.75 s stands
    assert landing(p, 4.0) == pytest.approx(0.4)
    assert landing(p, 0.0) == pytest.approx(DEFAULT_WORLD.dt_s)  # never below dt
    assert landing(p, None) == p.time_horizon_s  # no plan
    assert landing(OrcaParams(landing=False), 2.0) == p.time_horizon_s


@pytest.mark.parametrize("pattern,n", [("circle", 13), ("heart", 7)])
def test_landing_saves_the_plans_last_steps_and_keeps_2r(pattern: str, n: int) -> None:
    """A synchronised team behind the filter: with the landing horizon it forms in fewer
    steps, with no collision and no pair closer than 2R along the commanded moves; and it
    holds the formation, where the full horizon's filter keeps nudging parked robots."""
    rule = FrameRule("rule:frame-balanced")
    kw = {"seed": 424242 + n, "progress": False}
    fixed = evaluate_brain(rule, pattern, n, 6, safety=OrcaParams(landing=False), **kw)
    landed = evaluate_brain(rule, pattern, n, 6, safety=OrcaParams(), **kw)
    assert fixed.formed_rate == landed.success_rate == landed.held_rate == 1.0
    assert landed.collisions == 0
    assert landed.min_separation_m >= DEFAULT_WORLD.min_separation_m
    assert np.mean(landed.episode_stats["steps"]) < np.mean(fixed.episode_stats["steps"])


def test_a_run_that_pays_for_the_filter_is_judged_without_it(monkeypatch) -> None:
    """Held-out evaluation: behind the filter when a run trains behind it, without it when the
    run pays for the filter's changes (it trains to be safe alone)."""
    import trainer.train as tt

    calls: list[int] = []
    real = tt.behind_filter

    def counted(vel, bw):  # the real filter, counted
        calls.append(1)
        return real(vel, bw)

    monkeypatch.setattr(tt, "behind_filter", counted)
    cfg = TrainConfig(algo="ppo", obs="plan", residual=True, travel_weight=W, train_safety=True,
                      n_robots=5, seed=0)
    agent = plan_agent(3)
    behind = tt.evaluate_policy(agent, cfg, "circle", 2, seed=1)
    assert calls and behind.success_rate >= 0.0
    calls.clear()
    tt.evaluate_policy(agent, cfg.with_(reward={"safety_penalty": 1.0}), "circle", 2, seed=1)
    assert not calls
