"""The robot's faster decision kernels give the very numbers of the shared functions."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from runtime import decision
from runtime.assignment import certify_team
from runtime.brain import RuleBrain
from runtime.decision import Controller
from runtime.formation import assign_centred, assign_slots, linear_sum_assignment
from runtime.observation import frame_velocities, general_row
from runtime.patterns import make_pattern


@pytest.mark.parametrize("n", [2, 7, 40, 100])
def test_assignment_kernel_matches_assign_centred(n: int) -> None:
    rng = np.random.default_rng(n)
    c = Controller(RuleBrain())
    C = make_pattern("circle", n)
    c._set_pattern(C)
    prev = None
    for _ in range(30):
        P = rng.normal(size=(n, 2)) * 2.0
        if prev is not None and rng.random() < 0.5:  # near-ties: hysteresis decides
            P = C - C.mean(0) + rng.normal(size=(n, 2)) * 1e-3
        Pc = P - P.mean(0)
        c._prev_slots = prev
        got = c._assign(Pc)
        want = assign_centred(Pc, c._cc, prev)
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


def test_proof_keeps_the_solvers_assignment_while_a_team_forms_and_holds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """From PROOF_FROM robots the previous assignment is proven instead of solved, and
    every step's slots are still exactly scipy's with the hysteresis rule."""
    n = max(decision.PROOF_FROM, 30)
    proven: list[bool] = []

    def counting(*args: Any, **kwargs: Any) -> bool:
        ok = certify_team(*args, **kwargs)
        proven.append(ok)
        return ok

    monkeypatch.setattr(decision, "certify_team", counting)
    rng = np.random.default_rng(3)
    C = make_pattern("circle", n)
    pos = rng.uniform(0.0, 4.0, (n, 2))
    c = Controller(RuleBrain(), safety=None)
    ref = None
    for t in range(120):
        vel = np.array([c.decide(i, pos, C, t).velocity for i in range(n)])
        ref = assign_slots(pos, C, ref)
        assert c.previous_slots is not None
        assert c.previous_slots.tolist() == ref.tolist()
        pos = pos + 0.1 * vel + rng.normal(0.0, 1e-3, pos.shape)  # a little noise
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
