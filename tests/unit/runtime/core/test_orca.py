"""The ORCA filter (runtime/core/orca.py) on hand-worked cases, its landing horizon and
its speed clamp (runtime/core/orca_lp.py); and its source run as Python against the
compiled module.

The half-planes here are computed in the test from the ORCA paper (van den Berg, Guy,
Lin and Manocha, "Reciprocal n-body collision avoidance", 2011, section 5.2): with p
the neighbour's position relative to the robot, v the robot's velocity relative to
the neighbour's, r the pair's combined radius and tau the horizon, the velocity
obstacle is the cone from the origin tangent to the disc D(p, r), cut off by the disc
D(p / tau, r / tau). u is the vector from v to the nearest point of the obstacle's
boundary, n the boundary's outward normal there, and the robot's half-plane is
ORCA = {v' : (v' - (v_A + u / 2)) . n >= 0}. The filter returns the velocity of ORCA
(within v_max) closest to the preferred one: here, the preference's projection on the
half-plane's boundary line when it violates it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from support.core_source import python_core

from runtime.core import orca as core_orca
from runtime.core.orca import MAX_NEIGHBOURS, OrcaFilter
from runtime.core.orca_lp import clamp_speed
from runtime.decision.pipeline import commands
from runtime.decision.safety import OrcaParams, landing, make_filter
from runtime.world_config import DEFAULT_WORLD, WorldConfig

W = DEFAULT_WORLD
R = 0.24  # the pair's combined radius of these cases (m)
DT = 0.1
V_MAX = 1.0


def solo(nb_pos: Any, own_vel: Any, nb_vel: Any, pref: Any, tau: float = 0.75,
         keep_right: float = 0.0, cap: int = 10, dist: float = 2.0
         ) -> tuple[float, float, bool, float]:
    """Robot 0 at the origin with neighbours at ``nb_pos``: robot 0's filtered velocity."""
    nb = np.asarray(nb_pos, dtype=np.float64).reshape(-1, 2)
    pos = np.zeros((1, len(nb) + 1, 2))
    pos[0, 1:] = nb
    vel = np.zeros_like(pos)
    vel[0, 0] = own_vel
    vel[0, 1:] = np.asarray(nb_vel, dtype=np.float64).reshape(-1, 2)
    f = OrcaFilter(cap, dist, R, DT, keep_right, V_MAX)
    out: tuple[float, float, bool, float] = f.robot(0, 0, pos, vel, float(pref[0]),
                                                    float(pref[1]), tau)
    return out


def in_velocity_obstacle(v: Any, p: Any, r: float, tau: float) -> float:
    """How deep v is in the velocity obstacle: r minus the closest approach to p of the
    straight path t v, 0 <= t <= tau (> 0 inside, 0 on the boundary)."""
    v, p = np.asarray(v, dtype=np.float64), np.asarray(p, dtype=np.float64)
    t = min(max(float(v @ p) / float(v @ v), 0.0), tau) if v @ v > 0 else 0.0
    return r - float(np.hypot(*(t * v - p)))


def projection(pref: Any, point: Any, normal: Any) -> Any:
    """The point of {v : (v - point) . normal >= 0} closest to pref."""
    pref = np.asarray(pref, dtype=np.float64)
    s = float((pref - point) @ normal)
    return pref - min(s, 0.0) * normal


def half_plane_cut_off(v_own: Any, v_rel: Any, p: Any, r: float, tau: float
                       ) -> tuple[Any, Any]:
    """(point, outward normal) of ORCA when the boundary point nearest v_rel lies on the
    cut-off disc D(p / tau, r / tau) (also the collision case, tau then the step)."""
    c = np.asarray(p, dtype=np.float64) / tau
    away = np.asarray(v_rel, dtype=np.float64) - c
    n = away / np.hypot(*away)
    u = c + (r / tau) * n - v_rel
    return np.asarray(v_own) + u / 2, n


def half_plane_leg(v_own: Any, v_rel: Any, p: Any, r: float, side: int) -> tuple[Any, Any]:
    """(point, outward normal) of ORCA when the nearest boundary point lies on the cone's
    left (side +1) or right (side -1) leg: the tangent from the origin to D(p, r)."""
    theta = math.atan2(p[1], p[0]) + side * math.asin(r / math.hypot(*p))
    d = np.array([math.cos(theta), math.sin(theta)])
    u = float(np.asarray(v_rel) @ d) * d - v_rel
    n = side * np.array([-d[1], d[0]])  # out of the cone, across the leg
    return np.asarray(v_own) + u / 2, n


def check_on_boundary(got: tuple[float, float, bool, float], pref: Any, point: Any,
                      normal: Any) -> None:
    """The filter's answer is the preference projected on the half-plane's boundary."""
    v = np.array(got[:2])
    assert float((v - point) @ normal) == pytest.approx(0.0, abs=1e-12)  # on the line
    assert float((np.asarray(pref) - point) @ normal) < -1e-3  # the preference broke it
    np.testing.assert_allclose(v, projection(pref, point, normal), rtol=0, atol=1e-12)
    assert got[2] and got[3] == pytest.approx(float(np.hypot(*(v - pref))), abs=1e-15)


