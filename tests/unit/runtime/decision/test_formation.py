from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from runtime.core.plan_frame import min_enclosing_circle
from runtime.decision.formation import (
    _weiszfeld,
    assign_centred,
    assign_slots,
    assign_slots_batch,
    collision_pairs,
    count_collisions,
    formation_error,
    formation_error_batch,
    formation_measure,
    is_formed,
    keeps_previous,
    lower_bound_distance,
    lower_bounds,
    min_separation,
    min_swept_separation,
    overlaps,
    slot_distances,
    slot_positions,
)
from runtime.decision.patterns import BUILTIN_PATTERNS, make_pattern

coords = st.floats(-20, 20, allow_nan=False, allow_infinity=False)


def brute_force(P: np.ndarray, C: np.ndarray) -> tuple[float, float, float]:
    """(formation error, min total travel, min bottleneck distance) over all permutations."""
    err = travel = bottleneck = math.inf
    Pc = P - P.mean(0)
    Cc = C - C.mean(0)
    for perm in itertools.permutations(range(len(P))):
        c = C[list(perm)]
        err = min(err, float(np.sqrt(((Pc - Cc[list(perm)]) ** 2).sum(1).mean())))
        d = P - c
        t = _weiszfeld(d, d.mean(0), iters=500)
        travel = min(travel, float(np.linalg.norm(d - t, axis=1).sum()))
        bottleneck = min(bottleneck, min_enclosing_circle(d)[2])
    return err, travel, bottleneck


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6, 7])
def test_error_and_bounds_match_brute_force(n: int) -> None:
    rng = np.random.default_rng(n)
    for trial in range(3 if n < 6 else 1):
        P = rng.uniform(0, 10, (n, 2))
        C = make_pattern(BUILTIN_PATTERNS[trial % len(BUILTIN_PATTERNS)], n)
        err, travel, bottleneck = brute_force(P, C)
        assert formation_error(P, C) == pytest.approx(err, rel=1e-9, abs=1e-12)
        lb_travel, lb_steps = lower_bounds(P, C)
        # Documented tolerances: travel within 1 %, bottleneck within 3 % of the optimum,
        # and never below it (both are attained by a real assignment and translation).
        assert err - 1e-9 <= formation_error(P, C)
        assert travel - 1e-6 <= lb_travel <= travel * 1.01 + 1e-9
        dist = lower_bound_distance(P, C)
        assert bottleneck - 1e-6 <= dist <= bottleneck * 1.03 + 1e-9
        assert lb_steps == math.ceil(dist / 0.1 - 1e-9)


@given(
    st.integers(2, 8).flatmap(
        lambda n: st.tuples(
            st.lists(st.tuples(coords, coords), min_size=n, max_size=n),
            st.tuples(coords, coords),
            st.permutations(list(range(n))),
        )
    )
)
def test_error_invariant_to_translation_and_relabelling(
    data: tuple[list[tuple[float, float]], tuple[float, float], list[int]],
) -> None:
    pts, shift, perm = data
    P = np.array(pts)
    C = make_pattern("circle", len(P))
    base = formation_error(P, C)
    assert formation_error(P + np.array(shift), C) == pytest.approx(base, rel=1e-7, abs=1e-7)
    assert formation_error(P[perm], C) == pytest.approx(base, rel=1e-7, abs=1e-7)
    assert formation_error(P, C[perm]) == pytest.approx(base, rel=1e-7, abs=1e-7)


def test_formed_pattern_has_zero_error_anywhere() -> None:
    C = make_pattern("heart", 10)
    P = C[::-1] + np.array([3.0, -7.0])
    assert formation_error(P, C) < 1e-12
    assert is_formed(P, C)
    P2 = P.copy()
    P2[0, 0] += 0.05  # 2 R tolerance is 0.025
    assert not is_formed(P2, C)
    travel, steps = lower_bounds(P, C)
    assert travel < 1e-6 and steps == 0


def test_batch_matches_single() -> None:
    rng = np.random.default_rng(3)
    P = rng.uniform(0, 10, (16, 9, 2))
    C = make_pattern("cross", 9)
    slots = assign_slots_batch(P, C)
    errs = formation_error_batch(P, C, slots)
    for e in range(len(P)):
        np.testing.assert_array_equal(slots[e], assign_slots(P[e], C))
        assert errs[e] == pytest.approx(formation_error(P[e], C), rel=1e-12)
    sp = slot_positions(P, C, slots)
    # slots sit on the pattern placed at the team's centroid
    np.testing.assert_allclose(sp.mean(1), P.mean(1), atol=1e-12)


