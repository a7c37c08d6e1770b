"""The robot's faster decision kernels give the very numbers of the shared functions."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.brain import RuleBrain
from runtime.decision import Controller
from runtime.formation import assign_centred
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