# ----------------------------------------------------------------- hand-worked


def test_head_on_closing_slowly_meets_the_cut_off_disc() -> None:
    # a still neighbour 0.5 m ahead, closing at 0.5 m/s: v - p / tau = (-1/6, 0) points
    # back at the origin, so the nearest boundary point is on the cut-off disc:
    # u = (r / tau - 1/6) (-1, 0), ORCA: vx <= 0.5 - (0.32 - 1/6) / 2 = 0.42333...
    p, v_own, v_nb, pref = (0.5, 0.0), (0.5, 0.0), (0.0, 0.0), (0.5, 0.0)
    v_rel = np.subtract(v_own, v_nb)
    assert in_velocity_obstacle(v_rel, p, R, 0.75) > 0
    point, n = half_plane_cut_off(v_own, v_rel, p, R, 0.75)
    np.testing.assert_allclose(n, [-1.0, 0.0])
    assert point[0] == pytest.approx(0.5 - (0.32 - 1 / 6) / 2, abs=1e-15)
    assert in_velocity_obstacle(v_rel + 2 * (point - v_own), p, R, 0.75) == pytest.approx(
        0.0, abs=1e-12)  # v + u is on the obstacle's boundary
    got = solo([p], v_own, [v_nb], pref)
    check_on_boundary(got, pref, point, n)
    assert got[:2] == pytest.approx((0.5 - (0.32 - 1 / 6) / 2, 0.0), abs=1e-12)


@pytest.mark.parametrize("side", [1, -1], ids=["left-leg", "right-leg"])
def test_fast_closing_pair_meets_a_leg_of_the_cone(side: int) -> None:
    # a neighbour 1 m ahead coming at (-1, -0.1 side), the robot at (0.9, 0.1 side):
    # v - p / tau = (0.567, 0.2 side) points away from the origin, past the cut-off
    # disc: the nearest boundary point is on the leg on that side
    p, v_own, v_nb = (1.0, 0.0), (0.9, 0.1 * side), (-1.0, -0.1 * side)
    v_rel = np.subtract(v_own, v_nb)
    assert in_velocity_obstacle(v_rel, p, R, 0.75) > 0
    w = v_rel - np.divide(p, 0.75)
    assert w @ p > 0 and np.sign(p[0] * w[1] - p[1] * w[0]) == side
    point, n = half_plane_leg(v_own, v_rel, p, R, side)
    assert in_velocity_obstacle(v_rel + 2 * (point - v_own), p, R, 0.75) == pytest.approx(
        0.0, abs=1e-12)
    got = solo([p], v_own, [v_nb], v_own)
    check_on_boundary(got, v_own, point, n)
    assert np.sign(got[1] - v_own[1]) == side  # it turns away from the neighbour's side


def test_overlapping_pair_is_apart_again_after_one_step() -> None:
    # 0.2 m apart (< r = 0.24), both still: the obstacle is the disc D(p / dt, r / dt);
    # from v = 0 its nearest point is (-0.4, 0), u = (-0.4, 0), ORCA: vx <= -0.2
    p, pref = (0.2, 0.0), (0.5, 0.0)
    point, n = half_plane_cut_off((0.0, 0.0), (0.0, 0.0), p, R, DT)
    np.testing.assert_allclose([*point, *n], [-0.2, 0.0, -1.0, 0.0], atol=1e-15)
    a = solo([p], (0.0, 0.0), [(0.0, 0.0)], pref)
    check_on_boundary(a, pref, point, n)
    b = solo([(-0.2, 0.0)], (0.0, 0.0), [(0.0, 0.0)], (-0.5, 0.0))  # the other one
    assert b[:2] == pytest.approx((0.2, 0.0), abs=1e-12)
    gap = 0.2 + DT * (b[0] - a[0])  # each took half: together exactly r apart
    assert gap == pytest.approx(R, abs=1e-12)


def test_keep_right_turns_a_blocked_preference_clockwise_first() -> None:
    p, v_own = (0.5, 0.0), (0.5, 0.0)
    point, n = half_plane_cut_off(v_own, v_own, p, R, 0.75)
    a = 0.2
    turned = (0.5 * math.cos(a), -0.5 * math.sin(a))  # 0.2 rad clockwise
    got = solo([p], v_own, [(0.0, 0.0)], (0.5, 0.0), keep_right=a)
    np.testing.assert_allclose(got[:2], projection(turned, point, n), rtol=0, atol=1e-12)
    assert got[1] < -0.09  # to the right of the heading
    # a preference no half-plane forbids is not turned
    free = solo([(0.0, 0.6)], (0.8, 0.0), [(0.8, 0.0)], (0.8, 0.0), keep_right=a)
    assert free == (0.8, 0.0, False, 0.0)


