"""Tests of the ORCA safety filter (runtime/decision/safety.py).

The scenario tests simulate small worlds in which every robot runs the filter
each step on its own observation (neighbours' relative positions, velocities
estimated from the last two frames) and moves by ``p += dt * v``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.decision.formation import min_separation, min_swept_separation
from runtime.decision.pipeline import commands
from runtime.decision.safety import (
    FilterResult,
    OrcaParams,
    guard_shares,
    make_filter,
    orca_filter,
)
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD
TWO_R = W.min_separation_m
Arr = npt.NDArray[np.float64]


@dataclass
class Run:
    """Outcome of a simulated episode."""

    frames: Arr  # (T+1, n, 2) positions
    min_frame_dist: float  # closest approach at any frame
    min_path_dist: float  # closest approach along the straight moves between frames
    arrived_step: int | None  # first step at which every robot was within tol of its goal


def simulate(
    starts: npt.ArrayLike,
    goals: npt.ArrayLike,
    steps: int,
    *,
    params: OrcaParams | None = None,
    speeds: npt.ArrayLike | None = None,
    static: tuple[int, ...] = (),
) -> Run:
    """Every robot not in ``static`` heads for its goal through the filter.

    ``speeds`` caps each robot's preferred speed (default v_max). Static
    robots never move and do not run the filter.
    """
    prm = params if params is not None else OrcaParams()
    p = np.asarray(starts, dtype=np.float64).copy()
    g = np.asarray(goals, dtype=np.float64)
    n = p.shape[0]
    cap = np.full(n, W.v_max_mps) if speeds is None else np.asarray(speeds, dtype=np.float64)
    prev = p.copy()
    frames = [p.copy()]
    min_frame = float(min_separation(p))
    min_path = math.inf
    arrived: int | None = None
    for t in range(steps):
        d = g - p
        dist = np.linalg.norm(d, axis=1)
        speed = np.minimum(cap, dist / W.dt_s)
        pref = np.where(dist[:, None] > 1e-12, d / np.maximum(dist, 1e-12)[:, None], 0.0)
        pref = pref * speed[:, None]
        # every robot's own step: the others' velocities are what it sees, (p - prev) / dt
        v = commands(pref[None], p[None], prev[None], prm, W)[0][0]
        assert np.all(np.linalg.norm(v, axis=1) <= W.v_max_mps + 1e-12)
        if static:
            v[list(static)] = 0.0
        prev = p
        p = p + W.dt_s * v
        frames.append(p.copy())
        min_frame = min(min_frame, float(min_separation(p)))
        min_path = min(min_path, float(min_swept_separation(prev, p)))
        if arrived is None and np.all(np.linalg.norm(g - p, axis=1) <= W.formed_tol_m):
            arrived = t + 1
    return Run(np.array(frames), min_frame, min_path, arrived)


# --------------------------------------------------------------------------
# Scenarios
# --------------------------------------------------------------------------


def test_head_on_pair_passes_keeping_right() -> None:
    starts = [[-2.0, 0.0], [2.0, 0.0]]
    run = simulate(starts, [[2.0, 0.0], [-2.0, 0.0]], 80)
    assert run.arrived_step is not None and run.arrived_step <= 60
    assert run.min_frame_dist >= TWO_R
    assert run.min_path_dist >= TWO_R
    # Both swerve to their right: robot 0 (heading +x) to -y, robot 1 to +y.
    # (Exactly head-on, RVO2's tie rule already picks this side; keep-right
    # rotates the same way, so the pair passes right side to right side.)
    assert run.frames[:, 0, 1].min() < -0.02 and run.frames[:, 0, 1].max() < 1e-9
    assert run.frames[:, 1, 1].max() > 0.02 and run.frames[:, 1, 1].min() > -1e-9


def test_head_on_pair_slightly_offset_passes() -> None:
    run = simulate([[-2.0, 0.01], [2.0, -0.01]], [[2.0, 0.01], [-2.0, -0.01]], 80)
    assert run.arrived_step is not None
    assert run.min_path_dist >= TWO_R


def test_crossing_at_right_angles() -> None:
    run = simulate([[-2.0, 0.0], [0.0, -2.0]], [[2.0, 0.0], [0.0, 2.0]], 100)
    assert run.arrived_step is not None and run.arrived_step <= 60
    assert run.min_frame_dist >= TWO_R
    assert run.min_path_dist >= TWO_R
    # This mirror-symmetric encounter is settled by keep-right alone (see the
    # next test): robot 0 (heading +x) veers to -y, robot 1 (heading +y) to +x.
    y0, x1 = run.frames[:, 0, 1], run.frames[:, 1, 0]
    assert y0.max() <= 1e-9 and y0.min() < -0.05
    assert x1.min() >= -1e-9 and x1.max() > 0.05


def test_crossing_deadlocks_without_keep_right() -> None:
    # Why the keep-right rule exists: plain RVO2 (rotation 0) stalls this
    # mirror-symmetric crossing for good, both robots about 1.5 m from goal.
    run = simulate(
        [[-2.0, 0.0], [0.0, -2.0]],
        [[2.0, 0.0], [0.0, 2.0]],
        200,
        params=OrcaParams(keep_right_rad=0.0),
    )
    assert run.arrived_step is None
    assert run.min_frame_dist >= TWO_R


def test_overtaking_fast_behind_slow() -> None:
    # Robot 0 (1 m/s) starts 0.5 m behind robot 1 (0.3 m/s) on the same line.
    run = simulate(
        [[-2.0, 0.0], [-1.5, 0.0]],
        [[3.0, 0.0], [6.0, 0.0]],
        70,
        speeds=[1.0, 0.3],
    )
    xs = run.frames[:, :, 0]
    assert np.any(xs[:, 0] > xs[:, 1] + TWO_R), "the fast robot never got ahead"
    assert np.linalg.norm(run.frames[-1, 0] - [3.0, 0.0]) <= W.formed_tol_m
    assert run.min_frame_dist >= TWO_R
    assert run.min_path_dist >= TWO_R


def test_crowd_of_eight_swapping_antipodes() -> None:
    # Eight robots on a circle of radius 2 each head for the opposite point.
    # Observed (seeded, deterministic): with the defaults (tau = 0.75 s, margin
    # 0.02 m, keep-right 0.2 rad) the crowd forms a clockwise roundabout at the
    # centre and all arrive at step 71; closest approach 0.240 m = the inflated
    # 2(R + margin). Plain RVO2 (keep_right_rad=0) stalls for good in a ring
    # around the centre (no collision either); with keep-right 0.2 rad, tau =
    # 0.5 s with a 0.01 m margin stalls too. 12 robots arrive at step 88
    # (benchmarks/orca_sweep.py prints the grid).
    n = 8
    ang = np.arange(n) * 2.0 * np.pi / n
    starts = 2.0 * np.c_[np.cos(ang), np.sin(ang)]
    run = simulate(starts, -starts, 150)
    assert run.min_frame_dist >= TWO_R
    assert run.min_path_dist >= TWO_R
    assert run.arrived_step is not None and run.arrived_step <= 100


def test_crowd_of_eight_plain_orca_stalls_without_collision() -> None:
    n = 8
    ang = np.arange(n) * 2.0 * np.pi / n
    starts = 2.0 * np.c_[np.cos(ang), np.sin(ang)]
    run = simulate(starts, -starts, 150, params=OrcaParams(keep_right_rad=0.0))
    assert run.arrived_step is None  # deadlock: this is what keep-right is for
    assert run.min_frame_dist >= TWO_R


def test_stops_short_of_static_neighbour() -> None:
    # Robot 0 drives at full speed straight for a robot that never moves (and
    # never yields). Plain ORCA: it comes to rest just outside 2(R + margin).
    run = simulate(
        [[-1.5, 0.0], [0.0, 0.0]],
        [[0.0, 0.0], [0.0, 0.0]],
        150,
        params=OrcaParams(keep_right_rad=0.0),
        static=(1,),
    )
    assert run.min_frame_dist >= TWO_R
    assert run.min_path_dist >= TWO_R
    final_gap = float(np.linalg.norm(run.frames[-1, 0] - run.frames[-1, 1]))
    assert final_gap <= TWO_R + 0.05  # it did get close: it was stopped, not repelled
    last_speed = float(np.linalg.norm(run.frames[-1, 0] - run.frames[-2, 0])) / W.dt_s
    assert last_speed < 0.05


def test_static_neighbour_with_keep_right_never_touched() -> None:
    run = simulate([[-1.5, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]], 150, static=(1,))
    assert run.min_frame_dist >= TWO_R
    assert run.min_path_dist >= TWO_R


def test_parked_robot_yields_to_passer() -> None:
    # Robot 1 sits on its goal; robot 0's path goes straight through it.
    # Robot 0 goes round (keep right), the parked robot is barely disturbed
    # (observed: 1 mm) and ends back on its slot.
    run = simulate([[-2.0, 0.0], [0.0, 0.0]], [[2.0, 0.0], [0.0, 0.0]], 120)
    assert run.min_path_dist >= TWO_R
    assert np.linalg.norm(run.frames[-1, 0] - [2.0, 0.0]) <= W.formed_tol_m
    assert np.linalg.norm(run.frames[:, 1], axis=1).max() < 0.05
    assert np.linalg.norm(run.frames[-1, 1]) <= W.formed_tol_m


def test_parked_robot_steps_aside_from_pusher() -> None:
    # Without keep-right the passer comes straight on; the parked robot must
    # take its half of the avoidance and move, never being touched.
    run = simulate(
        [[-2.0, 0.0], [0.0, 0.0]],
        [[2.0, 0.0], [0.0, 0.0]],
        120,
        params=OrcaParams(keep_right_rad=0.0),
    )
    assert run.min_path_dist >= TWO_R
    assert np.linalg.norm(run.frames[:, 1], axis=1).max() > 0.01


# --------------------------------------------------------------------------
# Single calls
# --------------------------------------------------------------------------


def test_unchanged_when_nobody_near() -> None:
    pref = (0.6, -0.3)
    res = orca_filter(pref, (0.5, 0.0), np.array([[2.5, 0.0], [0.0, -3.0]]), np.zeros((2, 2)))
    assert isinstance(res, FilterResult)
    assert res.velocity == pref
    assert not res.changed and res.change_mps == 0.0


def test_unchanged_when_neighbour_near_but_harmless() -> None:
    # A neighbour 0.6 m to the left, both moving in parallel at the same speed.
    res = orca_filter((0.8, 0.0), (0.8, 0.0), np.array([[0.0, 0.6]]), np.array([[0.8, 0.0]]))
    assert not res.changed
    assert res.velocity == pytest.approx((0.8, 0.0), abs=1e-12)


def test_no_neighbours_at_all() -> None:
    res = orca_filter((0.1, 0.2), (0.0, 0.0), np.zeros((0, 2)), np.zeros((0, 2)))
    assert res.velocity == (0.1, 0.2) and not res.changed


def test_changed_when_heading_into_neighbour() -> None:
    res = orca_filter((1.0, 0.0), (1.0, 0.0), np.array([[0.5, 0.0]]), np.array([[-1.0, 0.0]]))
    assert res.changed
    assert res.change_mps == pytest.approx(
        math.hypot(res.velocity[0] - 1.0, res.velocity[1]), abs=1e-12
    )
    assert res.velocity[1] < -0.1  # it swerves to its right
    assert res.velocity[0] < 0.9  # and slows down


def test_too_fast_preference_is_clamped() -> None:
    res = orca_filter((3.0, 4.0), (0.0, 0.0), np.zeros((0, 2)), np.zeros((0, 2)))
    assert math.hypot(*res.velocity) == pytest.approx(W.v_max_mps)
    assert res.velocity[0] == pytest.approx(0.6) and res.changed


def test_far_and_excess_neighbours_ignored() -> None:
    # A neighbour just beyond neighbour_dist_m on a collision course is ignored...
    far = orca_filter((1.0, 0.0), (1.0, 0.0), np.array([[2.05, 0.0]]), np.array([[-1.0, 0.0]]))
    assert not far.changed
    # ...and so is one beyond the max_neighbours nearest.
    prm = OrcaParams(max_neighbours=1)
    rel = np.array([[0.0, 1.5], [0.5, 0.0]])  # the threatening one is nearer
    vel = np.array([[0.0, 0.0], [-1.0, 0.0]])
    one = orca_filter((1.0, 0.0), (1.0, 0.0), rel, vel, params=prm)
    assert one.changed  # the threatening one is the nearest, so it is kept
    rel2 = np.array([[0.0, 0.4], [1.2, 0.0]])  # now a harmless one is nearest
    vel2 = np.array([[1.0, 0.0], [-1.0, 0.0]])
    assert not orca_filter((1.0, 0.0), (1.0, 0.0), rel2, vel2, params=prm).changed
    assert orca_filter((1.0, 0.0), (1.0, 0.0), rel2, vel2).changed


def test_nan_preference_gives_zero_ish() -> None:
    nan = float("nan")
    alone = orca_filter((nan, 0.0), (0.0, 0.0), np.zeros((0, 2)), np.zeros((0, 2)))
    assert alone.velocity == (0.0, 0.0) and alone.changed
    inf = orca_filter((math.inf, -math.inf), (nan, nan), np.array([[3.0, 0.0]]), np.zeros((1, 2)))
    assert inf.velocity == (0.0, 0.0)
    # A still neighbour at 0.5 m, the robot still: stays (near) still, finite.
    near = orca_filter(np.array([nan, nan]), (0.0, 0.0), np.array([[0.5, 0.0]]), np.zeros((1, 2)))
    assert all(math.isfinite(c) for c in near.velocity)
    assert math.hypot(*near.velocity) < 1e-6


def test_non_finite_neighbour_rows_are_safe() -> None:
    rel = np.array([[math.nan, 0.0], [0.5, 0.0]])
    vel = np.array([[0.0, 0.0], [math.nan, math.inf]])
    res = orca_filter((1.0, 0.0), (1.0, 0.0), rel, vel)
    assert all(math.isfinite(c) for c in res.velocity)
    assert res.velocity[0] < 1.0  # the finite-position neighbour still counts


def test_overlapping_pair_separates_within_one_step() -> None:
    # Two robots already inside the inflated radius (0.21 apart), closing at
    # 1 m/s each: both running the filter, the next step does not bring them
    # closer than 2R, and in fact moves them apart.
    a, b = np.array([0.0, 0.0]), np.array([0.21, 0.0])
    va = orca_filter((1.0, 0.0), (1.0, 0.0), (b - a)[None], np.array([[-1.0, 0.0]])).velocity
    vb = orca_filter((-1.0, 0.0), (-1.0, 0.0), (a - b)[None], np.array([[1.0, 0.0]])).velocity
    a2, b2 = a + W.dt_s * np.array(va), b + W.dt_s * np.array(vb)
    assert np.linalg.norm(b2 - a2) >= 0.21 - 1e-12


def test_coincident_neighbour_gives_finite_output() -> None:
    res = orca_filter((0.5, 0.0), (0.0, 0.0), np.zeros((1, 2)), np.zeros((1, 2)))
    assert all(math.isfinite(c) for c in res.velocity)
    assert math.hypot(*res.velocity) <= W.v_max_mps


finite = st.floats(-5.0, 5.0, allow_nan=False)
anything = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None)
@given(
    pref=st.tuples(anything, anything),
    own=st.tuples(finite, finite),
    k=st.integers(0, 12),
    data=st.data(),
)
def test_output_norm_bounded_random(
    pref: tuple[float, float], own: tuple[float, float], k: int, data: st.DataObject
) -> None:
    rel = np.array(data.draw(st.lists(st.tuples(finite, finite), min_size=k, max_size=k)))
    vel = np.array(data.draw(st.lists(st.tuples(finite, finite), min_size=k, max_size=k)))
    res = orca_filter(pref, own, rel.reshape(k, 2), vel.reshape(k, 2))
    vx, vy = res.velocity
    assert math.isfinite(vx) and math.isfinite(vy)
    assert math.hypot(vx, vy) <= W.v_max_mps
    assert res.change_mps >= 0.0 and math.isfinite(res.change_mps)


def test_teams_are_filtered_apart_and_as_one_robot_each() -> None:
    """A batch of teams gives each robot what it gets in its team alone, robot by robot."""
    rng = np.random.default_rng(7)
    E, n = 4, 7
    pos = rng.uniform(0, 1.5, (E, n, 2))
    vel = rng.uniform(-1, 1, (E, n, 2))
    pref = rng.uniform(-1.5, 1.5, (E, n, 2))
    horizon = np.array([0.75, 0.3, 0.75, 0.1])
    out = np.empty((E, n, 2))
    changed = np.zeros((E, n), dtype=np.uint8)
    f = make_filter(OrcaParams(), W)
    f.teams(pos, vel, pref, horizon, out, changed)
    for e in range(E):
        for i in range(n):
            vx, vy, ch, _ = make_filter(OrcaParams(), W).robot(
                0, i, pos[e : e + 1].copy(), vel[e : e + 1].copy(), *pref[e, i], horizon[e])
            assert (vx, vy) == tuple(out[e, i]) and ch == bool(changed[e, i])
    # no filter: the speed clamp only, never "changed"
    make_filter(None, W).teams(pos, vel, pref, horizon, out, changed)
    assert not changed.any()
    assert np.all(np.hypot(out[..., 0], out[..., 1]) <= W.v_max_mps)
    assert np.allclose(out[np.hypot(pref[..., 0], pref[..., 1]) <= 1.0],
                       pref[np.hypot(pref[..., 0], pref[..., 1]) <= 1.0])


@given(st.lists(st.floats(-0.2, 0.2), min_size=6, max_size=6))
@settings(max_examples=200, deadline=None)
def test_guard_shares_of_a_pair_sum_to_one(xs: list[float]) -> None:
    """Both robots of a pair compute their shares from the same numbers, seen from either
    end: the two always sum to 1, each within [0, 1]."""
    own, peer = np.array(xs[0:2]), np.array(xs[2:4])
    toward = np.array(xs[4:6]) + np.array([0.3, 0.0])
    a = guard_shares(own, peer, toward)
    b = guard_shares(peer, own, -toward)
    assert 0.0 <= a <= 1.0 and a + b == pytest.approx(1.0, abs=1e-12)


def test_guard_shares_give_the_room_to_the_robot_that_comes() -> None:
    """A robot that was closing on a still peer at full speed takes nearly all the room; two
    still robots, or two that close alike, half each; one moving away while the peer comes
    leaves nearly all of it to the peer; a pair without a direction or with a number not
    finite, half."""
    toward = np.array([[0.5, 0.0]] * 4 + [[0.0, 0.0], [np.nan, 0.0]])
    own = np.array([[0.1, 0.0], [0.0, 0.0], [0.05, 0.0], [-0.1, 0.0], [0.1, 0.0], [0.1, 0.0]])
    peer = np.array([[0.0, 0.0], [0.0, 0.0], [-0.05, 0.0], [-0.05, 0.0], [0.0, 0.0],
                     [0.0, 0.0]])
    got = guard_shares(own, peer, toward)
    assert got[0] > 0.95 and got[3] < 0.05
    np.testing.assert_allclose(got[[1, 2, 4, 5]], 0.5)


def test_a_filter_without_its_guard_keeps_no_guard_under_any_condition() -> None:
    """``safety_params("orca-no-guard")``: the same filter, its guard off whatever the
    conditions; the robots' filter keeps one under every imperfect condition."""
    from runtime.conditions import parse_conditions
    from runtime.decision.safety import (
        SAFETY_MODES,
        guard_distance,
        safety_mode,
        safety_params,
        uncertainty_params,
    )

    assert safety_params("off") is None
    for mode in SAFETY_MODES:
        assert safety_mode(safety_params(mode)) == mode
    for spec in ("latency_steps=3", "noise_m=0.05", "realistic", "harsh"):
        c = parse_conditions(spec)
        with_guard = uncertainty_params(safety_params("orca"), c)
        without = uncertainty_params(safety_params("orca-no-guard"), c)
        assert guard_distance(with_guard) > 2 * DEFAULT_WORLD.radius_m
        assert guard_distance(without) == 0.0
        assert without.uncertainty_margin_m == with_guard.uncertainty_margin_m
    with pytest.raises(ValueError, match="safety mode"):
        safety_params("bogus")
