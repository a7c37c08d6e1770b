"""A run under several conditions at once: the envs and held-out episodes split among them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from patternrl.cli import main
from runtime.conditions import PERFECT, parse_conditions
from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig, obs_spec_for
from trainer.ppo.networks import Agent
from trainer.rollout import InProcessRollouts, condition_shares, stage_parts, stage_world
from trainer.train import evaluate_policy

MIX = TrainConfig(obs="general", n_robots=4, n_envs=5, rollout_steps=6, minibatch=64,
                  eval_episodes=4, seed=3, conditions="perfect; realistic ;noise_m=0.2")
WORLD = DEFAULT_WORLD.with_(step_limit=15)


def test_a_mixture_parses_in_order_and_bad_mixtures_are_refused() -> None:
    assert MIX.condition_mix == (PERFECT, parse_conditions("realistic"),
                                 parse_conditions("noise_m=0.2"))
    assert [s for s, _ in condition_shares(MIX)] == [(0, 2), (2, 4), (4, 5)]
    assert TrainConfig(conditions="realistic").world_conditions == parse_conditions("realistic")
    with pytest.raises(ValueError, match="mixture of 3"):
        MIX.world_conditions  # noqa: B018 -- the property raises
    for bad, match in [("perfect;;realistic", "non-empty"), (";".join(["perfect"] * 9), "at most"),
                       ("perfect;nope", "unknown preset")]:
        with pytest.raises(ValueError, match=match):
            TrainConfig(conditions=bad)
    with pytest.raises(ValueError, match="at least as many envs"):
        MIX.with_(n_envs=2)
    with pytest.raises(ValueError, match="general or plan"):
        TrainConfig(obs="paper", conditions="perfect;noise_m=0.1")


def test_each_condition_holds_its_envs_whoever_plays_them() -> None:
    """One process's parts, and a worker's share across a boundary, start where one world of
    all the envs starts, each part under its own condition."""
    whole, _ = stage_world(MIX.with_(conditions="perfect"), WORLD, "line", 0, 0)
    parts = stage_parts(MIX, WORLD, "line", 0, 0)
    assert [p.bw.conditions for p in parts] == list(MIX.condition_mix)
    assert [p.cfg.n_envs for p in parts] == [2, 2, 1]
    assert np.array_equal(np.concatenate([p.bw.positions for p in parts]), whole.positions)
    share = stage_parts(MIX, WORLD, "line", 0, 0, (1, 3))  # a Ray worker's envs 1 and 2
    assert [(p.cfg.n_envs, p.bw.conditions) for p in share] == [
        (1, PERFECT), (1, parse_conditions("realistic"))]
    assert np.array_equal(share[1].bw.positions, whole.positions[2:3])


def test_a_rollout_of_a_mixture_holds_every_condition_s_samples() -> None:
    spec = obs_spec_for(MIX)
    agent = Agent(spec.input_dim, MIX, WORLD.v_max_mps)
    src = InProcessRollouts(MIX, WORLD, "random", 0, 0)
    ro = src.collect(agent, torch.Generator().manual_seed(0))
    assert ro.batch.obs.shape[0] == MIX.rollout_steps * MIX.n_envs * MIX.n_robots
    assert ro.obs.shape[:2] == (MIX.n_envs, MIX.n_robots)
    assert torch.isfinite(ro.batch.advantages).all() and len(ro.returns) == len(ro.success)
    again = src.collect(agent, torch.Generator().manual_seed(1))  # each part goes on
    assert again.batch.obs.shape == ro.batch.obs.shape


def test_held_out_episodes_split_as_the_envs_under_each_condition() -> None:
    """A mixture of one condition twice judges exactly the episodes one condition does (to
    the last bits of the policy's arithmetic, which a batch of another size may round
    otherwise); a noisy second half changes the outcome."""
    cfg = MIX.with_(conditions="perfect", eval_episodes=4)
    agent = Agent(obs_spec_for(cfg).input_dim, cfg, WORLD.v_max_mps)
    one = evaluate_policy(agent, cfg, "line", 4, seed=5, world=WORLD)
    twice = evaluate_policy(agent, cfg.with_(conditions="perfect;perfect"), "line", 4, seed=5,
                            world=WORLD)
    noisy = evaluate_policy(agent, cfg.with_(conditions="perfect;noise_m=0.3"), "line", 4,
                            seed=5, world=WORLD)
    assert twice == pytest.approx(one, rel=1e-9, nan_ok=True)
    assert noisy.formation_error != one.formation_error


def test_a_brain_trained_under_conditions_is_judged_under_each_in_its_manifest(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`patternrl train --conditions 'perfect;noise_m=0.05'`: the manifest's evaluation holds
    the perfect world's block as ever and one more for the noise, with the tracker, held."""
    out = tmp_path / "b.onnx"
    code = main(["train", "--pattern", "line", "--obs", "plan", "--robots", "4", "--envs", "2",
                 "--eval-episodes", "2", "--conditions", "perfect;noise_m=0.05", "--set",
                 "rollout_steps=4", "--set", "minibatch=16", "--time-budget-s", "0",
                 "--final-eval-episodes", "3", "--no-progress", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    ev = json.loads(out.with_suffix(".json").read_text())["evaluation"]
    assert list(ev["conditions"]) == ["noise_m=0.05"]
    noisy = ev["conditions"]["noise_m=0.05"]
    assert (noisy["episodes"], noisy["hold_steps"], noisy["estimator"]) == (3, 20, True)
    assert ev["episodes"] == 3 and ev["hold_steps"] == 0  # the perfect world's, as ever
    assert "noise_m=0.05 (tracker, held): success" in text
