"""Team rules (runtime/decision/rules.py): synchronised straight lines in a frame per pattern."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from runtime.brain.brain import RULES, BrainError, RuleBrain, load_brain, make_rule
from runtime.core.plan_frame import min_enclosing_circle
from runtime.decision.controller import Controller
from runtime.decision.formation import assign_slots, lower_bounds
from runtime.decision.patterns import make_pattern
from runtime.decision.pipeline import decide_batch
from runtime.decision.rules import FRAME_RULES, FrameRule, frame_plan
from runtime.decision.safety import OrcaParams
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.world.brain_choice import brains_from_arg
from trainer.evaluate import evaluate_brain

W = DEFAULT_WORLD


def spread(n: int, rng: np.random.Generator, side: float) -> np.ndarray:
    """n points in a side x side square, at least 2.5 R apart (rejection sampling)."""
    pts: list[np.ndarray] = []
    while len(pts) < n:
        q = rng.uniform(0, side, 2)
        if all(np.hypot(*(q - p)) >= W.start_separation_m for p in pts):
            pts.append(q)
    return np.array(pts)


def run_plan(P: np.ndarray, C: np.ndarray, weight: float, steps: int) -> list[np.ndarray]:
    """The plan alone (no filter, no world contact model): positions at every step."""
    track = [P]
    for _ in range(steps):
        p = track[-1]
        slots = assign_slots(p, C)
        v = frame_plan(p[None], C[None], slots[None], weight)[0]
        track.append(p + W.dt_s * v)
    return track


@pytest.mark.parametrize("name", list(FRAME_RULES))
@pytest.mark.parametrize("pattern,n,seed", [("circle", 10, 1), ("heart", 25, 2), ("line", 7, 3)])
def test_every_robot_lands_on_its_slot_at_the_same_step(
    name: str, pattern: str, n: int, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    P = spread(n, rng, side=4.0)
    C = make_pattern(pattern, n)
    weight = FRAME_RULES[name]
    slots = assign_slots(P, C)
    d = P - C[slots]
    cx, cy, radius = min_enclosing_circle(d)
    centre = np.array([cx, cy])
    t = centre + weight * (d.mean(0) - centre)  # the blend of the two frames
    far = float(np.hypot(*(t - d).T).max())
    K = math.ceil(far / W.max_step_m - 1e-9)
    track = run_plan(P, C, weight, K + 3)
    goal = C[slots] + t  # the frame chosen at the start
    for k, p in enumerate(track):
        speeds = np.hypot(*((track[min(k + 1, len(track) - 1)] - p) / W.dt_s).T)
        assert speeds.max() <= W.v_max_mps + 1e-9
        left = np.hypot(*(p - goal).T)
        if k < K:
            assert (left > 1e-9).all()  # nobody is early: the arrival is synchronised
        else:
            np.testing.assert_allclose(p, goal, atol=1e-9)  # exactly there, and it stays
    if weight == 0.0:  # the minimax frame: the farthest robot needs the circle's radius
        assert K == math.ceil(radius / W.max_step_m - 1e-9)
    elif weight == 1.0:  # the centroid frame: the team's centroid never moves
        np.testing.assert_allclose(track[-1].mean(0), P.mean(0), atol=1e-9)


def test_the_frame_is_fixed_while_the_team_follows_the_plan() -> None:
    rng = np.random.default_rng(5)
    P = spread(12, rng, side=3.0)
    C = make_pattern("triangle", 12)
    for weight in (0.0, 0.5, 1.0):
        track = run_plan(P, C, weight, 20)
        # every step heads for the same goals: no robot's direction ever turns
        turns = 0
        for a, b in itertools.pairwise(track):
            s_a = b - a
            s_b = frame_plan(b[None], C[None], assign_slots(b, C)[None], weight)[0]
            moving = np.hypot(*s_b.T) > 1e-9
            cross = s_a[moving, 0] * s_b[moving, 1] - s_a[moving, 1] * s_b[moving, 0]
            dot = (s_a[moving] * s_b[moving]).sum(-1)
            turns += int((np.abs(cross) > 1e-9).sum() + (dot < 0).sum())
        assert turns == 0
        assert np.hypot(*(track[-1] - track[-2]).T).max() < 1e-12  # landed and still


def test_frame_rule_takes_no_more_steps_and_less_travel_than_rule_assign() -> None:
    """Safety off, same seeded starts: rule:frame never loses on either ratio here."""
    kw = {"seed": 918273, "safety": None, "progress": False}
    a = evaluate_brain(RuleBrain(), "circle", 10, 8, **kw)
    f = evaluate_brain(make_rule("rule:frame"), "circle", 10, 8, **kw)
    t = evaluate_brain(make_rule("rule:frame-travel"), "circle", 10, 8, **kw)
    assert f.success_rate == a.success_rate == t.success_rate == 1.0
    assert f.steps_ratio <= a.steps_ratio
    assert f.travel_ratio < a.travel_ratio - 0.03
    assert t.travel_ratio < f.travel_ratio  # the centroid frame: fewer metres, more steps
    assert t.steps_ratio > f.steps_ratio


def test_steps_of_the_minimax_frame_meet_the_lower_bound_when_assignments_agree() -> None:
    # two robots, two slots: the squared-distance and bottleneck assignments coincide
    P = np.array([[0.0, 0.0], [3.0, 0.4]])
    C = np.array([[0.0, 0.0], [0.4, 0.0]])
    _, lb_steps = lower_bounds(P, C)
    track = run_plan(P, C, 0.0, lb_steps)
    slots = assign_slots(track[-1], C)
    d = track[-1] - C[slots]
    assert np.hypot(*(d - d[0]).T).max() < 1e-9  # formed after exactly the lower bound


@pytest.mark.parametrize("safety", [None, OrcaParams()])
def test_robot_and_batch_paths_agree_number_for_number(safety: OrcaParams | None) -> None:
    rng = np.random.default_rng(11)
    n, E, T = 7, 3, 6
    brain = make_rule("rule:frame")
    C = make_pattern("circle", n)
    walks = []
    for _ in range(E):
        p = spread(n, rng, side=1.4)
        w = [p]
        for _ in range(T - 1):
            w.append(w[-1] + rng.uniform(-0.08, 0.08, p.shape))
        walks.append(np.array(w))
    walks_a = np.array(walks)
    ctrls = [[Controller(brain, W, safety) for _ in range(n)] for _ in range(E)]
    prev = None
    for t in range(T):
        frames = np.stack([walks_a[:, max(t - j, 0)] for j in range(3)], axis=1)
        vel, slots, _ = decide_batch(brain, frames, C, prev, safety, W)
        prev = slots
        for e in range(E):
            for i in range(n):
                d = ctrls[e][i].decide(i, walks_a[e, t], C, t)
                assert d.error == ""
                assert d.slot == slots[e, i]
                np.testing.assert_array_equal(d.velocity, vel[e, i])


def test_rules_are_selectable_by_name_everywhere() -> None:
    assert set(FRAME_RULES) <= set(RULES)
    for name in RULES:
        b = load_brain(name)
        assert b.brain_id == name
        assert brains_from_arg(name, ["circle"], 10, "general")["circle"].ref == name  # type: ignore[index]
    assert isinstance(load_brain("rule:frame"), FrameRule)
    with pytest.raises(BrainError, match="unknown rule brain 'rule:nope'"):
        load_brain("rule:nope")
