"""A robot's nearest others (runtime/core/neighbours.py) against a brute-force choice.

The reference sorts every other robot by (squared distance, id) with Python's
``sorted`` and keeps the first k closer than the range, never one whose distance is
not finite. ``nearest`` is a C-level function once compiled: it is called directly
here from its source run as Python (:func:`python_core`), and, compiled, through its
two callers, the general row's neighbour block and the ORCA filter.

:func:`python_core` (``support.core_source``) is also what the observation and ORCA tests use
to run the core's source uncompiled.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from support.core_source import python_core

from runtime.core.general_row import GeneralRows
from runtime.core.orca import OrcaFilter

INF = math.inf


def brute_nearest(pos: Any, e: int, i: int, k: int, range_sq: float
                  ) -> tuple[list[int], list[float]]:
    """The k nearest others of robot i of team e closer than sqrt(range_sq): (ids, d2)."""
    px, py = float(pos[e, i, 0]), float(pos[e, i, 1])
    found = []
    for j in range(pos.shape[1]):
        if j == i:
            continue
        dx, dy = float(pos[e, j, 0]) - px, float(pos[e, j, 1]) - py
        d2 = dx * dx + dy * dy
        if math.isfinite(d2) and d2 < range_sq:
            found.append((d2, j))
    best = sorted(found)[:k]  # by squared distance, then id
    return [j for _, j in best], [d2 for d2, _ in best]


def run_nearest(pos: Any, k: int, range_sq: float, e0: int = 0, e1: int | None = None,
                i0: int = 0, i1: int | None = None) -> tuple[Any, Any, Any]:
    """The uncompiled ``nearest`` on robots i0..i1 of teams e0..e1: (ids, d2, count)."""
    e1 = pos.shape[0] if e1 is None else e1
    i1 = pos.shape[1] if i1 is None else i1
    ids = np.full((e1 - e0, i1 - i0, max(k, 1)), -7, dtype=np.intp)
    d2 = np.full((e1 - e0, i1 - i0, max(k, 1)), -7.0)
    count = np.full((e1 - e0, i1 - i0), -7, dtype=np.intp)
    python_core().neighbours.nearest(np.ascontiguousarray(pos, dtype=np.float64), e0, e1, i0,
                                     i1, k, range_sq, ids, d2, count)
    return ids, d2, count


def crowd(rng: np.random.Generator, E: int, n: int, kind: str) -> Any:
    """E teams of n: ``random``, ``lattice`` (many exact distance ties, coincident robots)
    or ``nonfinite`` (random, with NaN and inf positions)."""
    if kind == "lattice":
        return rng.integers(0, 4, (E, n, 2)) * 0.25
    pos = rng.uniform(0.0, 3.0, (E, n, 2))
    if kind == "nonfinite" and n > 2:
        pos[:, 1, 0] = np.nan
        pos[:, n - 1] = [np.inf, 0.5]
        pos[0, 0, 1] = -np.inf
    return pos


# ------------------------------------------------------- uncompiled, called directly


@pytest.mark.parametrize("kind", ["random", "lattice", "nonfinite"])
@pytest.mark.parametrize("n", [1, 2, 5, 13, 40])
def test_nearest_is_the_brute_force_choice(n: int, kind: str) -> None:
    rng = np.random.default_rng(n * 10 + len(kind))
    E = 3
    pos = crowd(rng, E, n, kind)
    for k in sorted({0, 1, 3, max(n - 1, 0), n + 2}):
        for range_sq in (INF, 1.0, 0.25 ** 2 * 2.0):  # the last one exactly on lattice ties
            ids, d2, count = run_nearest(pos, k, range_sq)
            for e in range(E):
                for i in range(n):
                    want_ids, want_d2 = brute_nearest(pos, e, i, k, range_sq)
                    m = int(count[e, i])
                    assert ids[e, i, :m].tolist() == want_ids, (e, i, k, range_sq)
                    assert d2[e, i, :m].tolist() == want_d2


def test_a_block_of_robots_and_teams_is_written_at_its_offset() -> None:
    rng = np.random.default_rng(3)
    pos = crowd(rng, 5, 9, "lattice")
    ids, d2, count = run_nearest(pos, 4, INF, e0=1, e1=4, i0=2, i1=7)
    assert ids.shape == (3, 5, 4)
    for e in range(1, 4):
        for i in range(2, 7):
            want_ids, want_d2 = brute_nearest(pos, e, i, 4, INF)
            assert count[e - 1, i - 2] == 4
            assert ids[e - 1, i - 2].tolist() == want_ids
            assert d2[e - 1, i - 2].tolist() == want_d2


def test_hand_worked_ties_range_and_k() -> None:
    #            0          1          2           3          4          5
    pts = [[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [2.0, 0.0], [0.0, -1.0]]
    pos = np.array([pts])
    ids, d2, count = run_nearest(pos, 3, INF, i1=1)
    assert count[0, 0] == 3 and ids[0, 0].tolist() == [1, 2, 3]  # four at 1 m: by id
    assert d2[0, 0].tolist() == [1.0, 1.0, 1.0]
    ids, _, count = run_nearest(pos, 10, INF, i1=1)
    assert ids[0, 0, : count[0, 0]].tolist() == [1, 2, 3, 5, 4]  # k > n - 1: all others
    ids, _, count = run_nearest(pos, 10, 4.0, i1=1)  # robot 4 exactly at the range: out
    assert ids[0, 0, : count[0, 0]].tolist() == [1, 2, 3, 5]
    ids, _, count = run_nearest(pos, 10, math.nextafter(4.0, INF), i1=1)
    assert ids[0, 0, : count[0, 0]].tolist() == [1, 2, 3, 5, 4]
    ids, _, count = run_nearest(pos, 10, 1.0, i1=1)  # all at exactly 1 m: none closer
    assert count[0, 0] == 0
    ids, _, count = run_nearest(pos, 2, INF, i0=4, i1=5)  # robot 4: 1 then 0 / 3 / 5
    assert ids[0, 0].tolist() == [1, 0]


def test_k_zero_finds_nobody_and_writes_no_table() -> None:
    pos = np.array([[[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]]])
    ids, d2, count = run_nearest(pos, 0, INF)
    assert count.tolist() == [[0, 0, 0]]
    assert (ids == -7).all() and (d2 == -7.0).all()


def test_non_finite_positions_are_never_near() -> None:
    pos = np.array([[[0.0, 0.0], [np.nan, 0.0], [0.0, np.inf], [0.5, 0.0], [-np.inf, np.nan],
                     [1e300, 1e300]]])
    with np.errstate(over="ignore"):  # 1e300 squared, as Python floats overflow
        ids, d2, count = run_nearest(pos, 6, INF)
    assert ids[0, 0, : count[0, 0]].tolist() == [3]  # 1e300 squared overflows: inf, not near
    assert d2[0, 0, 0] == 0.25
    for i in (1, 2, 4):  # a robot without a finite position has no neighbour
        assert count[0, i] == 0
    assert ids[0, 3, : count[0, 3]].tolist() == [0]
    assert count[0, 5] == len(brute_nearest(pos, 0, 5, 6, INF)[0]) == 0


# ----------------------------------------------------------- compiled, through its callers


@pytest.mark.parametrize("kind", ["random", "lattice", "nonfinite"])
def test_the_general_rows_neighbours_are_the_brute_force_choice(kind: str) -> None:
    """Each neighbour entry [dx, dy, dvx, dvy] of the row is the brute-force neighbour's
    (random velocities tell coincident robots apart)."""
    rng = np.random.default_rng(len(kind))
    for n, k in ((1, 3), (2, 1), (7, 3), (12, 11), (12, 20), (30, 6)):
        pos = np.ascontiguousarray(crowd(rng, 3, n, kind), dtype=np.float64)
        vel = rng.normal(size=pos.shape)
        rows = np.full((3, n, 6 + 5 * k), np.nan)
        GeneralRows(k, 0.1).teams(pos, vel, pos.copy(), np.zeros(3), rows)
        for e in range(3):
            for i in range(n):
                want, _ = brute_nearest(pos, e, i, k, INF)
                block = rows[e, i, 6:].reshape(k, 5)
                m = len(want)
                assert (block[:m, 4] == 1.0).all() and (block[m:] == 0.0).all()
                np.testing.assert_array_equal(block[:m, 0:2], pos[e, want] - pos[e, i])
                np.testing.assert_array_equal(block[:m, 2:4], vel[e, want] - vel[e, i])


@pytest.mark.parametrize("kind", ["random", "lattice", "nonfinite"])
@pytest.mark.parametrize("cap", [1, 3, 10])
def test_the_filters_neighbours_are_the_brute_force_choice(cap: int, kind: str) -> None:
    """A robot's filtered velocity is the one it gets in a team of itself and the
    brute-force neighbours alone (in their order): the filter looks at those and no
    other, and in that order."""
    rng = np.random.default_rng(cap * 7 + len(kind))
    dist, E, n = 1.0, 2, 16
    whole = OrcaFilter(cap, dist, 0.24, 0.1, 0.2, 1.0)
    alone = OrcaFilter(64, dist, 0.24, 0.1, 0.2, 1.0)
    sizes = set()
    for trial in range(3):
        pos = np.ascontiguousarray(crowd(rng, E, n, kind) * 0.5)
        if trial == 0:
            pos[1, 2] = [20.0, 20.0]  # alone
        vel = rng.normal(size=pos.shape) * 0.5
        for e in range(E):
            for i in range(n):
                if not np.isfinite(pos[e, i]).all():
                    continue
                pref = rng.normal(size=2)
                want, _ = brute_nearest(pos, e, i, cap, dist * dist)
                sizes.add(len(want))
                team = [i, *want]
                got = whole.robot(e, i, pos, vel, *pref, 0.75)
                ref = alone.robot(0, 0, np.ascontiguousarray(pos[e, team][None]),
                                  np.ascontiguousarray(vel[e, team][None]), *pref, 0.75)
                assert got == ref, (e, i, want)
    assert {0, cap} <= sizes  # alone in range and a full table were both covered