def test_a_neighbour_out_of_range_is_ignored() -> None:
    # with a 3 s horizon a neighbour 2 m ahead closing at 2 m/s is in the obstacle ...
    assert in_velocity_obstacle((2.0, 0.0), (1.99, 0.0), R, 3.0) > 0
    near = solo([(1.99, 0.0)], (1.0, 0.0), [(-1.0, 0.0)], (1.0, 0.0), tau=3.0)
    assert near[2]
    # ... but at neighbour_dist_m (2 m) or farther it is not looked at
    for x in (2.0, 2.05):
        far = solo([(x, 0.0)], (1.0, 0.0), [(-1.0, 0.0)], (1.0, 0.0), tau=3.0)
        assert far == (1.0, 0.0, False, 0.0)


def test_only_the_nearest_max_neighbours_count() -> None:
    # two harmless neighbours beside the robot, moving with it, and a third in range on a
    # collision course, farther: beyond a cap of 2 it changes nothing
    nb = [(0.0, 0.5), (0.0, -0.5), (1.5, 0.0)]
    nb_vel = [(1.0, 0.0), (1.0, 0.0), (-1.0, 0.0)]
    assert in_velocity_obstacle((2.0, 0.0), nb[2], R, 0.75) > 0
    capped = solo(nb, (1.0, 0.0), nb_vel, (1.0, 0.0), cap=2)
    assert capped == (1.0, 0.0, False, 0.0)
    assert solo(nb[:2], (1.0, 0.0), nb_vel[:2], (1.0, 0.0)) == capped
    assert solo(nb, (1.0, 0.0), nb_vel, (1.0, 0.0), cap=3)[2]
    alone = solo(nb[2:], (1.0, 0.0), nb_vel[2:], (1.0, 0.0))
    assert alone[2] and solo(nb[2:], (1.0, 0.0), nb_vel[2:], (1.0, 0.0), cap=0) == capped


def test_a_non_finite_velocity_counts_as_still() -> None:
    rng = np.random.default_rng(2)
    nb = [(0.4, 0.1), (0.1, -0.5)]
    mattered = 0
    for bad in ((np.nan, 0.0), (0.0, np.inf), (-np.inf, np.nan)):
        for _ in range(5):
            own, other, pref = rng.normal(size=(3, 2)) * 0.6
            still = solo(nb, own, [(0.0, 0.0), other], pref)
            assert solo(nb, own, [bad, other], pref) == still  # a neighbour's
            assert solo(nb, bad, [other, other], pref) == solo(nb, (0.0, 0.0),
                                                               [other, other], pref)  # its own
            mattered += still[2]
    assert mattered >= 5  # the neighbours changed the velocity in many cases


def test_a_robot_holds_still_on_a_non_finite_preference_in_a_batch() -> None:
    pos = np.array([[[0.0, 0.0], [0.5, 0.0], [3.0, 3.0]]])
    vel = np.zeros_like(pos)
    pref = np.array([[[np.nan, 0.2], [0.3, np.inf], [0.3, 0.4]]])
    out, changed = np.full((1, 3, 2), 7.0), np.ones((1, 3), dtype=np.uint8)
    make_filter(OrcaParams(), W).teams(pos, vel, pref, np.array([0.75]), out, changed)
    assert out.tolist() == [[[0.0, 0.0], [0.0, 0.0], [0.3, 0.4]]]
    assert changed.tolist() == [[0, 0, 0]]


# ------------------------------------------------------------------- landing


@pytest.mark.parametrize("tau", [0.75, 0.3, 0.05])
def test_landing_shortens_the_horizon_to_the_plans_time_left(tau: float) -> None:
    p = OrcaParams(time_horizon_s=tau)
    assert landing(p, None, W) == tau  # no plan
    assert landing(OrcaParams(time_horizon_s=tau, landing=False), 2.0, W) == tau
    for k in (-3.0, 0.0, 0.5, 1.0, 2.0, 2.5, 4.0, 7.0, 7.5, 8.0, 20.0, 1e9):
        h = landing(p, k, W)
        assert h <= tau and h >= min(tau, W.dt_s)  # only shorter, never below dt
        want = min(tau, max(k, 1.0) * W.dt_s)
        assert h == pytest.approx(want, rel=1e-15)
    slow = WorldConfig(dt_s=0.2)
    assert landing(OrcaParams(), 2.0, slow) == pytest.approx(0.4)
    assert landing(OrcaParams(), 0.0, slow) == pytest.approx(0.2)


