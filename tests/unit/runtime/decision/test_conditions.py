"""Conditions: presets, overrides, one-line errors; the sensor, the tracker and the wheels."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from runtime.conditions import PERFECT, PRESETS, Conditions, parse_conditions
from runtime.decision.estimator import PeerTracker, steady_sigma
from runtime.decision.kinematics import Wheels
from runtime.decision.safety import OrcaParams, uncertainty_margin, uncertainty_params
from runtime.decision.sensing import Sensor
from runtime.errors import InputError


def test_presets_and_overrides_round_trip() -> None:
    c = parse_conditions("realistic,latency_steps=2,kinematics=diff")
    assert c.latency_steps == 2 and c.kinematics == "diff" and c.noise_m == 0.05
    assert Conditions.from_dict(c.to_dict()) == c
    assert parse_conditions(c.name()) == c
    assert parse_conditions("realistic").name() == "realistic"
    assert parse_conditions(None) is PERFECT and PERFECT.perfect
    assert parse_conditions("range_m=inf") == PERFECT
    assert not PRESETS["harsh"].acting_perfect and not PRESETS["harsh"].sensing_perfect


@pytest.mark.parametrize("spec", ["nonsense", "noise_m=-1", "noise_m=abc", "latency_steps=1.5",
                                  "loss=1", "kinematics=tank", "realistic,foo=1", "k_nearest=-2",
                                  "latency_steps=999", "range_m=0"])
def test_bad_specs_are_one_line_input_errors(spec: str) -> None:
    with pytest.raises(InputError) as e:
        parse_conditions(spec)
    assert "\n" not in str(e.value) and str(e.value).startswith("conditions:")


def _team(n: int, B: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    return np.repeat(rng.uniform(0, 5, (1, n, 2)), B, axis=0)


def test_perfect_sensor_sees_the_truth() -> None:
    P = _team(6, 6)
    view, age = Sensor(PERFECT, np.arange(6), list(range(6))).sense(P)
    assert np.array_equal(view, P) and not age.any()


def test_latency_shows_peers_late_and_the_own_pose_fresh() -> None:
    n = 4
    s = Sensor(Conditions(latency_steps=2), np.arange(n), list(range(n)))
    frames = [_team(n, n) + k for k in range(4)]
    for P in frames:
        view, age = s.sense(P)
    for b in range(n):
        for j in range(n):
            want = frames[3][b, j] if j == b else frames[1][b, j]
            assert np.array_equal(view[b, j], want)
            assert age[b, j] == (0 if j == b else 2)


def test_k_nearest_and_range_keep_unseen_peers_where_last_seen() -> None:
    n = 8
    P = np.zeros((1, n, 2))
    P[0, :, 0] = np.arange(n)  # a row, 1 m apart; observer 0 at x = 0
    s = Sensor(Conditions(k_nearest=2), np.array([0]), [1])
    s.sense(P)  # the roll call: everyone seen
    moved = P + 0.5
    view, age = s.sense(moved)
    assert np.allclose(view[0, 1:3], moved[0, 1:3])  # the 2 nearest follow
    assert np.allclose(view[0, 3:], P[0, 3:]) and (age[0, 3:] == 1).all()  # the rest stay
    s2 = Sensor(Conditions(range_m=2.5), np.array([0]), [1])
    s2.sense(P)
    view2, _ = s2.sense(moved)
    assert np.allclose(view2[0, 1:3], moved[0, 1:3]) and np.allclose(view2[0, 3:], P[0, 3:])


def test_noise_and_loss_have_their_stated_size_and_are_seeded() -> None:
    n, B = 10, 50
    c = Conditions(noise_m=0.05, loss=0.3)
    P = _team(n, B)
    s = Sensor(c, np.zeros(B, dtype=np.int64), list(range(B)))
    s.sense(P)
    errs, lost = [], []
    for _ in range(20):
        view, age = s.sense(P)
        fresh = age[:, 1:] == 0
        errs.append((view - P)[:, 1:][fresh])
        lost.append(1 - fresh.mean())
    e = np.concatenate(errs)
    assert abs(e.std() - 0.05) < 0.005
    assert abs(float(np.mean(lost)) - 0.3) < 0.03
    assert np.array_equal(_second_view(c, P, list(range(B))), _second_view(c, P, list(range(B))))
    assert not np.array_equal(_second_view(c, P, list(range(B))),
                              _second_view(c, P, list(range(1, B + 1))))


def _second_view(c: Conditions, P: np.ndarray, seeds: list[int]) -> np.ndarray:
    s = Sensor(c, np.zeros(len(seeds), dtype=np.int64), seeds)
    s.sense(P)
    return s.sense(P)[0]


def test_tracker_beats_the_raw_view_on_noise_and_latency() -> None:
    """A peer moving at constant velocity, seen 2 steps late with 5 cm noise: the tracker's
    estimate of where it is now is closer than the raw view."""
    rng = np.random.default_rng(4)
    tr = PeerTracker(np.array([0]), noise_m=0.05, latency_steps=2)
    v = np.array([0.5, -0.3])
    raw_err, est_err = [], []
    for t in range(200):
        true_now = np.array([[0.0, 0.0], v * 0.1 * t])
        seen = np.array([[0.0, 0.0], v * 0.1 * (t - 2) + rng.normal(0, 0.05, 2)])
        x, vel, sigma = tr.update(seen[None], np.array([[0, 2]]))
        if t > 50:
            raw_err.append(np.linalg.norm(seen[1] - true_now[1]))
            est_err.append(np.linalg.norm(x[0, 1] - true_now[1]))
    assert np.mean(est_err) < 0.5 * np.mean(raw_err)
    assert sigma[0, 0] == 0.0 and sigma[0, 1] == pytest.approx(steady_sigma(0.05))
    assert np.allclose(vel[0, 1], v, atol=0.15)


def test_tracker_averages_a_still_peer_longer_and_follows_one_that_moves() -> None:
    """A peer that keeps still is averaged at the still gain (half the error or less than
    at the moving gain, 10 cm noise); one that drives off at full speed is followed within
    a few steps as before."""
    rng = np.random.default_rng(5)
    errs: dict[bool, list[float]] = {True: [], False: []}
    for still in (True, False):
        tr = PeerTracker(np.array([0]), noise_m=0.1, still=still)
        peer = np.array([1.0, 0.0])
        for t in range(200):
            z = np.array([[[0.0, 0.0], peer + rng.normal(0, 0.1, 2)]])
            x, _, _ = tr.update(z, np.zeros((1, 2), dtype=np.int64))
            if t >= 50:
                errs[still].append(float(np.hypot(*(x[0, 1] - peer))))
    assert np.mean(errs[True]) < 0.7 * np.mean(errs[False])
    tr = PeerTracker(np.array([0]), noise_m=0.01)
    for t in range(40):
        peer = np.array([1.0 + max(t - 20, 0) * 0.1, 0.0])  # still, then off at 1 m/s
        x, v, _ = tr.update(np.array([[[0.0, 0.0], peer]]), np.zeros((1, 2), dtype=np.int64))
    assert np.hypot(*(x[0, 1] - peer)) < 0.05 and v[0, 1, 0] == pytest.approx(1.0, abs=0.1)


def test_tracker_is_the_view_when_the_view_is_exact() -> None:
    tr = PeerTracker(np.arange(3))
    rng = np.random.default_rng(1)
    for _ in range(5):
        P = np.repeat(rng.uniform(0, 3, (1, 3, 2)), 3, axis=0)
        x, _, _ = tr.update(P, np.zeros((3, 3), dtype=np.int64))
        assert np.allclose(x, P, atol=1e-12)


def test_tracker_carries_a_peer_out_of_view_along_the_plan_and_takes_it_back_seen() -> None:
    tr = PeerTracker(np.arange(1))
    still = np.zeros((1, 2), dtype=np.int64)
    team = np.array([[[0.0, 0.0], [5.0, 0.0]]])
    tr.update(team, still)  # the roll call
    follow = np.array([[[np.nan, np.nan], [0.0, 0.5]]])  # the plan: up at 0.5 m/s
    for t in range(1, 5):  # out of view: the view keeps it where last seen, age growing
        x, v, _ = tr.update(team, np.array([[0, t]]), follow)
        assert np.allclose(x[0, 1], [5.0, 0.05 * t]) and np.allclose(v[0, 1], [0.0, 0.5])
        assert np.allclose(tr.sensed[0, 1], x[0, 1])  # the plan reads it where it is now
    x, _, _ = tr.update(np.array([[[0.0, 0.0], [5.1, 0.3]]]), still, follow)  # seen again
    assert np.allclose(x[0, 1], [5.1, 0.3]) and np.allclose(tr.sensed[0, 1], [5.1, 0.3])
    plain = PeerTracker(np.arange(1))  # without a plan: kept where last seen
    plain.update(team, still)
    x, _, _ = plain.update(team, np.array([[0, 3]]))
    assert np.allclose(x[0, 1], [5.0, 0.0])


def test_tracker_carries_late_views_along_the_plan_to_where_the_peer_is_now() -> None:
    """A peer on the team's plan (1 m/s for 10 steps, then still), seen 2 steps late without
    noise: ``planned`` is where it truly is at every step, the stop included; the view as
    sensed lags it by 2 steps and the constant-velocity estimate overshoots the stop.
    Without a plan ``planned`` is the view as sensed."""
    tr = PeerTracker(np.arange(1), latency_steps=2)
    plain = PeerTracker(np.arange(1), latency_steps=2)
    vel = [np.array([1.0, 0.0]) if t < 10 else np.zeros(2) for t in range(16)]
    true = [np.zeros(2)]
    for v in vel:
        true.append(true[-1] + 0.1 * v)
    overshoot = 0.0
    for t in range(16):
        seen = true[max(t - 2, 0)]
        view = np.array([[[0.0, 0.0], seen]])
        age = np.array([[0, 2]])  # as the sensor has it from the start (the roll call)
        follow = None if t == 0 else np.array([[[np.nan, np.nan], vel[t - 1]]])
        x, _, _ = tr.update(view, age, follow)
        plain.update(view, age)
        assert np.allclose(tr.planned[0, 1], true[t], atol=1e-9), t
        assert np.allclose(plain.planned, plain.sensed) and np.allclose(tr.sensed[0, 1], seen)
        overshoot = max(overshoot, x[0, 1, 0] - true[t][0])
    assert overshoot > 0.15  # the estimate now, at constant velocity, runs on past the stop


def test_tracker_carries_a_lost_update_along_the_plan_and_restarts_without_it() -> None:
    """Updates lost for 3 steps (the view's age grows): ``planned`` goes along the plan over
    the whole age; after a restart the plan of before is forgotten."""
    tr = PeerTracker(np.arange(1), latency_steps=1)
    team = np.array([[[0.0, 0.0], [1.0, 1.0]]])
    tr.update(team, np.array([[0, 0]]))  # the roll call
    plan = np.array([[[np.nan, np.nan], [0.0, 0.5]]])
    for t in range(1, 5):
        tr.update(team, np.array([[0, t]]), plan)
        assert np.allclose(tr.planned[0, 1], [1.0, 1.0 + 0.05 * t])
    tr.restart(np.arange(1))
    tr.update(team, np.array([[0, 0]]))
    tr.update(team, np.array([[0, 2]]))
    assert np.allclose(tr.planned[0, 1], [1.0, 1.0])  # no plan since the restart, still


@pytest.mark.parametrize("spec", ["latency_steps=1", "latency_steps=2", "latency_steps=3",
                                  "loss=0.3"])
def test_a_team_on_a_plan_with_late_exact_views_lands_as_in_the_perfect_world(spec: str) -> None:
    """Exact views, late or gappy, without the safety filter: every robot plans from its
    peers carried along the team's plan, and each episode lands in the very steps of the
    perfect world (planning from the views as sensed took 1.22x the lower bound at 2 steps
    late, the perfect world 1.05x). Two and three steps late the landing keeps the plan's
    frame of one moment (runtime.decision.settle, "The plan's frame, kept, then the median
    robot's"); in the centroid frame from its first step it took up to a step less than the
    views' age more."""
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    brain = load_brain("rule:frame-balanced")
    for shape in ("circle", "heart", "cross"):
        perfect = evaluate_brain(brain, shape, 10, 3, seed=5, safety=None, progress=False)
        late = evaluate_brain(brain, shape, 10, 3, seed=5, safety=None, estimator=True,
                              conditions=parse_conditions(spec), progress=False)
        assert late.success_rate == 1.0 and late.collisions == 0
        assert late.episode_stats["steps"] == perfect.episode_stats["steps"], shape


def test_one_step_late_lands_as_planned_with_the_filter() -> None:
    """Exact views one step late, the safety filter on: each episode lands in the very steps of
    the perfect world; the centroid frame, which 2 or more steps late need, starts a step or
    two short of the plan's frame and cost every one of these episodes a step."""
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    brain = load_brain("rule:frame-balanced")
    for shape in ("circle", "heart"):
        perfect = evaluate_brain(brain, shape, 10, 4, seed=5, progress=False)
        late = evaluate_brain(brain, shape, 10, 4, seed=5, estimator=True,
                              conditions=parse_conditions("latency_steps=1"), progress=False)
        assert late.success_rate == 1.0 and late.collisions == 0
        assert late.episode_stats["steps"] == perfect.episode_stats["steps"], shape


def test_wheels_gain_noise_and_diff_drive() -> None:
    c = Conditions(gain_noise=0.1, act_noise_mps=0.0, kinematics="diff", turn_rate_rps=2.0)
    w = Wheels(c, 2, 50, list(np.random.SeedSequence(3).spawn(2)), 0.1)
    assert np.all(np.abs(w.gain - 1) <= 0.1) and w.gain.std() > 0.02
    cmd = np.zeros((2, 50, 2))
    cmd[..., 0] = 0.5
    u = w.apply(cmd)
    heading = w.heading
    assert np.allclose(u[..., 0] * np.sin(heading) - u[..., 1] * np.cos(heading), 0, atol=1e-12)
    assert np.all(np.hypot(u[..., 0], u[..., 1]) <= 0.5 * w.gain + 1e-12)
    still = Wheels(Conditions(act_noise_mps=0.05), 1, 5, [np.random.SeedSequence(1)], 0.1)
    assert not still.apply(np.zeros((1, 5, 2))).any()  # a robot at rest stays at rest


def test_margin_grows_with_uncertainty_and_vanishes_when_perfect() -> None:
    assert uncertainty_margin(PERFECT) == 0.0
    assert uncertainty_params(OrcaParams(), PERFECT) == OrcaParams()
    assert 0 < uncertainty_margin(PRESETS["realistic"]) < uncertainty_margin(PRESETS["harsh"])
    wide, narrow = Conditions(noise_m=0.1), Conditions(noise_m=0.05)
    assert uncertainty_margin(wide) > uncertainty_margin(narrow)
    assert math.isfinite(uncertainty_margin(PRESETS["harsh"]))


def test_a_team_on_late_or_gappy_views_forms_and_holds_with_the_tracker() -> None:
    """Views 2 steps late, or 30 % of updates lost: each robot on its own view with the
    tracker forms, holds and never collides (ground truth)."""
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    brain = load_brain("rule:frame-balanced")
    for spec in ("latency_steps=2", "loss=0.3"):
        r = evaluate_brain(brain, "circle", 7, 3, seed=77, conditions=parse_conditions(spec),
                           estimator=True, progress=False)
        assert r.success_rate == 1.0 and r.collisions == 0 and r.held_rate == 1.0, spec


def test_the_filter_on_the_tracker_keeps_a_noisy_crowd_apart() -> None:
    """Robots that see each other with 5 cm noise: a filter on the raw views (velocities from
    their frame differences, no margin, no guard: ``naive``) lets them collide; the robots'
    own filter does not (same seeds, ground truth)."""
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    brain = load_brain("rule:assign")
    kw = {"conditions": parse_conditions("noise_m=0.05"), "progress": False}
    safe = evaluate_brain(brain, "heart", 10, 4, seed=5, **kw)
    bare = evaluate_brain(brain, "heart", 10, 4, seed=5, naive=True, **kw)
    assert bare.collisions > 0
    assert safe.collisions == 0 and safe.min_separation_m >= 0.2


@pytest.mark.parametrize(("spec", "bare_collides"), [
    ("noise_m=0.05", True), ("latency_steps=2", True), ("latency_steps=3", True),
    ("loss=0.3", True),
    ("gain_noise=0.1,act_noise_mps=0.02", False), ("kinematics=diff,turn_rate_rps=2", True),
    ("realistic", True)])
def test_a_brain_that_charges_its_nearest_peer_never_reaches_it(spec: str,
                                                                 bare_collides: bool) -> None:
    """Every robot drives at full speed at its nearest peer: the safety filter is the last
    word, and it keeps the team apart in ground truth under each condition up to the stated
    limits; the same team without what the robots know of their uncertainty (``naive``)
    collides, except with noisy wheels alone, which ORCA's fixed margin already covers."""
    from trainer.adversary import ChargeBrain
    from trainer.evaluate import evaluate_brain

    kw = {"conditions": parse_conditions(spec), "progress": False, "hold_steps": 0}
    safe = evaluate_brain(ChargeBrain(), "random", 10, 2, seed=11, **kw)
    bare = evaluate_brain(ChargeBrain(), "random", 10, 2, seed=11, naive=True, **kw)
    assert safe.collisions == 0 and safe.min_separation_m >= 0.2 - 1e-9
    assert (bare.collisions > 0) == bare_collides


def test_the_guards_margin_adds_independent_noises_in_quadrature() -> None:
    """Sensing noise and actuation noise are independent: the guard's margin for both is the
    root of the sum of their squares, less than the two margins side by side and more than
    either; latency adds none (the guard pairs each view with the robot's pose of its age)."""
    from runtime.decision.safety import guard_bound

    sense, act = guard_bound(parse_conditions("noise_m=0.05")), guard_bound(
        parse_conditions("act_noise_mps=0.02"))
    both = guard_bound(parse_conditions("noise_m=0.05,act_noise_mps=0.02"))
    assert both == pytest.approx(math.hypot(sense, act))
    assert max(sense, act) < both < sense + act
    assert guard_bound(parse_conditions("latency_steps=3")) == 0.0
    assert guard_bound(parse_conditions("noise_m=0.05,act_noise_mps=0.02,latency_steps=3")) \
        == pytest.approx(both)


@pytest.mark.parametrize("spec", ["harsh", "realistic", "noise_m=0.1"])
def test_the_guards_distance_is_where_the_filter_stops_an_approach(spec: str) -> None:
    """``guard_distance``: a robot driving at a still peer a little inside it may not close
    in at all, a little outside it may; a pattern spaced inside it draws a note."""
    from runtime.decision.safety import guard_distance, guard_note, make_filter

    params = uncertainty_params(OrcaParams(), parse_conditions(spec))
    g = guard_distance(params)
    assert guard_distance(OrcaParams()) == 0.0 and guard_distance(None) == 0.0
    flt = make_filter(params)
    vel = np.zeros((1, 2, 2))
    approach = {}
    for d in (g - 0.01, g + 0.04):
        pos = np.array([[[0.0, 0.0], [d, 0.0]]])
        vx, _, _, _ = flt.robot(0, 0, pos, vel, 0.2, 0.0, 2.0)
        approach[d] = vx
    assert approach[g - 0.01] <= 1e-9 < approach[g + 0.04]
    assert guard_note(g, g - 0.01) is not None and guard_note(g, g + 0.01) is None
    assert guard_note(0.0, 0.4) is None and guard_note(g, math.nan) is None


@pytest.mark.parametrize("gain", [0.1, 0.3])
def test_the_wheels_gain_bounds_the_guards_command_not_its_distance(gain: float) -> None:
    """Wheels whose gain may be off by ``gain``: the guard keeps the distance it keeps without
    them and divides its bounds on the command by ``1 + gain`` instead, and a team driven at
    its nearest peers by wheels that far off still never reaches them (ground truth)."""
    from runtime.decision.safety import guard_bound
    from trainer.adversary import ChargeBrain
    from trainer.evaluate import evaluate_brain

    cond = parse_conditions(f"gain_noise={gain},act_noise_mps=0.02")
    params = uncertainty_params(OrcaParams(), cond)
    assert params.guard_gain == gain
    assert params.guard_margin_m == guard_bound(parse_conditions("act_noise_mps=0.02"))
    r = evaluate_brain(ChargeBrain(), "random", 10, 2, seed=13, conditions=cond,
                       progress=False, hold_steps=0)
    assert r.collisions == 0 and r.min_separation_m >= 0.2 - 1e-9


@pytest.mark.parametrize(("spec", "by_need"), [("latency_steps=2", True),
                                               ("gain_noise=0.1,act_noise_mps=0.02", True),
                                               ("noise_m=0.05", False), ("loss=0.1", False),
                                               ("latency_steps=2,own_latency_steps=1", False)])
def test_robots_split_the_guards_room_by_need_only_on_exact_views(spec: str,
                                                                  by_need: bool) -> None:
    """Each robot of a moving team perceives it on its own (its own sensor and tracker): with
    exact views, late or on noisy wheels, the two robots of every pair reckon shares of the
    guard's room that sum to 1 and move toward their need by at most ``GUARD_SHARE_RATE`` a
    step, and each takes the least of its reckoned shares over the views' age, so the two it
    takes sum to at most 1; under noise or loss, half each. A missed world step or a restart
    brings them back toward half."""
    from runtime.core.orca import GUARD_REF_COLUMNS
    from runtime.decision.local import GUARD_SHARE_RATE, Perception

    n = 4
    cond = parse_conditions(spec)
    per = Perception(cond, np.arange(n), [np.random.SeedSequence((3, i)) for i in range(n)],
                     estimator=True)
    rng = np.random.default_rng(8)
    team = rng.uniform(-1.0, 1.0, (n, 2))
    step = rng.uniform(-0.08, 0.08, (n, 2))
    step[0] = 0.0  # one stands still
    off = ~np.eye(n, dtype=bool)
    last = np.full((n, n), 0.5)
    last_reckoned = last.copy()
    most = 0.0  # the farthest any share came from half
    for t in (*range(10), 11):  # world steps, the tenth missed (a robot process)
        seen = per.perceive(np.repeat(team[None], n, axis=0), None, t)
        assert seen.guard_ref is not None and seen.guard_ref.shape == (n, n, GUARD_REF_COLUMNS)
        share = seen.guard_ref[..., 5]
        assert ((share + share.T)[off] <= 1.0 + 1e-12).all()
        reckoned = share if per._share is None else per._share
        np.testing.assert_allclose((reckoned + reckoned.T)[off], 1.0, atol=1e-12)
        assert (share <= reckoned + 1e-12).all()
        assert np.abs(share - last).max() <= GUARD_SHARE_RATE + 1e-12
        if t == 11:  # no last step to read: back toward half
            gone = np.abs(last_reckoned - 0.5)
            assert (np.abs(reckoned - 0.5)
                    <= np.maximum(gone - GUARD_SHARE_RATE, 0) + 1e-12).all()
        last, last_reckoned = share.copy(), reckoned.copy()
        most = max(most, float(np.abs(share - 0.5).max()))
        team = team + step * (2 if t == 9 else 1)
    assert (most > 0.25) if by_need else (most == 0.0)
    per.restart(np.arange(n))
    for _ in range(3):  # from halves again
        share = per.perceive(np.repeat(team[None], n, axis=0)).guard_ref[..., 5]
        assert np.abs(share - 0.5).max() <= GUARD_SHARE_RATE + 1e-12


def _pairs_seen(per: Any, team: np.ndarray, move: np.ndarray, steps: int,
                follow: np.ndarray | None = None) -> Iterator[tuple[int, int, int, Any, list]]:
    """A team moving by ``move`` a step, each robot perceiving it (``per``, one observer per
    robot): every step, each pair (b, j) with the age of b's view of j, that step's ``Seen``
    and the team's positions so far, newest first."""
    n = len(team)
    path: list[np.ndarray] = []
    for _ in range(steps):
        path.insert(0, team.copy())
        seen = per.perceive(np.repeat(team[None], n, axis=0), follow)
        age = per.last_age
        assert seen.guard_ref is not None and age is not None
        for b in range(n):
            for j in range(n):
                if j != b and int(age[b, j]) < len(path):
                    yield b, j, int(age[b, j]), seen, path
        team = team + move


@pytest.mark.parametrize("spec", ["realistic", "loss=0.3,latency_steps=2"])
def test_a_lost_update_pairs_the_view_with_the_own_pose_of_the_latencys_age(spec: str) -> None:
    """A peer whose last update was lost is paired, for the guard, with where the robot stood
    the latency's age ago (the moment its peer's own bound counts from when its view came on
    time), and may lie the way it could have come unseen since its view off it: a full step,
    what the wheels' gain adds and their noise, for each step the view is older than the
    latency, counted up to the lost run the guard covers. A peer seen on time is paired with
    the robot's pose of its view's age, and nothing unseen."""
    from runtime.decision.local import LOST_TAIL, Perception

    n = 6
    cond = parse_conditions(spec)
    late = cond.latency_steps
    covered = late + math.ceil(math.log(LOST_TAIL) / math.log(cond.loss))
    per = Perception(cond, np.arange(n), [np.random.SeedSequence((4, i)) for i in range(n)],
                     estimator=True)
    rng = np.random.default_rng(2)
    team = rng.uniform(-1.5, 1.5, (n, 2))
    step = rng.uniform(-0.09, 0.09, (n, 2))
    reach = 0.1 * (1.0 + cond.gain_noise) + 2.0 * cond.act_noise_mps * 0.1
    lost_seen = 0
    for b, j, a, seen, path in _pairs_seen(per, team, step, 40):
        ref = seen.guard_ref[b, j]
        if a > late:  # lost: the own pose of the latency's age, and the way unseen
            lost_seen += 1
            np.testing.assert_allclose(ref[2:4], path[late][b], atol=1e-12)
            unseen = (min(a, covered) - late) * reach
            assert ref[4] == pytest.approx(unseen, abs=1e-12) and ref[4] > 0.0
        else:
            np.testing.assert_allclose(ref[2:4], path[a][b], atol=1e-12)
            assert ref[4] == 0.0
    assert lost_seen > 20


@pytest.mark.parametrize("spec", ["k_nearest=2", "range_m=1.2", "k_nearest=2,latency_steps=2"])
def test_a_peer_out_of_view_is_bounded_where_the_plan_carried_it(spec: str) -> None:
    """A peer beyond the k nearest, or out of range, is known to lie farther than those in
    view; the guard bounds it from the tracker's estimate now (its last view carried along
    the team's plan), paired with the robot's own pose now, not from its stale view paired
    with the robot's pose of that age, a phantom where the peer was long ago. A peer in view
    is still paired with its view and the robot's pose of the view's age."""
    from runtime.decision.local import Perception

    n = 6
    cond = parse_conditions(spec)
    late = cond.latency_steps
    per = Perception(cond, np.arange(n), [np.random.SeedSequence((5, i)) for i in range(n)],
                     estimator=True)
    assert per.follows_plans
    rng = np.random.default_rng(3)
    team = rng.uniform(-1.5, 1.5, (n, 2))
    vel = rng.uniform(-0.5, 0.5, (n, 2))
    follow = np.repeat(vel[None], n, axis=0)  # every robot's plan: the team's true velocities
    out = inside = 0
    for b, j, a, seen, path in _pairs_seen(per, team, vel * 0.1, 30, follow):
        ref = seen.guard_ref[b, j]
        assert seen.now is not None
        if a > late:  # out of view: where the plan carried it, from here and now
            out += 1
            np.testing.assert_allclose(ref[0:2], seen.now[b, j], atol=1e-12)
            np.testing.assert_allclose(ref[2:4], path[0][b], atol=1e-12)
            if late == 0:  # every robot followed the plan: it is where it was carried
                np.testing.assert_allclose(ref[0:2], path[0][j], atol=1e-9)
            assert ref[4] == 0.0
        else:
            inside += 1
            np.testing.assert_allclose(ref[2:4], path[a][b], atol=1e-12)
    assert out > 20 and inside > 20


def test_the_damped_landing_cuts_short_steps_only_and_only_under_noise() -> None:
    from runtime.decision.settle import Lander, settle_for

    assert settle_for(PRESETS["perfect"]) is None
    assert settle_for(Conditions(loss=0.3)) is None
    assert settle_for(Conditions(latency_steps=1, loss=0.1)) is None  # lands as planned
    late = settle_for(Conditions(latency_steps=2, loss=0.3))  # lands in the centroid frame,
    assert late is not None and late.radius_m == 0.0 and late.sigma_m == 0.0  # undamped
    assert late.plan_frame_steps == 5  # after the plan's frame: 2 steps to land, 2 to see it
    assert settle_for(Conditions(latency_steps=3)).plan_frame_steps == 6  # type: ignore[union-attr]
    assert late.landed_m == math.inf  # every robot in the landing keeps the landed guard
    assert Lander(late, 0.1).apply(0.2, 0.1, to_slot_m=0.001) == (0.2, 0.1)
    s = settle_for(Conditions(noise_m=0.05), estimator=True)
    assert s is not None and s.landed_m == math.inf  # under noise too
    assert s.plan_frame_steps == 0  # the plan's frame of a noisy view carries its noise
    assert s is not None and 0 < s.radius_m <= 0.05
    lander = Lander(s, 0.1)
    assert lander.apply(1.0, 0.0) == (1.0, 0.0)  # a full step passes
    vx, vy = lander.apply(0.2, 0.1)  # a 2.2 cm step is damped
    assert (vx, vy) == pytest.approx((0.2 * s.gain, 0.1 * s.gain))
    # under a plan it is the way left that counts: a slow robot far from its slot is not
    # held back, one next to it is
    assert lander.apply(0.2, 0.1, to_slot_m=1.0) == (0.2, 0.1)
    assert lander.apply(0.2, 0.1, to_slot_m=0.01) == pytest.approx((0.2 * s.gain,
                                                                     0.1 * s.gain))


def test_a_differential_drive_on_noisy_wheels_parks_inside_the_tolerance(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``harsh`` (a differential drive, wheels that add noise as they move): a robot whose way
    to its slot in the landing is under 1.5 cm stays exactly still until it grows past
    2.0 cm; without a plan (no way left) and on holonomic or noiseless wheels it never
    parks. On a circle of 8 spaced 0.6 m, 12 episodes, parked robots hold the formation
    more often than the same robots correcting every millimetre, each in its own centroid
    frame (``--agree off``; in the leader's frame, the default, both held 95 %)."""
    import dataclasses

    from runtime.decision.settle import Lander, settle_for
    from runtime.world_config import DEFAULT_WORLD

    s = settle_for(PRESETS["harsh"], estimator=True)
    assert s is not None and (s.park_m, s.unpark_m) == pytest.approx(
        (0.6 * DEFAULT_WORLD.formed_tol_m, 0.8 * DEFAULT_WORLD.formed_tol_m))
    for other in ("realistic", "noise_m=0.1,kinematics=diff", "realistic,act_noise_mps=0.05"):
        o = settle_for(parse_conditions(other), estimator=True)
        assert o is not None and o.park_m == 0.0
    lander = Lander(s, 0.1)
    assert lander.apply(0.2, 0.1, to_slot_m=0.01) == (0.0, 0.0)  # parks
    assert lander.apply(0.2, 0.1, to_slot_m=0.019) == (0.0, 0.0)  # stays parked
    assert lander.apply(0.2, 0.1, to_slot_m=0.021) != (0.0, 0.0)  # moves again
    assert lander.apply(0.2, 0.1, to_slot_m=0.019) != (0.0, 0.0)  # not parked: not yet
    assert lander.apply(0.01, 0.0) != (0.0, 0.0)  # no plan, no parking
    lander.apply(0.2, 0.1, to_slot_m=0.01)
    lander.reset()  # a new landing starts unparked
    assert lander.apply(0.2, 0.1, to_slot_m=0.019) != (0.0, 0.0)

    import runtime.decision.local as local
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    wide = dataclasses.replace(DEFAULT_WORLD, pattern_spacing_m=0.6)
    held = {}
    orig = local.settle_for
    for parks in (True, False):
        monkeypatch.setattr(local, "settle_for", orig if parks else (
            lambda c, e=False, world=DEFAULT_WORLD: dataclasses.replace(
                orig(c, e, world), park_m=0.0, unpark_m=0.0)))
        r = evaluate_brain(load_brain("rule:frame-balanced"), "heart", 8, 40, seed=5,
                           conditions=PRESETS["harsh"], estimator=True, hold_steps=20,
                           progress=False, world=wide, agree="off")
        assert r.formed_rate == 1.0 and r.collisions == 0
        held[parks] = r.held_rate
    assert held[True] > held[False]


def test_the_landing_averages_the_teams_centroid_over_its_steps() -> None:
    """A landing's centroid is the running mean of the centroids seen on consecutive steps
    (each new one weighing at least ``centroid_gain``); the same step again (realtime) redoes
    its own average, a gap or a reset starts from the view, and a centroid seen far beyond its
    noise moves the average at once."""
    import dataclasses

    from runtime.decision.landing_frame import centroid_targets
    from runtime.decision.settle import Lander, settle_for

    s = settle_for(Conditions(noise_m=0.1), estimator=True)
    assert s is not None and s.centroid_gain == pytest.approx(0.03)
    assert s.centroid_gate(10) == pytest.approx(10 * 0.1 / math.sqrt(10))  # the raw noise
    assert s.centroid_weight(1) == pytest.approx(0.25)  # the start counts as 3 raw views
    assert s.centroid_weight(1000) == pytest.approx(0.03)
    lander = Lander(dataclasses.replace(s, gate_sigmas=math.inf, centroid_prior=1.0), 0.1)
    # a landing starts from the tracker's centroid (start), then the running mean of the raw
    assert np.allclose(lander.centroid(np.array([9.0, 9.0]), 5, 10, start=np.array([1.0, 0.0])),
                       [1.0, 0.0])
    assert np.allclose(lander.centroid(np.array([2.0, 0.0]), 6, 10), [1.5, 0.0])
    assert np.allclose(lander.centroid(np.array([3.0, 0.0]), 6, 10), [2.0, 0.0])  # redone
    assert np.allclose(lander.centroid(np.array([3.0, 1.0]), 7, 10), [7 / 3, 1 / 3])
    assert np.allclose(lander.centroid(np.array([0.0, 0.0]), 9, 10), [0.0, 0.0])  # a gap
    lander.reset()
    assert np.allclose(lander.centroid(np.array([4.0, 4.0]), 10, 10), [4.0, 4.0])
    rng = np.random.default_rng(2)  # noise on the centroid seen: the average keeps less
    gated = Lander(s, 0.1)
    sigma_c = 0.1 / math.sqrt(10)
    seen = rng.normal(0.0, sigma_c, (200, 2))
    avg = np.array([gated.centroid(z, 11 + t, 10) for t, z in enumerate(seen)])[50:]
    assert avg.std() < 0.5 * seen.std()
    m = gated.centroid(np.array([1.0, 0.0]), 211, 10)  # the team has moved: followed at once
    assert np.allclose(m, [1.0, 0.0])
    # the landing plan: the pattern centred on the centroid, K steps at full speed
    pos = np.array([[0.0, 0.0], [0.5, 0.0]])
    target, k = centroid_targets(pos, np.array([[10.0, 0.0], [10.4, 0.0]]),
                                 np.array([0.25, 0.05]))
    assert np.allclose(target, [[0.05, 0.05], [0.45, 0.05]]) and float(k) == 1.0
    target, k = centroid_targets(pos, np.array([[0.0, 0.0], [0.0, 0.4]]), np.array([0.25, 0.0]))
    assert float(k) == 4.0  # the way of the farthest, 0.36 m, at 0.1 m a step


def test_a_late_landing_keeps_the_plans_frame_then_the_frame_of_the_teams_core() -> None:
    """Exact views 3 steps late: the landing's first step asks the plan for its frame once and
    keeps it for ``plan_frame_steps`` steps, whatever the team seen does; then the frame of the
    team's core, which a robot held off its slot does not move (the centroid frame moves by its
    share of the way it is off) and which is the centroid frame where every robot is in it, at
    the slots the team of one moment gives every robot alike; the same step again redoes it, a
    gap starts a new landing, which asks again. Under noise: the centroid frame from the start,
    at the robot's own slots."""
    from runtime.decision.landing_frame import CORE_M, core_frame, shared_slots
    from runtime.decision.settle import Lander, settle_for

    s = settle_for(Conditions(latency_steps=3))
    assert s is not None
    points = np.array([[-0.4, 0.0], [0.0, 0.0], [0.4, 0.0], [0.0, 0.4]])
    asked: list[np.ndarray] = []

    def planned(team: np.ndarray) -> np.ndarray:
        asked.append(team.copy())
        return np.array([7.0, 7.0])

    def shared(team: np.ndarray) -> np.ndarray:
        return points[shared_slots(team, points - points.mean(axis=0))]

    held = points - points.mean(axis=0) + [2.0, 1.0]  # formed around (2, 1) but one robot
    held[3] += [0.0, 0.3]  # held 0.3 m off its slot
    lander = Lander(s, 0.1)
    frames = [lander.frame(held + np.array([0.0, 0.01 * t]), points, t, np.zeros(2), planned)[0]
              for t in range(s.plan_frame_steps + 2)]
    assert len(asked) == 1 and np.allclose(asked[0], held)
    assert all(np.allclose(f, [7.0, 7.0]) for f in frames[:s.plan_frame_steps])
    t = s.plan_frame_steps
    assert np.allclose(frames[t], [2.0, 1.0 + 0.01 * t])  # the core's frame, robot 3 left out
    assert np.allclose(held.mean(axis=0), [2.0, 1.075])  # where the centroid frame would walk
    assert np.allclose(core_frame(held, points + 5.0, CORE_M), [2.0, 1.0])  # any translation
    settling = points - points.mean(axis=0) + [2.0, 1.0]
    settling[:2] += [[0.05, 0.0], [0.03, 0.01]]  # every robot in the core: the centroid frame
    assert np.allclose(core_frame(settling, points, CORE_M), settling.mean(axis=0))
    split = points - points.mean(axis=0) + [2.0, 1.0]
    split[:2] += [1.0, 0.0]  # half the team 1 m off one way, half on its slots: no core
    assert np.allclose(core_frame(split, points, CORE_M), [2.5, 1.0])  # the median's, not 0
    assert np.allclose(core_frame(np.stack([held, split]), points, CORE_M), [[2, 1], [2.5, 1]])
    t += 1
    # robots 0 and 1 held to each other's slots (one robot's hysteresis): one moment's
    # assignment gives them back their own
    swapped = points[[1, 0, 2, 3]]
    frame, pts = lander.frame(held, swapped, t, np.zeros(2), planned, shared)
    assert np.allclose(pts, points) and np.allclose(frame, [2.0, 1.0])
    assert np.allclose(lander.frame(held, points, t + 5, np.zeros(2), planned)[0], [7, 7])
    assert len(asked) == 2  # a new landing
    noisy = settle_for(Conditions(noise_m=0.05), estimator=True)
    assert noisy is not None  # under noise the centroid frame from the start, never the plan
    start = np.full(2, 3.0)
    frame, pts = Lander(noisy, 0.1).frame(held, swapped, 0, start, planned, shared)
    assert np.allclose(frame, start) and pts is swapped
    assert len(asked) == 2
    batch = shared_slots(np.stack([held, held[[1, 0, 2, 3]]]), points - points.mean(axis=0))
    assert batch.tolist() == [[0, 1, 2, 3], [1, 0, 2, 3]]


def test_the_landing_sees_the_centroid_in_the_raw_views() -> None:
    """Each peer where it was last sensed (the raw view, which the tracker's smoothing does not
    lag), the robot itself where it is, the estimate where a view is missing; a batch of
    robots alike."""
    from runtime.decision.landing_frame import seen_centroid

    pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # the tracker's estimates
    ref = np.full((3, 5), np.nan)
    ref[0, 0:2] = [5.0, 5.0]  # robot 0's own row: its own position counts
    ref[1, 0:2] = [1.3, 0.0]
    assert np.allclose(seen_centroid(pos, 0, ref), [(0 + 1.3 + 0) / 3, 1 / 3])
    assert np.allclose(seen_centroid(pos, 0, None), pos.mean(axis=0))
    batch = seen_centroid(np.stack([pos, pos]), np.array([0, 1]), np.stack([ref, ref]))
    assert np.allclose(batch, [[1.3 / 3, 1 / 3], [(5 + 1 + 0) / 3, (5 + 0 + 1) / 3]])


def test_the_averaged_landing_centroid_holds_a_team_at_10_cm_of_noise(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """10 cm noise, n = 10, circle and heart, 10 episodes each (ground truth): the landing's
    averaged centroid forms and holds more episodes than this step's centroid alone
    (gain 1: 14 of 20 held, as the robots did before), where each robot lands in its own
    centroid frame (``--agree off``; in the leader's frame, the default, both held 20)."""
    import dataclasses

    import runtime.decision.local as local
    from runtime.brain.brain import load_brain
    from runtime.decision.settle import settle_for
    from trainer.evaluate import evaluate_brain

    def held(gain: float | None) -> float:
        if gain is not None:
            monkeypatch.setattr(local, "settle_for", lambda *a, **k: dataclasses.replace(
                settle_for(*a, **k), centroid_gain=gain))
        ok = 0.0
        for shape in ("circle", "heart"):
            r = evaluate_brain(load_brain("rule:frame-balanced"), shape, 10, 10, seed=5,
                               conditions=parse_conditions("noise_m=0.1"), estimator=True,
                               hold_steps=20, progress=False, agree="off")
            assert r.collisions == 0
            ok += r.success_rate * 10
        return ok

    averaged = held(None)
    assert averaged >= 17 and averaged > held(1.0)


def _heart_landing(monkeypatch: pytest.MonkeyPatch, n: int, cond: Conditions,
                   **landing: object) -> tuple[float, float]:
    """`rule:frame-balanced` + the tracker on the heart (n robots, 8 episodes, seed 5, 20-step
    hold) under ``cond``, every robot's landing with ``landing`` changed (none: as
    :func:`settle_for` sizes it): success and steps over the lower bound, 0 collisions."""
    import dataclasses

    import runtime.decision.local as local
    from runtime.brain.brain import load_brain
    from runtime.decision.settle import settle_for
    from trainer.evaluate import evaluate_brain

    if landing:
        monkeypatch.setattr(local, "settle_for", lambda *a, **k: dataclasses.replace(
            settle_for(*a, **k), **landing))
    r = evaluate_brain(load_brain("rule:frame-balanced"), "heart", n, 8, seed=5,
                       conditions=cond, estimator=True, hold_steps=20, progress=False)
    assert r.collisions == 0
    return r.success_rate, r.steps_ratio


def test_under_noise_the_landing_lasts_six_steps_and_lands_the_team_sooner(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Under noise a plan's last six steps are its landing, every robot landed, the filter on
    the team's plan: at 10 cm of noise (n = 10, heart, 8 episodes, ground truth) the team
    forms and holds every episode in fewer steps than with the two steps of before, 0
    collisions (both in the centroid frame for those steps)."""

    from runtime.decision.settle import NOISY_LANDING_STEPS, settle_for

    cond = parse_conditions("noise_m=0.1")
    landing = settle_for(cond, estimator=True)
    assert landing is not None and landing.filter_steps == NOISY_LANDING_STEPS == 6.0
    assert landing.filters_on_plan(6.0) and not landing.filters_on_plan(6.5)
    late = settle_for(parse_conditions("latency_steps=3"), estimator=True)
    assert late is not None and late.centroid_steps == late.filter_steps == 2.0  # as before
    assert late.filters_on_plan(2.0) and not late.filters_on_plan(2.5)

    six = _heart_landing(monkeypatch, 10, cond, centroid_steps=6.0)
    two = _heart_landing(monkeypatch, 10, cond, centroid_steps=2.0, filter_steps=2.0)
    assert six[0] == 1.0 and six[1] < two[1]


def test_under_noise_a_plan_goes_in_the_centroid_frame_from_the_start(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Under noise a synchronised plan takes the team's centroid frame, averaged, from its
    first step, not for its last six: the frame of the enclosing circle rests on two or three
    robots' noisy views, so the robots' frames disagree, where the centroid of the team's
    still centre is averaged over the whole run. At 10 cm of noise (n = 10, heart, 8 episodes,
    ground truth) the team forms and holds every episode in fewer steps, 0 collisions."""

    from runtime.decision.settle import settle_for

    landing = settle_for(parse_conditions("noise_m=0.1"), estimator=True)
    assert landing is not None and landing.centroid_steps == math.inf
    assert bool(landing.lands_in_centroid(1e9))

    cond = parse_conditions("noise_m=0.1")
    start = _heart_landing(monkeypatch, 10, cond)
    six = _heart_landing(monkeypatch, 10, cond, centroid_steps=6.0)
    assert start[0] == 1.0 and start[1] < six[1], (start, six)


def test_under_noise_each_robot_of_a_landing_goes_at_its_own_pace(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Under noise a landing robot takes its own steps left, those of its own way at v_max,
    not the team's (the farthest robot's, which noisy views overstate); every robot works out
    each peer's velocity by the same rule. On exact late views the team keeps one pace. A team
    of 12 at 5 cm of noise (heart, 8 episodes, ground truth) holds every episode in fewer
    steps than at the team's pace, 0 collisions."""

    from runtime.decision.rules import pace_velocity, plan_velocity
    from runtime.decision.settle import landing_steps, settle_for

    cond = parse_conditions("noise_m=0.05")
    noisy = settle_for(cond, estimator=True)
    late = settle_for(parse_conditions("latency_steps=3"), estimator=True)
    assert noisy is not None and noisy.own_pace and late is not None and not late.own_pace
    pos = np.zeros((3, 2))
    target = np.array([[0.05, 0.0], [0.0, 0.25], [-0.31, 0.0]])
    np.testing.assert_array_equal(landing_steps(target, pos, 4.0, noisy), [1.0, 3.0, 4.0])
    np.testing.assert_array_equal(landing_steps(target, pos, 4.0, late), [4.0, 4.0, 4.0])
    np.testing.assert_allclose(pace_velocity(target, pos, np.array([1.0, 3.0, 4.0])),
                               [[0.5, 0.0], [0.0, 0.25 / 0.3], [-0.31 / 0.4, 0.0]])
    np.testing.assert_allclose(pace_velocity(target, pos, np.full(3, 4.0)),
                               plan_velocity(target, pos, 4.0))

    own = _heart_landing(monkeypatch, 12, cond, own_pace=True)
    team = _heart_landing(monkeypatch, 12, cond, own_pace=False)
    assert own[0] == 1.0 and own[1] < team[1]


@pytest.mark.parametrize("spec", ["noise_m=0.1", "realistic"])
def test_a_team_holds_at_10_cm_of_noise_and_in_the_realistic_preset(spec: str) -> None:
    """Where the team's frame jittered by more than the tolerance (held 0 %): the still peers'
    longer average and the centroid landing frame make it hold (ground truth, no
    collision)."""
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    r = evaluate_brain(load_brain("rule:frame-balanced"), "circle", 7, 4, seed=78,
                       conditions=parse_conditions(spec), estimator=True, progress=False)
    assert r.collisions == 0 and r.formed_rate == 1.0 and r.held_rate >= 0.5


def test_a_team_on_noisy_views_holds_with_the_tracker_and_the_landing() -> None:
    """5 cm of noise: each robot on its own view, tracker on, forms and holds (ground truth)."""
    from runtime.brain.brain import load_brain
    from trainer.evaluate import evaluate_brain

    r = evaluate_brain(load_brain("rule:frame-balanced"), "circle", 7, 3, seed=78,
                       conditions=parse_conditions("noise_m=0.05"), estimator=True,
                       progress=False)
    assert r.collisions == 0 and r.formed_rate == 1.0 and r.held_rate >= 2 / 3


def test_a_landed_robot_may_close_in_on_its_slot_inside_the_full_guard() -> None:
    """Two robots at 10 cm of noise, 0.43 m apart on a pattern 0.40 m wide: each is 1.5 cm
    outside its slot, toward which the full guard (0.45 m between centres) forbids any
    approach. Landed (in the centroid frame, within ``landed_m``), a robot keeps half the
    guard's margin and closes in; the full guard alone would keep it where it is."""
    from runtime.brain.brain import load_brain
    from runtime.decision.controller import Controller
    from runtime.decision.safety import make_filter
    from runtime.decision.settle import settle_for
    from runtime.world_config import DEFAULT_WORLD

    cond = parse_conditions("noise_m=0.1")
    settle = settle_for(cond, estimator=True)
    assert settle is not None
    safety = uncertainty_params(OrcaParams(), cond)
    full = make_filter(safety)
    hard = 2 * (DEFAULT_WORLD.radius_m + safety.radius_margin_m)
    assert 0.43 < hard + 2 * safety.guard_margin_m < 0.46  # the guard's distance
    assert hard + 2 * settle.landed_safety(safety).guard_margin_m < 0.40
    pattern = np.array([[-0.2, 0.0], [0.2, 0.0]])
    pos = np.array([[-0.215, 0.0], [0.215, 0.0]])
    ctl = Controller(load_brain("rule:frame-balanced"), safety=safety, settle=settle)
    vx, vy = ctl.decide(0, pos, pattern, 0, np.zeros((2, 2))).velocity
    assert vx > 0.01 and abs(vy) < 1e-9  # toward its slot, half the way (the landing's damping)
    gx, _gy, _changed, _ = full.robot(0, 0, pos[None], np.zeros((1, 2, 2)), vx, vy, 0.1)
    assert gx < 1e-9  # the full guard: no approach at all


def test_a_landing_robot_takes_its_peers_velocities_from_the_plan() -> None:
    """A team landed on its slots, 0.30 m apart, under 5 cm of noise: the tracker still has the
    peer coming on at 1 m/s (its estimate lags a peer that stopped). In the landing the filter
    reads the team's plan (the peer stays), so the robot is not pushed off its slot; with the
    tracker's velocity it would dodge a peer that is not coming."""
    from runtime.brain.brain import load_brain
    from runtime.decision.controller import Controller
    from runtime.decision.safety import make_filter
    from runtime.decision.settle import settle_for

    cond = parse_conditions("noise_m=0.05")
    settle = settle_for(cond, estimator=True)
    safety = uncertainty_params(OrcaParams(), cond)
    pattern = np.array([[-0.15, 0.0], [0.15, 0.0]])
    pos = pattern.copy()
    stale = np.array([[0.0, 0.0], [-1.0, 0.0]])  # robot 1 seen coming at robot 0
    ctl = Controller(load_brain("rule:frame-balanced"), safety=safety, settle=settle)
    d = ctl.decide(0, pos, pattern, 0, stale)
    assert math.hypot(*d.velocity) < 1e-6 and not d.safety_changed  # stays on its slot
    dodge = make_filter(settle.landed_safety(safety)).robot(0, 0, pos[None], stale[None], 0.0,
                                                             0.0, 0.1)
    assert dodge[0] < -0.05  # the tracker's velocity alone: pushed off towards -x


def test_the_assignment_reads_the_team_of_one_moment_not_the_plans_carry() -> None:
    """One step late, a peer the plan moves at 1 m/s keeps still (the guard held it, say):
    the plan's view carries it a step along the plan, where it is not; the team of one
    moment has it as sensed and the robot where it stood then. The controller's assignment
    reads that moment: carried views made two robots keep slots that were no longer the
    best, and a line of 50 stalled on them."""
    from runtime.brain.brain import load_brain
    from runtime.decision.controller import Controller
    from runtime.decision.local import Perception

    per = Perception(Conditions(latency_steps=1), np.arange(2),
                     [np.random.SeedSequence((5, i)) for i in range(2)], estimator=True)
    me = [np.array([0.0, 0.0])]
    peer = np.array([1.0, 0.0])
    plan = np.array([[[np.nan, np.nan], [1.0, 0.0]]] * 2)  # each robot's plan for robot 1
    seen = per.perceive(np.array([[me[-1], peer]] * 2))
    for _ in range(5):
        me.append(me[-1] + [0.0, 0.05])
        seen = per.perceive(np.array([[me[-1], peer]] * 2), plan)
    assert seen.moment is not None
    np.testing.assert_allclose(seen.plan[0, 1], peer + np.array([0.1, 0.0]), atol=1e-9)  # carried
    np.testing.assert_allclose(seen.moment[0, 1], peer, atol=1e-9)  # as it is
    np.testing.assert_allclose(seen.moment[0, 0], me[-2], atol=1e-12)  # a step ago
    np.testing.assert_allclose(seen.plan[0, 0], me[-1], atol=1e-12)

    pattern = np.array([[-0.2, 0.0], [0.2, 0.0]])
    moment = np.array([[-1.0, 0.0], [1.0, 0.0]])  # robot 0 left of robot 1
    carried = np.array([[-1.0, 0.0], [-3.0, 0.0]])  # the plan's view: robot 1 far left
    brain = load_brain("rule:frame-balanced")
    assert Controller(brain).decide(0, carried, pattern).slot == 1
    assert Controller(brain).decide(0, carried, pattern, moment=moment).slot == 0
