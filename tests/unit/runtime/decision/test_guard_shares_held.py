"""Shares of the guard's room held for the views' age: a robot takes the least of its shares
over the last ``latency_steps + 1`` steps, so its peer never counts on room the robot took
under a larger share and cannot give back. The charging adversary, 25 robots, views 3 steps
old, collided there (the circle, seed 3000000, episode 14: 1 colliding pair) and no longer
does."""

from __future__ import annotations

import numpy as np

from runtime.conditions import parse_conditions
from runtime.decision.local import Perception
from trainer.adversary import ChargeBrain
from trainer.evaluate import evaluate_brain


def test_the_share_taken_is_the_least_of_the_views_age() -> None:
    late = 3
    p = Perception(parse_conditions(f"perfect,latency_steps={late}"), np.array([0, 1]),
                   [np.random.SeedSequence(i) for i in range(2)], estimator=True)
    rng = np.random.default_rng(0)
    truth = np.array([[[0.0, 0.0], [1.0, 0.0]]] * 2)
    raw: list[np.ndarray] = []
    taken: list[np.ndarray] = []
    for step in range(30):
        v = rng.uniform(-1.0, 1.0, (2, 2)) * 0.1
        truth = truth + v[None]  # both robots move; each observes the pair
        seen = p.perceive(truth, step=step)
        assert seen.guard_ref is not None
        taken.append(seen.guard_ref[..., 5].copy())
        raw.append(np.full((2, 2), np.nan) if p._share is None else p._share.copy())
    checked = 0
    for t in range(late, 30):
        window = np.array(raw[t - late: t + 1])
        if np.isnan(window).any():  # the first steps: no last step to move from
            continue
        assert np.allclose(taken[t], window.min(axis=0))
        checked += 1
    assert checked >= 20
    assert (np.abs(np.array(raw[late + 1:]) - 0.5) > 1e-6).any()  # shares moved by need
    assert (np.array(taken[late + 1:]) < np.array(raw[late + 1:]) - 1e-9).any()  # held


def test_the_charging_adversary_no_longer_collides_three_steps_late_at_25() -> None:
    r = evaluate_brain(ChargeBrain(), "circle", 25, 15, seed=3_000_000,
                       conditions=parse_conditions("latency_steps=3"), progress=False)
    assert r.collisions == 0 and r.min_separation_m >= 0.2