def test_the_landing_horizon_lets_a_robot_run_at_a_neighbour_it_will_not_reach() -> None:
    # robot 0 at 1 m/s, a still neighbour 0.5 m ahead: in K steps it travels 0.1 K m, so
    # it comes within r = 0.24 m of it only from K = 3 on (0.3 m: 0.2 m apart)
    pos = np.array([[[0.0, 0.0], [0.5, 0.0]]])
    prev = pos - [[[0.1, 0.0], [0.0, 0.0]]]
    act = np.array([[[1.0, 0.0], [0.0, 0.0]]])
    params = OrcaParams(radius_margin_m=0.02)  # r = 2 (R + margin) = 0.24 m
    seen = {}
    for k in (None, 1.0, 2.0, 3.0, 4.0, 7.0):
        vel, changed = commands(act, pos, prev, params, W,
                                None if k is None else np.array([k]))
        seen[k] = bool(changed[0, 0])
        if not changed[0, 0]:
            assert vel[0, 0].tolist() == [1.0, 0.0]
    assert seen == {None: True, 1.0: False, 2.0: False, 3.0: True, 4.0: True, 7.0: True}


# --------------------------------------------------------------- speed clamp


def norms_within(vx: float, vy: float, v_max: float, hypot: Any = np.hypot) -> bool:
    """Both norms within v_max: ``hypot`` (the C library's, as the compiled module takes
    it; Python's ``math.hypot`` for the source) and sqrt(x x + y y)."""
    return bool(hypot(vx, vy) <= v_max) and math.sqrt(vx * vx + vy * vy) <= v_max


@pytest.mark.parametrize("clamp", [clamp_speed, "source"], ids=["compiled", "source"])
def test_the_speed_clamp_is_exact_both_ways_of_taking_the_norm(clamp: Any) -> None:
    fn = python_core().orca_lp.clamp_speed if clamp == "source" else clamp
    hypot = math.hypot if clamp == "source" else np.hypot
    rng = np.random.default_rng(4)
    cases = 0
    for v_max in (1.0, 0.37, 2.5, 1e-3):
        for _ in range(3000):
            a = rng.uniform(0, 2 * math.pi)
            s = v_max * (10.0 ** rng.uniform(-3, 3) if rng.random() < 0.5
                         else 1.0 + rng.uniform(-1e-15, 1e-15) * rng.integers(0, 8))
            x, y = s * math.cos(a), s * math.sin(a)
            vx, vy = fn(x, y, v_max)
            assert norms_within(vx, vy, v_max, hypot), (x, y, v_max)
            if norms_within(x, y, v_max, hypot):
                assert (vx, vy) == (x, y)  # within the limit: untouched
            else:
                assert math.hypot(vx, vy) >= v_max * (1 - 1e-13)  # only just shortened
                assert abs(vx * y - vy * x) <= 1e-12 * v_max * math.hypot(x, y)  # same line
                assert vx * x + vy * y > 0.0  # same direction
                cases += 1
    assert cases > 5000
    assert fn(0.0, 0.0, 1.0) == (0.0, 0.0)
    assert fn(3.0, 4.0, 1.0) == pytest.approx((0.6, 0.8), abs=1e-15)


def test_every_filtered_velocity_is_within_v_max_both_ways() -> None:
    rng = np.random.default_rng(6)
    f = make_filter(OrcaParams(), W)
    for n in (2, 9, 30):
        pos = rng.uniform(0, 1.2, (3, n, 2))
        vel = rng.normal(size=(3, n, 2))
        pref = rng.normal(size=(3, n, 2)) * 3.0
        out, changed = np.empty((3, n, 2)), np.zeros((3, n), dtype=np.uint8)
        f.teams(pos, vel, pref, np.full(3, 0.75), out, changed)
        for vx, vy in out.reshape(-1, 2).tolist():
            assert norms_within(vx, vy, W.v_max_mps)


# ---------------------------------------------------------------- arguments


def test_the_filter_refuses_what_does_not_fit() -> None:
    for cap in (-1, MAX_NEIGHBOURS + 1, 100):
        with pytest.raises(ValueError):
            OrcaFilter(cap, 2.0, R, DT, 0.2, V_MAX)
    with pytest.raises(ValueError):
        make_filter(OrcaParams(max_neighbours=65), W)
    f = OrcaFilter(MAX_NEIGHBOURS, 50.0, R, DT, 0.2, V_MAX)  # 64 of 80: the cap is usable
    rng = np.random.default_rng(0)
    pos, vel = rng.uniform(0, 8, (1, 80, 2)), np.zeros((1, 80, 2))
    vx, vy, _, _ = f.robot(0, 5, pos, vel, 1.0, 0.0, 0.75)
    assert norms_within(vx, vy, V_MAX)
    for e, i, v in ((1, 0, vel), (0, 80, vel), (0, -1, vel), (0, 0, vel[:, :-1])):
        with pytest.raises(ValueError):
            f.robot(e, i, pos, v, 1.0, 0.0, 0.75)
    out, changed = np.empty((1, 80, 2)), np.zeros((1, 80), dtype=np.uint8)
    with pytest.raises(ValueError):
        f.teams(pos, vel, vel, np.zeros(2), out, changed)  # two horizons for one team
    with pytest.raises(ValueError):
        f.teams(pos, vel, vel[:, :-1], np.zeros(1), out, changed)
    if core_orca.__file__.endswith(".py"):
        return  # typed buffers are the compiled module's
    with pytest.raises((ValueError, TypeError)):
        f.robot(0, 0, pos.astype(np.float32), vel, 1.0, 0.0, 0.75)


