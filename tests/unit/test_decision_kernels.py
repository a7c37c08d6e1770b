"""The robot's faster decision kernels give the very numbers of the shared functions."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from runtime import controller
from runtime.assignment import certify_team
from runtime.brain import RuleBrain
from runtime.controller import Controller
from runtime.decision import _near_in_order, decide_batch, neighbour_rows
from runtime.formation import assign_centred, assign_slots, linear_sum_assignment
from runtime.observation import frame_velocities, general_row, neighbour_order
from runtime.patterns import make_pattern
from runtime.safety import OrcaParams, nearest_in_range


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("n", [2, 7, 40, 100])
def test_assignment_kernel_matches_assign_centred(n: int, compiled: bool) -> None:
    rng = np.random.default_rng(n)
    c = Controller(RuleBrain(), compiled=compiled)
    C = make_pattern("circle", n)
    c._set_pattern(C)
    prev = None
    for _ in range(30):
        P = rng.normal(size=(n, 2)) * 2.0
        if prev is not None and rng.random() < 0.5:  # near-ties: hysteresis decides
            P = C - C.mean(0) + rng.normal(size=(n, 2)) * 1e-3
        cen = np.add.reduce(P, 0) / n
        c._prev_slots = prev
        got, cx, cy = c._assign(P)
        assert [cx, cy] == cen.tolist()  # the centroid, bit for bit
        want = assign_centred(P - cen, c._cc, prev)
        assert got.tolist() == want.tolist()
        prev = got


@pytest.mark.parametrize("n", [1, 2, 12, 33, 100])
def test_general_row_same_numbers_for_any_team_size(n: int) -> None:
    rng = np.random.default_rng(n)
    P = rng.normal(size=(n, 2))
    P[-1] = P[0] + (P[1] - P[0]) if n > 2 else P[-1]  # a tie in distance
    L, Lp = P.tolist(), (P - 0.01).tolist()
    V = frame_velocities(L, Lp, 0.1)
    for i in range(n):
        slow = general_row(i, L, V, (0.5, -0.5), 6)
        fast = general_row(i, L, V, (0.5, -0.5), 6, P=P)
        assert fast == slow


@pytest.mark.parametrize("compiled", [False, True])
def test_proof_keeps_the_solvers_assignment_while_a_team_forms_and_holds(
    monkeypatch: pytest.MonkeyPatch, compiled: bool,
) -> None:
    """From PROOF_FROM robots the previous assignment is proven instead of solved (Python
    path) or the solver starts warm from it (compiled path), and every step's slots are
    still exactly scipy's with the hysteresis rule."""
    n = max(controller.PROOF_FROM, 30)
    proven: list[bool] = []

    def counting(*args: Any, **kwargs: Any) -> bool:
        ok = certify_team(*args, **kwargs)
        proven.append(ok)
        return ok

    monkeypatch.setattr(controller, "certify_team", counting)
    rng = np.random.default_rng(3)
    C = make_pattern("circle", n)
    pos = rng.uniform(0.0, 4.0, (n, 2))
    c = Controller(RuleBrain(), safety=None, compiled=compiled)
    ref = None
    for t in range(120):
        vel = np.array([c.decide(i, pos, C, t).velocity for i in range(n)])
        ref = assign_slots(pos, C, ref)
        assert c.previous_slots is not None
        assert c.previous_slots.tolist() == ref.tolist()
        pos = pos + 0.1 * vel + rng.normal(0.0, 1e-3, pos.shape)  # a little noise
    if compiled:
        assert not proven  # the warm start is the compiled path's proof
        return
    assert any(proven[-n:])  # formed: the proof holds ...
    assert not all(proven)  # ... and it was tried and failed while forming


@pytest.mark.parametrize("n", [3, 12, 40])
def test_team_proof_is_a_proof(n: int) -> None:
    """certify_team True: nothing beats the assignment by more than n * tol (scipy's
    optimum), whatever the potentials it started from."""
    rng = np.random.default_rng(n)
    proven = 0
    for trial in range(60):
        C = rng.normal(size=(n, 2))
        P = C[rng.permutation(n)] + rng.normal(size=(n, 2)) * (0.02 if trial % 2 else 0.5)
        cost = ((P[:, None, :] - C[None, :, :]) ** 2).sum(-1)
        slots = linear_sum_assignment(cost)[1] if trial % 3 else rng.permutation(n)
        duals = rng.normal(size=n) if trial % 5 == 0 else np.zeros(n)
        tol = 1e-6
        best = cost[np.arange(n), linear_sum_assignment(cost)[1]].sum()
        mine = cost[np.arange(n), slots].sum()
        if certify_team(cost, slots, tol, duals, max_rounds=n + 1):
            proven += 1
            assert best >= mine - n * tol - 1e-9
        else:
            assert mine > best  # within n + 1 rounds an optimal assignment is always proven
    assert proven > 0


@pytest.mark.parametrize("n", [2, 7, 30, 100])
def test_filter_neighbours_from_the_observation_order_are_the_filters_own(n: int) -> None:
    """The robot reads the safety filter's neighbours off the observation's order:
    the same tuples as nearest_in_range over every other robot, ties included."""
    rng = np.random.default_rng(n)
    for trial in range(20):
        if trial % 2:  # a lattice: many equal distances, ties broken by dx, dy, index
            P = rng.integers(0, 6, (n, 2)) * 0.3 + (rng.random((n, 2)) < 0.1) * 1e-9
        else:
            P = rng.normal(size=(n, 2)) * 1.5
        L = P.tolist()
        V = frame_velocities(L, (P - 0.01).tolist(), 0.1)
        params = OrcaParams(max_neighbours=int(rng.integers(1, 12)))
        for i in range(n):
            order, d2 = neighbour_order(i, L, P)
            got = _near_in_order(i, L, order, d2, params)
            _, rel, _ = neighbour_rows(i, L, V)
            want = nearest_in_range(rel, params)
            assert [(a, b, c) for a, b, c, _ in got] == [(a, b, c) for a, b, c, _ in want]
            others = [j for j in range(n) if j != i]
            assert [j for *_, j in got] == [others[k] for *_, k in want]


def test_controller_and_batch_agree_on_big_teams_with_the_filter() -> None:
    """Above the numpy neighbour threshold and the proof's team size: the robot's
    decisions are decide_batch's (rule brain, ORCA on)."""
    rng = np.random.default_rng(8)
    n = controller.PROOF_FROM + 6
    C = make_pattern("circle", n)
    pos = rng.uniform(0.0, 3.5, (n, 2))
    ctrls = [Controller(RuleBrain()) for _ in range(n)]
    prev_pos, prev_slots = pos, None
    changed = 0
    for t in range(12):
        frames = np.stack([pos, prev_pos, prev_pos])[None]
        vel, slots, ch = decide_batch(RuleBrain(), frames, C, prev_slots, OrcaParams())
        for i in range(n):
            d = ctrls[i].decide(i, pos, C, t)
            assert d.slot == slots[0, i]
            # the rule brain's one-row path takes math.hypot, its batch np.hypot:
            # they may round the last bit differently, nothing else may differ
            np.testing.assert_allclose(d.velocity, vel[0, i], rtol=1e-12, atol=1e-15)
            assert d.safety_changed == ch[0, i]
        changed += int(ch.sum())
        prev_pos, prev_slots = pos, slots
        pos = pos + 0.1 * vel[0]
    assert changed > 0  # the filter acted
