"""A paper-observation brain learns: a short seeded run on a small team raises its reward."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from runtime.world_config import DEFAULT_WORLD
from trainer.config import TrainConfig
from trainer.train import RunPlan, train

SMALL = TrainConfig(
    obs="paper",
    n_robots=4,
    n_envs=16,
    rollout_steps=16,
    minibatch=512,
    ae_steps=8,
    policy_steps=8,
    value_steps=8,
    eval_every=1000,
    eval_episodes=4,
    desync=False,
)
SMALL_WORLD = DEFAULT_WORLD.with_(step_limit=60)


def rewards(curve: list[dict[str, object]]) -> list[float]:
    out = [float(r["mean_reward"]) for r in curve]  # type: ignore[arg-type]
    return [r for r in out if math.isfinite(r)]


@pytest.mark.parametrize("front_end", ["rank", "transport"])
def test_paper_brain_mean_reward_rises(tmp_path: Path, front_end: str) -> None:
    cfg = SMALL.with_(front_end=front_end)
    plan = RunPlan(patterns=["line"], out=tmp_path / "p.onnx", episodes=400, progress=False,
                   write_files=False, world=SMALL_WORLD)
    res = train(cfg, plan)
    r = rewards(res.curve)
    assert len(r) >= 12
    first, last = float(np.mean(r[:4])), float(np.mean(r[-4:]))
    assert last > first + 0.25 * abs(first) + 1.0, (first, last)


def test_a_pattern_sequence_gives_the_brain_each_stage_s_pattern(tmp_path: Path) -> None:
    from runtime.decision.patterns import make_pattern

    cfg = SMALL.with_(front_end="transport")
    plan = RunPlan(patterns=["circle", "line"], out=tmp_path / "s.onnx", episodes=8,
                   progress=False, write_files=False, world=SMALL_WORLD)
    res = train(cfg, plan)
    front = res.agent.front
    assert front is not None and front.mode == "transport"
    line = make_pattern("line", 4)
    line = line - line.mean(axis=0)
    got = sorted(tuple(round(float(v), 4) for v in p) for p in front.slots.numpy())
    assert got == sorted(tuple(round(float(v), 4) for v in p) for p in line)


def test_a_brain_that_carries_its_pattern_refuses_random_shapes(tmp_path: Path) -> None:
    from runtime.errors import InputError

    plan = RunPlan(patterns=["random"], out=tmp_path / "r.onnx", episodes=4, progress=False,
                   write_files=False, world=SMALL_WORLD)
    with pytest.raises(InputError, match="carries one pattern"):
        train(SMALL.with_(front_end="transport"), plan)