# ------------------------------------------------------ the source run as Python


def crowds(rng: np.random.Generator) -> list[tuple[str, Any, Any, Any]]:
    """(name, positions, velocities, preferred velocities) of crowds meant to reach every
    branch: collisions, coincident robots, out of range, ties, NaN, infeasible LPs."""
    out = []
    n = 14
    pos: Any = rng.uniform(0.0, 3.0, (n, 2))
    out.append(("random", pos, rng.normal(size=(n, 2)) * 0.6, rng.normal(size=(n, 2))))
    pos = rng.uniform(0.0, 1.0, (n, 2))  # most pairs closer than 2R: the collision branch
    out.append(("overlap", pos, rng.normal(size=(n, 2)) * 0.6, rng.normal(size=(n, 2)) * 2))
    pos = rng.uniform(0.0, 1.5, (8, 2))
    pos[1] = pos[0]  # two coincident robots ...
    vel = rng.normal(size=(8, 2)) * 0.5
    vel[1] = vel[0]  # ... with the same velocity: w = 0, the arbitrary axis
    out.append(("coincident", pos, vel, rng.normal(size=(8, 2))))
    pos = rng.uniform(0.0, 9.0, (n, 2))  # most neighbours beyond 2 m ...
    pos[:3] = [[1.0, 1.0], [3.0, 1.0], [1.0, 3.0]]  # ... two at exactly 2 m: out of range
    out.append(("sparse", pos, rng.normal(size=(n, 2)), rng.normal(size=(n, 2))))
    pos = rng.integers(0, 4, (16, 2)) * 0.3  # a lattice: exact distance ties
    pos = pos[np.unique(pos, axis=0, return_index=True)[1]]
    m = len(pos)
    out.append(("lattice", pos, rng.normal(size=(m, 2)) * 0.5, rng.normal(size=(m, 2))))
    vel = rng.normal(size=(n, 2)) * 0.6
    vel[0] = np.nan  # a NaN own velocity (robot 0) and NaN / inf neighbour velocities
    vel[3, 1], vel[5, 0] = np.nan, np.inf
    out.append(("nan", rng.uniform(0.0, 1.5, (n, 2)), vel, rng.normal(size=(n, 2))))
    # dense rings all heading inward at v_max: infeasible LPs (lp3), the first one
    # overlapping (the collision branch), the second 2R apart (the cone's legs)
    for name, m, r in (("ring-overlap", 20, 0.45), ("ring", 16, 0.65)):
        a = np.arange(m) * (2 * np.pi / m)
        ring = np.stack([np.cos(a), np.sin(a)], axis=1) * r
        out.append((name, ring, -ring / r * W.v_max_mps, -ring / r * 1.3))
    return out