def test_assignment_hysteresis_keeps_previous_on_near_ties() -> None:
    C = np.array([[0.0, 0.0], [1.0, 0.0]])
    # both robots exactly between the two slots: both assignments cost the same
    P = np.array([[0.5, 0.0], [0.5, 1e-9]])
    prev = np.array([1, 0])
    np.testing.assert_array_equal(assign_slots(P, C, previous=prev), prev)
    # a clearly better assignment replaces the previous one
    P = np.array([[0.0, 0.0], [1.0, 0.0]])
    np.testing.assert_array_equal(assign_slots(P, C, previous=prev), [0, 1])
    Pb = np.stack([P, P])
    np.testing.assert_array_equal(
        assign_slots_batch(Pb, C, previous=np.array([[1, 0], [0, 1]])), [[0, 1], [0, 1]]
    )


def test_collision_check_catches_pass_through() -> None:
    # two robots swap places head-on within one step: the end positions are far apart
    P0 = np.array([[0.0, 0.0], [0.3, 0.0]])
    P1 = np.array([[0.3, 0.0], [0.0, 0.0]])
    assert min_separation(P1) > 0.2
    assert collision_pairs(P0, P1) == [(0, 1)]
    assert count_collisions(P0[None], P1[None]).tolist() == [1]
    # parallel motion at a safe distance is not a collision
    Q0 = np.array([[0.0, 0.0], [0.0, 0.25]])
    assert collision_pairs(Q0, Q0 + 0.1) == []
    # grazing exactly at 2R is allowed
    R0 = np.array([[0.0, 0.0], [0.2, 0.0]])
    assert collision_pairs(R0, R0) == []


def test_min_separation_batch() -> None:
    P = np.array([[[0.0, 0.0], [3.0, 4.0], [0.0, 1.0]]])
    assert np.allclose(min_separation(P), [1.0])
    assert min_separation(P[0]) == pytest.approx(1.0)


def test_assign_centred_is_assign_slots_and_keeps_on_near_ties() -> None:
    rng = np.random.default_rng(5)
    C = make_pattern("heart", 7)
    for _ in range(20):
        P = rng.uniform(0, 5, (7, 2))
        Pc, Cc = P - P.mean(0), C - C.mean(0)
        np.testing.assert_array_equal(assign_centred(Pc, Cc), assign_slots(P, C))
    P = np.array([[0.5, 0.0], [0.5, 1e-9]])
    Cc = np.array([[-0.5, 0.0], [0.5, 0.0]])
    prev = np.array([1, 0])
    np.testing.assert_array_equal(assign_centred(P - P.mean(0), Cc, prev), prev)
    assert keeps_previous(1.0, 1.0) and not keeps_previous(0.5, 1.0)
    np.testing.assert_array_equal(keeps_previous(np.array([1.0, 0.5]), 1.0), [True, False])


def test_min_swept_separation_and_formation_measure() -> None:
    P0 = np.array([[0.0, 0.0], [0.3, 0.0], [5.0, 5.0]])
    P1 = np.array([[0.3, 0.0], [0.0, 0.0], [5.0, 5.0]])
    assert min_swept_separation(P0, P1) == pytest.approx(0.0)  # they pass through each other
    both = min_swept_separation(np.stack([P0, P0]), np.stack([P1, P0]))
    np.testing.assert_allclose(both, [0, 0.3], atol=1e-12)
    rng = np.random.default_rng(2)
    P = rng.uniform(0, 5, (4, 6, 2))
    C = make_pattern("circle", 6)
    err, far = formation_measure(P, C)
    slots = assign_slots_batch(P, C)
    np.testing.assert_allclose(err, formation_error_batch(P, C, slots), rtol=1e-12)
    np.testing.assert_allclose(far, slot_distances(P, C, slots).max(-1), rtol=1e-12)
    e1, f1 = formation_measure(P[0], C)
    assert e1.shape == () and float(e1) == pytest.approx(formation_error(P[0], C), rel=1e-12)
    assert float(f1) == pytest.approx(far[0])


def test_overlaps_marks_pairs_closer_than_the_limit() -> None:
    P = np.array([[[0.0, 0.0], [0.15, 0.0], [1.0, 0.0]]])  # (E=1, n=3, 2)
    X = P.transpose(2, 1, 0)
    diff, d2, over = overlaps(X, 0.2)
    assert over[:, :, 0].tolist() == [[False, True, False], [True, False, False], [False] * 3]
    np.testing.assert_allclose(diff[:, 0, 1, 0], [-0.15, 0.0])
    assert d2[0, 2, 0] == pytest.approx(1.0)
