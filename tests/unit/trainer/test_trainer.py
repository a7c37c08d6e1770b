"""Trainer: returns, losses, lambda adaptation, and short real training runs."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from support.training import TINY, TINY_WORLD

from trainer.checkpoints import (
    InitError,
    best_record,
    is_better,
    load_checkpoint,
    new_best,
    save_checkpoint,
    start_state,
)
from trainer.config import TrainConfig, obs_spec_for, reward_for
from trainer.curve import CURVE_FIELDS, curve_row, write_curve
from trainer.ppo.networks import Agent, ObsNormaliser, gaussian_kl, gaussian_logprob
from trainer.ppo.storage import RolloutBatch, discounted_returns, gae
from trainer.ppo.update import UpdateStats, adapt_kl_coef, minibatches, policy_loss
from trainer.rollout import collect_rollout
from trainer.world.training_world import BatchWorld

# ------------------------------------------------------------------ returns


def _reference_returns(rewards, dones, last_values, gamma):
    """Plain loops: Phi_t = r_t + gamma r_{t+1} + ... up to the episode end or the cut."""
    T, E = rewards.shape
    out = np.zeros_like(rewards)
    for e in range(E):
        for t in range(T):
            total, discount = 0.0, 1.0
            for u in range(t, T):
                total += discount * rewards[u, e]
                if dones[u, e]:
                    break
                discount *= gamma
            else:
                total += discount * last_values[e]
            out[t, e] = total
    return out


def _reference_gae(rewards, values, dones, last_values, gamma, lam):
    T, E = rewards.shape
    adv = np.zeros_like(rewards)
    for e in range(E):
        for t in range(T):
            total, w = 0.0, 1.0
            for u in range(t, T):
                nv = last_values[e] if u == T - 1 else values[u + 1, e]
                delta = rewards[u, e] + gamma * nv * (1 - dones[u, e]) - values[u, e]
                total += w * delta
                if dones[u, e]:
                    break
                w *= gamma * lam
            adv[t, e] = total
    return adv


@pytest.fixture
def episode_data():
    rng = np.random.default_rng(3)
    T, E = 17, 5
    rewards = rng.normal(size=(T, E)).astype(np.float32)
    dones = (rng.random((T, E)) < 0.15).astype(np.float32)
    values = rng.normal(size=(T, E)).astype(np.float32)
    last = rng.normal(size=E).astype(np.float32)
    return rewards, dones, values, last


def test_discounted_returns_match_plain_loop(episode_data) -> None:
    rewards, dones, _, last = episode_data
    got = discounted_returns(rewards, dones, last, 0.9)
    ref = _reference_returns(rewards, dones, last, 0.9)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)


def test_returns_count_only_rewards_from_t_on() -> None:
    # one episode of 4 steps, reward only at step 1: Phi_0 = gamma, Phi_1 = 1, Phi_2 = Phi_3 = 0
    r = np.array([[0.0], [1.0], [0.0], [0.0]], np.float32)
    d = np.array([[0], [0], [0], [1]], np.float32)
    got = discounted_returns(r, d, np.array([99.0], np.float32), 0.5)[:, 0]
    np.testing.assert_allclose(got, [0.5, 1.0, 0.0, 0.0])


def test_gae_matches_plain_loop_and_is_mc_at_lambda_one(episode_data) -> None:
    rewards, dones, values, last = episode_data
    got = gae(rewards, values, dones, last, 0.9, 0.8)
    ref = _reference_gae(rewards, values, dones, last, 0.9, 0.8)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5)
    mc = discounted_returns(rewards, dones, last, 0.9) - values
    np.testing.assert_allclose(gae(rewards, values, dones, last, 0.9, 1.0), mc, atol=1e-5)


# ------------------------------------------------------------------ losses


def test_gaussian_logprob_and_kl_closed_forms() -> None:
    mean, std = torch.tensor([[0.1, -0.2]]), torch.tensor([[0.5, 0.3]])
    a = torch.tensor([[0.4, 0.0]])
    ref = torch.distributions.Normal(mean, std).log_prob(a).sum(-1)
    torch.testing.assert_close(gaussian_logprob(a, mean, std), ref)
    m2, s2 = torch.tensor([[0.0, 0.1]]), torch.tensor([[0.4, 0.6]])
    ref_kl = torch.distributions.kl_divergence(
        torch.distributions.Normal(mean, std), torch.distributions.Normal(m2, s2)
    ).sum(-1)
    torch.testing.assert_close(gaussian_kl(mean, std, m2, s2), ref_kl)
    assert float(gaussian_kl(mean, std, mean, std)) == pytest.approx(0.0, abs=1e-7)


def _hand_batch(old_mean: float, new_mean: float, action: float) -> tuple[RolloutBatch, float]:
    std = 0.5
    old = torch.tensor([[old_mean, 0.0]])
    s = torch.full((1, 2), std)
    a = torch.tensor([[action, 0.0]])
    batch = RolloutBatch(
        obs=torch.zeros(1, 3),
        actions=a,
        old_mean=old,
        old_std=s,
        old_logprob=gaussian_logprob(a, old, s),
        returns=torch.zeros(1),
        advantages=torch.ones(1),
    )
    # ratio = exp(-(a-m)^2/2s^2 + (a-m_old)^2/2s^2)
    ratio = math.exp((-((action - new_mean) ** 2) + (action - old_mean) ** 2) / (2 * std**2))
    return batch, ratio


def test_kl_penalty_loss_on_a_hand_case() -> None:
    batch, ratio = _hand_batch(old_mean=0.0, new_mean=0.2, action=0.3)
    kl = 0.2**2 / (2 * 0.5**2)  # equal stds: (m - m_old)^2 / 2 s^2
    cfg = TrainConfig(algo="pattern-rl")
    idx = torch.tensor([0])
    adv = torch.tensor([2.0])
    loss, r = policy_loss(
        torch.tensor([[0.2, 0.0]]), torch.full((1, 2), 0.5), batch, idx, adv, cfg, 3.0
    )
    assert float(r) == pytest.approx(ratio, rel=1e-5)
    assert float(loss) == pytest.approx(-(ratio * 2.0 - 3.0 * kl), rel=1e-5)


@pytest.mark.parametrize(
    ("new_mean", "adv", "clipped"),
    [
        (0.3, 1.0, True),  # ratio > 1 + eps with A > 0: clipped at 1.2
        (0.3, -1.0, False),  # ratio > 1 + eps with A < 0: the unclipped (worse) term
        (-0.3, 1.0, False),  # ratio < 1 - eps with A > 0: unclipped
        (-0.3, -1.0, True),  # ratio < 1 - eps with A < 0: clipped at 0.8
        (0.01, 1.0, False),  # inside the trust region
    ],
)
def test_clipped_ppo_loss_on_hand_cases(new_mean: float, adv: float, clipped: bool) -> None:
    batch, ratio = _hand_batch(old_mean=0.0, new_mean=new_mean, action=0.5)
    cfg = TrainConfig(algo="ppo", clip_coef=0.2)
    loss, _ = policy_loss(
        torch.tensor([[new_mean, 0.0]]),
        torch.full((1, 2), 0.5),
        batch,
        torch.tensor([0]),
        torch.tensor([adv]),
        cfg,
        kl_coef=123.0,  # ignored by PPO
    )
    expect_ratio = min(max(ratio, 0.8), 1.2) if clipped else ratio
    assert float(loss) == pytest.approx(-expect_ratio * adv, rel=1e-5)


def test_lambda_grows_when_kl_is_too_high_and_shrinks_when_too_low() -> None:
    cfg = TrainConfig(kl_target=0.01, kl_alpha=0.5, kl_coef_min=0.1, kl_coef_max=10.0)
    assert adapt_kl_coef(1.0, 0.1, cfg) == pytest.approx(2.0)  # KL too high: penalty x 1/alpha
    assert adapt_kl_coef(1.0, 0.001, cfg) == pytest.approx(0.5)  # KL too low: penalty x alpha
    assert adapt_kl_coef(1.0, 0.01, cfg) == pytest.approx(1.0)  # inside the band: unchanged
    assert adapt_kl_coef(8.0, 1.0, cfg) == pytest.approx(10.0)  # clipped to the range
    assert adapt_kl_coef(0.15, 0.0, cfg) == pytest.approx(0.1)
    slow = cfg.with_(kl_alpha=0.8)
    assert adapt_kl_coef(1.0, 0.1, slow) == pytest.approx(1.25)


def test_minibatches_cover_memory_without_repeats_per_pass() -> None:
    gen = torch.Generator().manual_seed(0)
    batches = list(minibatches(10, 3, 6, gen))
    assert [len(b) for b in batches] == [3] * 6
    first_pass = torch.cat(batches[:3])
    assert len(set(first_pass.tolist())) == 9


# ---------------------------------------------------------------- networks


def test_normaliser_matches_numpy_statistics() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(2.0, 3.0, size=(500, 4))
    x[:, 3] = 1.0  # a constant feature: centred, not scaled
    norm = ObsNormaliser(4)
    norm.update(x[:200])
    norm.update(x[200:])
    np.testing.assert_allclose(norm.mean64.numpy(), x.mean(0), rtol=1e-10)
    np.testing.assert_allclose(norm.var64.numpy(), x.var(0), rtol=1e-9, atol=1e-12)
    out = norm(torch.tensor([[2.0, 2.0, 2.0, 0.0]]))
    assert float(out[0, 3]) == pytest.approx(-1.0)


def test_policy_shapes_and_ranges() -> None:
    cfg = TrainConfig(algo="pattern-rl", init_std=0.5)
    agent = Agent(obs_dim=12, cfg=cfg, v_max_mps=2.0)
    obs = torch.randn(64, 12) * 100
    with torch.no_grad():
        mean, std = agent.policy(agent.features(obs))
    assert mean.shape == (64, 2) and std.shape == (64, 2)
    assert float(mean.abs().max()) <= 1.0
    assert float(std.min()) >= cfg.min_std
    assert float(std.mean()) == pytest.approx(0.5, abs=0.05)
    with torch.no_grad():
        assert float(agent.act_mps(obs).abs().max()) <= 2.0
    ppo = Agent(obs_dim=12, cfg=cfg.with_(algo="ppo"), v_max_mps=1.0)
    assert ppo.decoder is None


# -------------------------------------------------- a rollout, a checkpoint, the curve
# (training runs: tests/integration/test_training_runs.py)


def test_rollout_fills_memory_and_replays_with_the_same_generator() -> None:
    cfg = TINY.with_(seed=3)
    E, N, T = cfg.n_envs, cfg.n_robots, cfg.rollout_steps
    spec = obs_spec_for(cfg)
    agent = Agent(spec.dim, cfg, TINY_WORLD.v_max_mps)

    def once():
        bw = BatchWorld(E, N, "circle", spec, world=TINY_WORLD, reward=reward_for(cfg), seed=1)
        gen = torch.Generator().manual_seed(5)
        return collect_rollout(agent, bw, bw.observe(), cfg, gen, TINY_WORLD.v_max_mps)

    a, b = once(), once()
    assert a.batch.obs.shape == (T * E * N, spec.dim) and a.batch.actions.shape == (T * E * N, 2)
    assert a.obs.shape == (E, N, spec.dim)
    assert len(a.returns) == len(a.success)
    torch.testing.assert_close(a.batch.actions, b.batch.actions)
    torch.testing.assert_close(a.batch.advantages, b.batch.advantages)


def test_checkpoint_round_trip_and_the_best_rule(tmp_path) -> None:
    cfg = TINY.with_(seed=2)
    spec = obs_spec_for(cfg)
    st = start_state(cfg, spec, TINY_WORLD.v_max_mps, None, None)
    assert st.iteration == 0 and st.best["iteration"] == -1 and st.value_warmup == 0
    assert is_better(0.0, math.nan, new_best(st.agent))  # any evaluation beats none
    st.best = best_record(0.5, 40.0, 3, st.agent)
    assert is_better(0.5, 30.0, st.best) and not is_better(0.5, 40.0, st.best)
    assert not is_better(0.25, 10.0, st.best)
    hit = best_record(0.9, 40.0, 4, st.agent, collisions=3)  # 3 touches in the failed tenth
    assert is_better(0.9, 50.0, hit, collisions=1) and not is_better(0.9, 30.0, hit, 5)
    assert is_better(0.9, 30.0, hit, 3) and not is_better(0.8, 30.0, hit, 0)
    old = {k: v for k, v in hit.items() if k != "collisions"}  # an older checkpoint's record
    assert is_better(0.9, 30.0, old) and not is_better(0.9, 30.0, old, 1)
    st.iteration, st.episodes, st.kl_coef = 3, 17, 0.7
    st.curve = [{"iteration": 3, "stage": 0, "episodes": 17}]
    path = tmp_path / "run.ckpt.pt"
    save_checkpoint(path, st, cfg, spec, wall_s=1.5, stage=0)
    ck = load_checkpoint(path)
    back = start_state(TrainConfig.from_dict(ck["config"]), spec, TINY_WORLD.v_max_mps, ck, None)
    assert (back.iteration, back.episodes, back.kl_coef, back.wall0_s) == (3, 17, 0.7, 1.5)
    assert back.best["iteration"] == 3 and back.curve == st.curve
    assert torch.equal(back.gen.get_state(), st.gen.get_state())
    for k, v in st.agent.state_dict().items():
        torch.testing.assert_close(back.agent.state_dict()[k], v)
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InitError, match="cannot read checkpoint"):
        load_checkpoint(tmp_path / "bad.pt")


def test_curve_rows_and_csv(tmp_path) -> None:
    stats = UpdateStats(*([0.5] * len(UpdateStats._fields)))
    row = curve_row(iteration=1, stage=0, pattern="circle", episodes=4, agent_steps=64,
                    wall_s=0.1, recent_returns=[1.0, 3.0], recent_success=[True, False],
                    eval_success=math.nan, eval_steps=math.nan, stats=stats, kl_coef=0.2,
                    lr_scale=1.0)
    assert set(row) == set(CURVE_FIELDS)
    assert row["mean_reward"] == 2.0 and row["train_success"] == 0.5
    write_curve(tmp_path / "c.csv", [row])
    header, line = (tmp_path / "c.csv").read_text().splitlines()
    assert header.split(",") == list(CURVE_FIELDS)
    cells = dict(zip(CURVE_FIELDS, line.split(","), strict=True))
    assert cells["eval_success"] == "" and cells["mean_reward"] == "2"


# --------------------------------------------------------------------- CLI


def _cli(*argv: str) -> int:
    from patternrl.cli import main

    return main(list(argv))


def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    out = str(tmp_path / "b.onnx")
    assert _cli("train", "--pattern", "blob", "--out", out) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown pattern 'blob'" in err[0]
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"junk")
    assert _cli("train", "--init", str(junk), "--out", out, "--episodes", "1") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "junk.onnx" in err[0]
    assert _cli("train", "--init", str(tmp_path / "none.pt"), "--out", out) == 2
    assert _cli("eval", "--brain", str(junk), "--pattern", "circle") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("patternrl eval:")


def test_cli_eval_json_on_the_rule_brain(capsys) -> None:
    code = _cli(
        "eval",
        "--brain",
        "rule:assign",
        "--pattern",
        "circle",
        "--robots",
        "4",
        "--episodes",
        "2",
        "--seed",
        "3",
        "--json",
        "--no-progress",
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("success_rate", "collisions", "steps_ratio", "travel_ratio", "formation_error"):
        assert key in out
    assert out["success_rate"] == 1.0 and out["steps_ratio"] >= 1.0