@pytest.mark.parametrize("tau", [0.75, 0.1])
@pytest.mark.parametrize("keep_right", [0.0, 0.2])
def test_the_source_run_as_python_filters_as_the_compiled_module(
    keep_right: float, tau: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same source in two execution modes: the same velocities (within the last bit
    of a libm hypot against Python's) and the same ``changed``, robot by robot and for a
    batch, over crowds that reach every branch (checked: the infeasible LP)."""
    py, py_lp = python_core().orca, python_core().orca_lp
    lp3_in: set[str] = set()
    real_lp3, crowd_name = py_lp._lp3, [""]

    def counting_lp3(*args: Any) -> None:
        lp3_in.add(crowd_name[0])
        real_lp3(*args)

    monkeypatch.setattr(py_lp, "_lp3", counting_lp3)
    rng = np.random.default_rng(int(tau * 100 + keep_right * 10))
    for cap in (1, 3, 10):
        args = (cap, 2.0, 2.0 * (W.radius_m + 0.02), W.dt_s, keep_right, W.v_max_mps)
        fast, slow = OrcaFilter(*args), py.OrcaFilter(*args)
        for crowd_name[0], pos, vel, pref in crowds(rng):
            P, V = np.ascontiguousarray(pos[None], dtype=np.float64), vel[None].copy()
            for i in range(len(pos)):
                got = fast.robot(0, i, P, V, *pref[i], tau)
                want = slow.robot(0, i, P, V, *pref[i], tau)
                assert got[2] == want[2], (crowd_name[0], i, got, want)
                np.testing.assert_allclose(got[:2] + got[3:], want[:2] + want[3:], rtol=0,
                                           atol=1e-12)
            Pr = np.ascontiguousarray(pref[None], dtype=np.float64)
            outs = [np.empty(P.shape), np.empty(P.shape)]
            chs = [np.zeros(P.shape[:2], dtype=np.uint8) for _ in range(2)]
            fast.teams(P, V, Pr, np.array([tau]), outs[0], chs[0])
            slow.teams(P, V, Pr, np.array([tau]), outs[1], chs[1])
            np.testing.assert_allclose(outs[0], outs[1], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(chs[0], chs[1])
    assert {"overlap", "ring-overlap"} <= lp3_in, lp3_in  # the infeasible LP ...
    assert tau < 0.5 or "ring" in lp3_in, lp3_in  # ... also without a collision


# ------------------------------------------------------------------ the guard

G = 0.3  # the guard's distance in these cases (m); the hard radius is R = 0.24


def guarded(nb: Any, nb_vel: Any, pref: Any, ref: Any = None) -> tuple[float, float]:
    """Robot 0 at the origin, one neighbour at ``nb``: its velocity behind ORCA and the guard."""
    f = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX, R, G)
    pos = np.array([[[0.0, 0.0], nb]])
    vel = np.array([[[0.0, 0.0], nb_vel]])
    r = None if ref is None else np.ascontiguousarray(ref, dtype=np.float64)[None]
    vx, vy, _, _ = f.robot(0, 0, pos, vel, *pref, 0.75, r)
    return vx, vy


def test_the_guard_caps_the_approach_to_half_the_room_whatever_the_neighbour_does() -> None:
    """A neighbour 0.4 m ahead, racing away at full speed: ORCA lets the robot follow faster
    than the guard, which allows half the room above G per step, (0.4 - G) / 2 / dt."""
    f = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX, R)  # no guard: ORCA alone
    vx, _, _, _ = f.robot(0, 0, np.array([[[0.0, 0.0], [0.4, 0.0]]]),
                          np.array([[[0.0, 0.0], [1.0, 0.0]]]), 1.0, 0.0, 0.75)
    assert vx > (0.4 - G) / 2 / DT + 0.05
    vx, vy = guarded([0.4, 0.0], [1.0, 0.0], (1.0, 0.0))
    assert vx == pytest.approx((0.4 - G) / 2 / DT) and vy == pytest.approx(0.0, abs=1e-12)
    vx, vy = guarded([0.4, 0.0], [1.0, 0.0], (-1.0, 0.0))  # away from it: untouched
    assert (vx, vy) == pytest.approx((-1.0, 0.0))


@pytest.mark.parametrize("pref", [(1.0, 0.0), (0.0, 1.0), (0.7, -0.7)])
def test_a_pair_inside_the_guard_keeps_its_distance(pref: tuple[float, float]) -> None:
    """0.28 m apart, inside G: no approach along the seen direction nor along either edge
    of the cone the neighbour may lie in (a noisy view's error)."""
    vx, vy = guarded([0.28, 0.0], [0.0, 0.0], pref)
    sn = (G - R) / 0.28
    cs = math.sqrt(1 - sn * sn)
    for wx, wy in ((1.0, 0.0), (cs, sn), (cs, -sn)):
        assert vx * wx + vy * wy <= 1e-12


def test_a_pair_inside_the_guard_gives_back_what_it_closed_while_its_view_was_late() -> None:
    """Seen 0.28 m away, inside G, when the robot stood 3 cm further back: it has closed 3 cm
    since, unseen by its peer, and steps back by them this step (the two robots then keep
    the distance they were seen at), even when its brain asks to go on or to stand still."""
    ref = [[0.0, 0.0, 0.0, 0.0, 0.0, 0.5], [0.25, 0.0, -0.03, 0.0, 0.0, 0.5]]
    sn = (G - R) / 0.28
    for pref in ((1.0, 0.0), (0.0, 0.0), (0.0, 0.5)):
        vx, vy = guarded([0.25, 0.0], [0.0, 0.0], pref, ref)
        for wx, wy in ((1.0, 0.0), (math.sqrt(1 - sn * sn), sn), (math.sqrt(1 - sn * sn), -sn)):
            assert vx * wx + vy * wy <= -0.03 / DT + 1e-9
    ref[1][2] = 0.0  # not closed since: it keeps its distance, no more
    vx, _ = guarded([0.28, 0.0], [0.0, 0.0], (0.0, 0.0), ref)
    assert vx == pytest.approx(0.0, abs=1e-12)


def test_the_guard_counts_the_room_from_the_pair_as_last_seen() -> None:
    """The neighbour was last seen 0.7 m away, when the robot stood 0.15 m further back: of
    half the room then, (0.7 - G) / 2 = 0.2 m, it has used 0.15, so 0.05 m are left this
    step, whatever the neighbour now seems to do."""
    ref = [[0.0, 0.0, 0.0, 0.0, 0.0, 0.5], [0.55, 0.0, -0.15, 0.0, 0.0, 0.5]]
    vx, _ = guarded([0.9, 0.0], [1.0, 0.0], (1.0, 0.0), ref)
    assert vx == pytest.approx(0.05 / DT)
    ref[1][4] = 0.05  # an update lost: the peer may have come 5 cm unseen since the view,
    vx, _ = guarded([0.9, 0.0], [1.0, 0.0], (1.0, 0.0), ref)  # (0.7 - 0.05 - G) / 2 - 0.15
    assert vx == pytest.approx(0.025 / DT)
    ref[1][4] = 0.2  # 20 cm: (0.7 - 0.2 - G) / 2 - 0.15 < 0: it gives 5 cm back, along the
    vx, vy = guarded([0.9, 0.0], [1.0, 0.0], (1.0, 0.0), ref)  # cone the 20 cm widen
    sn = (G - R + 0.2) / 0.7
    cs = math.sqrt(1 - sn * sn)
    for wx, wy in ((1.0, 0.0), (cs, sn), (cs, -sn)):
        assert vx * wx + vy * wy <= -0.05 / DT + 1e-9
    assert math.hypot(vx, vy) <= V_MAX


def test_the_guard_holds_a_peer_that_the_estimates_misplace() -> None:
    """The guard reads the views as sensed, not the estimates ORCA plans from: a peer seen
    0.4 m ahead that the estimates put 5 m away, behind ten nearer peers (out of ORCA's
    nearest ten and its 2 m), still caps the approach to half the room, (0.4 - G) / 2 per
    step. With the estimates right ORCA is stricter still. A peer seen far adds no bound."""
    n = 12
    f = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX, R, G)
    pos = np.zeros((1, n, 2))
    pos[0, 1] = [5.0, 0.0]  # robot 1 as estimated
    pos[0, 2:, 0] = -1.0  # ten peers 1 m behind, along a line
    pos[0, 2:, 1] = np.linspace(-1.5, 1.5, n - 2)
    vel = np.zeros((1, n, 2))
    ref = np.zeros((1, n, 6))
    ref[0, :, 0:2] = pos[0]
    ref[0, 1, 0:2] = [0.4, 0.0]  # robot 1 as last sensed
    ref[0, :, 5] = 0.5
    vx, vy, _, _ = f.robot(0, 0, pos, vel, 1.0, 0.0, 0.75, ref)
    assert vx == pytest.approx((0.4 - G) / 2 / DT) and vy == pytest.approx(0.0, abs=1e-9)
    assert f.guard_scale(0, 0, pos, 1.0, 0.0, False, ref) == pytest.approx((0.4 - G) / 2 / DT)
    ref[0, 1, 0:2] = [5.0, 0.0]  # seen far: nothing binds
    vx, vy, _, _ = f.robot(0, 0, pos, vel, 1.0, 0.0, 0.75, ref)
    assert (vx, vy) == pytest.approx((1.0, 0.0))
    pos[0, 1] = ref[0, 1, 0:2] = [0.4, 0.0]  # estimated and seen near: ORCA, stricter
    vx, _, _, _ = f.robot(0, 0, pos, vel, 1.0, 0.0, 0.75, ref)
    assert 0.0 <= vx <= (0.4 - G) / 2 / DT


@pytest.mark.parametrize(("share", "left_m"), [(0.6, 0.09), (0.3, -0.03), (0.5, 0.05),
                                               (np.nan, 0.05), (-2.0, -0.15), (0.45, 0.03)])
def test_the_guard_gives_the_robot_its_share_of_the_room(share: float, left_m: float) -> None:
    """Seen 0.7 m away with 0.15 m closed since: of ``share`` of the room then,
    ``share (0.7 - G)``, what is left this step (a share not finite is half, one below 0
    none); a lost update's way unseen shrinks the room it shares. Where the robot has
    closed more than its share, it gives the rest back, along the seen direction and both
    edges of the cone (so a little more along the direction), at most at full speed."""
    ref = [[0.0, 0.0, 0.0, 0.0, 0.0, 0.5], [0.55, 0.0, -0.15, 0.0, 0.0, share]]
    vx, vy = guarded([0.9, 0.0], [1.0, 0.0], (1.0, 0.0), ref)
    if left_m >= 0.0:
        assert vx == pytest.approx(left_m / DT, abs=1e-12)
    else:
        sn = (G - R) / 0.7
        assert vx == pytest.approx(max(left_m / DT / math.sqrt(1 - sn * sn), -V_MAX),
                                   rel=1e-4)
        assert abs(vy) < 1e-3 and math.hypot(vx, vy) <= V_MAX
    if share == 0.6:  # an update lost, 10 cm unseen: 0.6 (0.7 - 0.1 - G) - 0.15 = 0.03 m
        ref[1][4] = 0.1
        vx, _ = guarded([0.9, 0.0], [1.0, 0.0], (1.0, 0.0), ref)
        assert vx == pytest.approx(0.03 / DT)


@pytest.mark.parametrize("gain", [0.0, 0.1, 0.3])
def test_the_guard_leaves_room_for_wheels_that_drive_faster_than_asked(gain: float) -> None:
    """Wheels that may drive up to ``1 + gain`` of the command: the guard caps the command at
    its share of the room over ``1 + gain``, so the fastest wheels still keep to it; a pair
    near the guard's distance (two landing robots) may still close in by short steps, where
    a full step's gain error added to the guard's distance would stop them."""
    f = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX, R, G, gain)
    vel = np.array([[[0.0, 0.0], [1.0, 0.0]]])  # racing away: ORCA lets it follow
    for ahead in (0.4, 0.31):
        pos = np.array([[[0.0, 0.0], [ahead, 0.0]]])
        room = (ahead - G) / 2  # this robot's half, m
        vx, vy, _, _ = f.robot(0, 0, pos, vel, 1.0, 0.0, 0.75)
        assert vx == pytest.approx(room / DT / (1.0 + gain))
        assert vy == pytest.approx(0.0, abs=1e-12)
        assert vx * (1.0 + gain) * DT <= room + 1e-12  # driven at the highest gain
        assert f.guard_scale(0, 0, pos, 1.0, 0.0) == pytest.approx(room / DT / (1.0 + gain))
        short = 0.9 * room / DT / (1.0 + gain)
        vx, _, _, _ = f.robot(0, 0, pos, vel, short, 0.0, 0.75)
        assert vx == pytest.approx(short)
    wide = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX, R, G + 2 * gain * V_MAX * DT)
    vx, _, _, _ = wide.robot(0, 0, pos, vel, short, 0.0, 0.75)
    assert vx == pytest.approx(short) if gain == 0.0 else vx == 0.0


