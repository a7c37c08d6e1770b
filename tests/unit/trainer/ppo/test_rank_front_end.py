"""The paper brain's front end and the rank matching it shares with the training world."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from runtime.decision.observation import ObservationSpec, paper_observation
from runtime.decision.patterns import make_pattern
from trainer.config import TrainConfig
from trainer.ppo.export import BrainFileError, agent_from_onnx, build_onnx
from trainer.ppo.front_end import front_dim
from trainer.ppo.networks import Agent
from trainer.ppo.rank import TEAM_AXIS, TEAM_AXIS_DEG, axis_gap, rank_goals, ranks
from trainer.world.training_world import BatchWorld

N = 10
SPEC = ObservationSpec("paper", n_robots=N)
CFG = TrainConfig(obs="paper", n_robots=N, front_end="rank")


def robot_major(P: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(P).transpose(2, 1, 0))


def test_ranks_are_a_permutation_ordered_along_the_axis() -> None:
    X = np.random.default_rng(1).uniform(-5, 5, size=(2, N, 7))
    r = ranks(X)
    assert (np.sort(r, axis=0) == np.arange(N)[:, None]).all()
    s = TEAM_AXIS[0] * X[0] + TEAM_AXIS[1] * X[1]
    for e in range(7):
        assert (s[np.argsort(r[:, e]), e] == np.sort(s[:, e])).all()


@pytest.mark.parametrize("pattern", ["circle", "cross", "line", "heart", "triangle"])
def test_a_formed_team_is_at_its_rank_goals_however_its_robots_are_numbered(pattern: str) -> None:
    C = make_pattern(pattern, N)
    C = C - C.mean(axis=0)
    perm = np.random.default_rng(2).permutation(N)
    P = C[perm] + np.array([3.0, -1.5])  # the pattern, translated, robots in another order
    goals, dist = rank_goals(robot_major(P[None]), robot_major(C[None]))
    assert np.allclose(goals[:, :, 0].T, P, atol=1e-12)
    assert dist.max() < 1e-12


def test_rank_goals_are_a_matching_to_distinct_slots() -> None:
    C = make_pattern("heart", N)
    C = C - C.mean(axis=0)
    X = np.random.default_rng(3).uniform(-4, 4, size=(2, N, 5))
    goals, dist = rank_goals(X, np.repeat(robot_major(C[None]), 5, axis=2))
    centred = goals - X.mean(axis=1, keepdims=True)
    for e in range(5):
        got = {tuple(np.round(g, 9)) for g in centred[:, :, e].T}
        assert got == {tuple(np.round(c, 9)) for c in C}
    assert np.allclose(dist, np.hypot(*(X - goals)))


def test_the_team_axis_is_the_one_the_sweep_finds() -> None:
    Cs = [make_pattern(p, N) for p in ("circle", "cross", "line", "heart", "triangle")]
    deg, gap = axis_gap(Cs, steps=18000)
    assert deg == pytest.approx(TEAM_AXIS_DEG, abs=0.011)
    assert gap > 0.04  # 4.8 cm: nearly two formed tolerances (2.5 cm)


def world_obs(seed: int = 4) -> tuple[BatchWorld, np.ndarray]:
    bw = BatchWorld(6, N, "circle", SPEC, seed=seed, rank_goals=True)
    rng = np.random.default_rng(seed)
    obs = bw.observe()
    for _ in range(3):
        obs = bw.step(rng.normal(0.0, 1.0, size=(6, N, 2))).obs
    return bw, obs


def test_front_end_reads_centroid_rank_and_neighbours_from_the_paper_observation() -> None:
    bw, obs = world_obs()
    agent = Agent(SPEC.dim, CFG, 1.0)
    assert agent.front is not None
    f = agent.front(torch.from_numpy(obs.reshape(6 * N, -1))).numpy().reshape(6, N, -1)
    assert f.shape[-1] == front_dim(N) == 4 + N + 24
    P = bw.positions
    assert np.allclose(f[..., 0:2], P - P.mean(axis=1, keepdims=True), atol=1e-5)
    moved = (P - bw.prev_positions) - (P - bw.prev_positions).mean(axis=1, keepdims=True)
    assert np.allclose(f[..., 2:4], moved / 0.1, atol=1e-4)
    assert (f[..., 4 : 4 + N].sum(-1) == 1).all()
    assert (f[..., 4 : 4 + N].argmax(-1) == ranks(robot_major(P)).T).all()
    # the nearest other, nearest first: its relative position and velocity
    rel = paper_observation(bw.frames[:, :, :, :])[..., :2]
    assert np.allclose(f[..., 4 + N : 6 + N], rel, atol=1e-6)


def test_exported_brain_with_the_front_end_equals_the_agent_and_reads_back(tmp_path: Path) -> None:
    _, obs = world_obs(5)
    agent = Agent(SPEC.dim, CFG, 1.0)
    agent.normaliser.update(agent.front_features(torch.from_numpy(obs.reshape(-1, SPEC.dim))))
    with torch.no_grad():
        for p in agent.policy.mean_head.parameters():
            p.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(0))
    model = build_onnx(agent)
    x = obs.reshape(6 * N, -1)
    got = ort.InferenceSession(model.SerializeToString()).run(["action"], {"obs": x})[0]
    want = agent.act_mps(torch.from_numpy(x)).detach().numpy()
    assert np.abs(want).max() > 0.05  # a brain that moves, so the comparison means something
    assert np.allclose(got, want, atol=1e-5)
    path = tmp_path / "b.onnx"
    onnx.save(model, path)
    back = agent_from_onnx(path, CFG, 1.0)
    assert back.front is not None and back.obs_dim == SPEC.dim
    assert np.allclose(back.act_mps(torch.from_numpy(x)).detach().numpy(), want, atol=1e-6)
    with pytest.raises(BrainFileError, match="--obs paper"):
        agent_from_onnx(path, TrainConfig(obs="general"), 1.0)


def test_front_end_is_refused_on_the_general_observation() -> None:
    with pytest.raises(ValueError, match="paper observation"):
        TrainConfig(obs="general", front_end="rank")
    assert TrainConfig(obs="paper").front == "transport"
    assert TrainConfig(obs="paper", front_end="rank").front == "rank"
    assert TrainConfig(obs="paper", front_end="none").front == "none"
    assert TrainConfig(obs="general").front == "none"


def test_slots_front_end_points_each_robot_at_its_rank_slot(tmp_path: Path) -> None:
    bw, obs = world_obs(6)
    cfg = TrainConfig(obs="paper", n_robots=N, front_end="slots")
    agent = Agent(SPEC.dim, cfg, 1.0)
    assert agent.front is not None
    agent.front.set_pattern(make_pattern("circle", N))
    x = obs.reshape(6 * N, -1)
    f = agent.front(torch.from_numpy(x)).numpy().reshape(6, N, -1)
    assert f.shape[-1] == front_dim(N, "slots")
    goals, _ = rank_goals(bw._X, bw._C)  # the world's rank matching, the reward's goals
    want = goals.transpose(2, 1, 0) - bw.positions
    assert np.allclose(f[..., 0:2], want, atol=1e-5)
    step = want / np.maximum(np.linalg.norm(want, axis=-1, keepdims=True), 0.1)
    assert np.allclose(f[..., 2:4], step, atol=1e-5)
    agent.normaliser.update(agent.front_features(torch.from_numpy(obs.reshape(-1, SPEC.dim))))
    model = build_onnx(agent)
    got = ort.InferenceSession(model.SerializeToString()).run(["action"], {"obs": x})[0]
    assert np.allclose(got, agent.act_mps(torch.from_numpy(x)).detach().numpy(), atol=1e-5)
    onnx.save(model, tmp_path / "s.onnx")
    back = agent_from_onnx(tmp_path / "s.onnx", TrainConfig(obs="paper", n_robots=N), 1.0)
    assert back.front is not None and back.front.with_slots
    assert torch.equal(back.front.slots, agent.front.slots)


def test_progress_toward_rank_goals_telescopes_so_swapping_goals_cannot_be_farmed() -> None:
    from trainer.world.reward import RewardConfig

    only_progress = RewardConfig(step_penalty=0.0, collision_penalty=0.0, beta=0.0,
                                 progress_weight=1.0, formed_bonus=0.0)
    bw = BatchWorld(4, N, "circle", SPEC, seed=7, reward=only_progress, rank_goals=True,
                    step_limit=1000)
    _, d_start = rank_goals(bw._X, bw._C)
    rng = np.random.default_rng(7)
    total = np.zeros((4, N))
    swaps = 0
    before = ranks(bw._X)
    for _ in range(60):  # robots wander across each other: their ranks, and goals, swap
        res = bw.step(rng.normal(0.0, 1.0, size=(4, N, 2)))
        assert res.episode is None
        total += res.reward
        now = ranks(bw._X)
        swaps += int((now != before).sum())
        before = now
    _, d_end = rank_goals(bw._X, bw._C)
    assert swaps > 10
    assert np.allclose(total * bw.world.max_step_m, (d_start - d_end).T, atol=1e-4)


@pytest.mark.parametrize("pattern", ["circle", "heart", "line"])
def test_transport_front_end_finds_the_optimal_assignment_from_the_paper_observation(
    pattern: str,
) -> None:
    from runtime.decision.formation import assign_slots

    C = make_pattern(pattern, N)
    Cc = C - C.mean(axis=0)
    agent = Agent(SPEC.dim, TrainConfig(obs="paper", n_robots=N, front_end="transport"), 1.0)
    assert agent.front is not None
    agent.front.set_pattern(C)
    E = 40
    bw = BatchWorld(E, N, pattern, SPEC, seed=11)
    f = agent.front(torch.from_numpy(bw.observe().reshape(E * N, -1))).numpy().reshape(E, N, -1)
    P = bw.positions
    mine = f[..., 0:2] + (P - P.mean(axis=1, keepdims=True))  # slot about the centroid
    exact = 0
    for e in range(E):
        want = Cc[assign_slots(P[e], C)]  # scipy's optimal assignment, centred
        exact += bool(np.abs(mine[e] - want).max() < 1e-3)
    assert exact >= 0.85 * E  # the rest: near-ties, where the soft matching blends two slots


def test_transport_brain_exports_and_reads_back(tmp_path: Path) -> None:
    _, obs = world_obs(8)
    cfg = TrainConfig(obs="paper", n_robots=N, front_end="transport")
    agent = Agent(SPEC.dim, cfg, 1.0)
    assert agent.front is not None
    agent.front.set_pattern(make_pattern("triangle", N))
    agent.normaliser.update(agent.front_features(torch.from_numpy(obs.reshape(-1, SPEC.dim))))
    x = obs.reshape(6 * N, -1)
    model = build_onnx(agent)
    got = ort.InferenceSession(model.SerializeToString()).run(["action"], {"obs": x})[0]
    want = agent.act_mps(torch.from_numpy(x)).detach().numpy()
    assert np.allclose(got, want, atol=1e-5)
    onnx.save(model, tmp_path / "t.onnx")
    back = agent_from_onnx(tmp_path / "t.onnx", TrainConfig(obs="paper", n_robots=N), 1.0)
    assert back.front is not None and back.front.mode == "transport"
    assert np.allclose(back.act_mps(torch.from_numpy(x)).detach().numpy(), want, atol=1e-6)


def test_transport_solved_once_per_team_equals_once_per_robot() -> None:
    _, obs = world_obs(9)
    agent = Agent(SPEC.dim, TrainConfig(obs="paper", n_robots=N, front_end="transport"), 1.0)
    assert agent.front is not None
    agent.front.set_pattern(make_pattern("heart", N))
    x = torch.from_numpy(obs.reshape(6 * N, -1))
    per_robot = agent.front(x).numpy()
    per_team = agent.front(x, team_rows=N).numpy()
    assert np.allclose(per_team, per_robot, atol=2e-4)