def test_the_guard_scale_bounds_what_the_wheels_will_drive() -> None:
    """A differential-drive base drives its command along its heading: the scale keeps the
    drive within the guard, and with the heading unknown, any drive the command allows."""
    f = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX, R, G)
    pos = np.array([[[0.0, 0.0], [0.35, 0.0]]])
    vel = np.zeros((1, 2, 2))
    vx, vy, _, _ = f.robot(0, 0, pos, vel, 0.0, 1.0, 0.75)  # sideways: allowed
    cap = (0.35 - G) / 2 / DT
    assert f.guard_scale(0, 0, pos, vx, vy) == 1.0
    assert f.guard_scale(0, 0, pos, 1.0, 0.0) == pytest.approx(cap)  # drives straight at it
    sn = (G - R) / 0.35
    want = cap / (0.5 * (math.hypot(vx, vy) + abs(vx) * math.sqrt(1 - sn * sn)
                         + abs(vy) * sn))
    assert f.guard_scale(0, 0, pos, vx, vy, True) == pytest.approx(min(1.0, want))
    orca_only = OrcaFilter(10, 2.0, R, DT, 0.0, V_MAX)
    assert orca_only.guard_scale(0, 0, pos, 1.0, 0.0) == 1.0
    with pytest.raises(ValueError):
        f.robot(0, 0, pos, vel, 1.0, 0.0, 0.75, np.zeros((1, 2, 4)))


def test_the_guard_in_the_source_run_as_python_is_the_compiled_module() -> None:
    py = python_core().orca
    rng = np.random.default_rng(17)
    for gain in (0.0, 0.15):
        args = (10, 2.0, R + 0.02, DT, 0.2, V_MAX, R, G, gain)
        _same_guard(OrcaFilter(*args), py.OrcaFilter(*args), rng)


def _same_guard(fast: Any, slow: Any, rng: np.random.Generator) -> None:
    """The two filters' guards agree on random crowds with random references."""
    for _, pos, vel, pref in crowds(rng):
        n = len(pos)
        P, V = np.ascontiguousarray(pos[None], dtype=np.float64), vel[None].copy()
        ref = np.zeros((1, n, 6))
        ref[0, :, 0:2] = pos + rng.normal(0.0, 0.05, (n, 2))
        ref[0, :, 2:4] = pos[rng.integers(0, n, n)]  # some other pose of "its own"
        ref[0, :, 4] = rng.integers(0, 2, n) * rng.uniform(0.0, 0.3, n)
        ref[0, :, 5] = rng.uniform(-0.1, 1.1, n)  # its share of the room, clipped to [0, 1]
        for r in (None, ref):
            for i in range(n):
                got = fast.robot(0, i, P, V, *pref[i], 0.75, r)
                want = slow.robot(0, i, P, V, *pref[i], 0.75, r)
                np.testing.assert_allclose(got[:2], want[:2], rtol=0, atol=1e-12)
                for heading_known in (True, False):
                    a = fast.guard_scale(0, i, P, *pref[i], not heading_known, r)
                    b = slow.guard_scale(0, i, P, *pref[i], not heading_known, r)
                    assert a == pytest.approx(b, abs=1e-12) and 0.0 <= a <= 1.0
