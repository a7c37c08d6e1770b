"""The shared slot assignment (runtime/core/assignment.py) against independent references.

References: scipy's ``linear_sum_assignment`` (values and ties), brute force over all
permutations (n <= 7), the hysteresis rule worked by hand, numpy's own sums. The
module is also run uncompiled (its .py and its solver's loaded by path,
:func:`support.core_source.python_assignment`) and held equal to the compiled one,
number for number.
"""

from __future__ import annotations

import itertools
from types import ModuleType

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment
from support.core_source import python_assignment

from runtime.core import assignment as A
from runtime.decision.formation import (
    _sq_cost,
    assign_slots_batch,
    assign_slots_env_last,
    keeps_previous,
)

REL, FLOOR = A.HYSTERESIS_REL, A.HYSTERESIS_ABS_M2
PY = python_assignment().assignment  # the source run as Python, its solver too


def _cost(rng: np.random.Generator, n: int, kind: int) -> np.ndarray:
    """Random (any scale), integer (tie-heavy), constant, or lattice squared distances."""
    if kind == 0:
        out: np.ndarray = rng.random((n, n)) * 10.0 ** rng.uniform(-6, 3)
        return out
    if kind == 1:
        return rng.integers(0, 3, (n, n)).astype(np.float64)
    if kind == 2:
        return np.full((n, n), float(rng.integers(0, 2)))
    P = rng.integers(0, 3, (n, 2)).astype(np.float64)
    Q = rng.integers(0, 3, (n, 2)).astype(np.float64)
    d = P[:, None] - Q[None]
    return np.ascontiguousarray(d[..., 0] ** 2 + d[..., 1] ** 2)


def _rule(cost: np.ndarray, prev: np.ndarray | None) -> np.ndarray:
    """scipy's assignment, then the hysteresis rule against ``prev``."""
    cols: np.ndarray = linear_sum_assignment(cost)[1].astype(np.int64)
    if prev is None:
        return cols
    rows = np.arange(len(cols))
    return prev if keeps_previous(cost[rows, cols].sum(), cost[rows, prev].sum()) else cols


def _team(mod: ModuleType, cost: np.ndarray, prev: np.ndarray | None,
          v: np.ndarray | None = None) -> tuple[np.ndarray, int, np.ndarray]:
    n = cost.shape[0]
    slots = np.full(n, -7, dtype=np.int64)
    pot = np.zeros(n) if v is None else v.copy()
    p = np.arange(n, dtype=np.int64) if prev is None else prev.astype(np.int64)
    res = mod.assign_team(np.ascontiguousarray(cost), p, prev is not None, pot, slots)
    return slots, res, pot


# ---------------------------------------------------------------- the solver


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 14), kind=st.integers(0, 3))
def test_cold_is_scipys_assignment_ties_included(seed: int, n: int, kind: int) -> None:
    cost = _cost(np.random.default_rng(seed), n, kind)
    slots, res, _ = _team(A, cost, None)
    assert res == 1
    assert slots.tolist() == linear_sum_assignment(cost)[1].tolist()


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
def test_brute_force_optimum_and_rule(n: int) -> None:
    """Over all permutations: the answer is optimal, or ``prev`` kept within the margin."""
    rng = np.random.default_rng(n)
    perms = np.array(list(itertools.permutations(range(n))), dtype=np.int64)
    rows = np.arange(n)
    for t in range(150):
        cost = _cost(rng, n, t % 4)
        totals = cost[rows, perms].sum(axis=1)
        best = totals.min()
        prev = perms[rng.integers(len(perms))]
        v = rng.normal(0, 1, n) if t % 2 else np.zeros(n)
        slots, _, _ = _team(A, cost, prev, v)
        got = cost[rows, slots].sum()
        old = cost[rows, prev].sum()
        if slots.tolist() == prev.tolist():
            assert not best < old - (REL * old + FLOOR) - 1e-12
        else:
            assert got == pytest.approx(best, rel=1e-12, abs=1e-12)
            assert best < old - (REL * old + FLOOR) + 1e-12
        cold, _, _ = _team(A, cost, None)
        assert cost[rows, cold].sum() == pytest.approx(best, rel=1e-12, abs=1e-12)


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 12), kind=st.integers(0, 3),
       warm=st.booleans())
def test_with_previous_is_scipy_and_the_rule(seed: int, n: int, kind: int, warm: bool) -> None:
    """Against scipy + the rule; with exact ties any optimal answer may differ from scipy's,
    so there only its cost (and the rule's choice) is held to the reference."""
    rng = np.random.default_rng(seed)
    cost = _cost(rng, n, kind)
    prev = rng.permutation(n).astype(np.int64)
    v = rng.normal(0, 1, n) if warm else np.zeros(n)
    slots, res, _ = _team(A, cost, prev, v)
    want = _rule(cost, prev)
    if kind == 0:  # no ties
        assert slots.tolist() == want.tolist()
    rows = np.arange(n)
    assert cost[rows, slots].sum() == pytest.approx(cost[rows, want].sum(), abs=1e-9)
    assert res in (0, 1)
    if res == 0:
        assert slots.tolist() == prev.tolist()


# ---------------------------------------------------------------- the rule


@pytest.mark.parametrize(
    ("off", "kept"),
    [
        (1.0005, True),  # old 2.001, new 2.0: better by 0.001 < margin 0.002002
        (1.002, False),  # old 2.004, new 2.0: better by 0.004 > margin 0.002005
    ],
)
def test_hysteresis_relative_margin_by_hand(off: float, kept: bool) -> None:
    cost = np.array([[1.0, off], [off, 1.0]])
    prev = np.array([1, 0], dtype=np.int64)  # the dearer assignment
    slots, res, _ = _team(A, cost, prev)
    assert res == 1
    assert slots.tolist() == ([1, 0] if kept else [0, 1])


@pytest.mark.parametrize(
    ("off", "kept"),
    [
        (4e-7, True),  # old 8e-7, new 0: better by 8e-7 < margin 1.0008e-6
        (6e-7, False),  # old 1.2e-6, new 0: better by 1.2e-6 > margin 1.0012e-6
    ],
)
def test_hysteresis_absolute_floor_by_hand(off: float, kept: bool) -> None:
    cost = np.array([[0.0, off], [off, 0.0]])
    slots, _, _ = _team(A, cost, np.array([1, 0]))
    assert slots.tolist() == ([1, 0] if kept else [0, 1])


def test_an_optimal_previous_is_kept_without_solving() -> None:
    cost = np.array([[0.0, 1.0, 4.0], [1.0, 0.0, 1.0], [4.0, 1.0, 0.0]])
    slots, res, v = _team(A, cost, None)
    assert res == 1 and slots.tolist() == [0, 1, 2]
    moved = cost + np.array([[0.01, 0.0, 0.0], [0.0, 0.02, 0.0], [0.0, 0.0, 0.0]])
    slots2, res2, _ = _team(A, moved, slots, v)
    assert res2 == 0 and slots2.tolist() == [0, 1, 2]


# ---------------------------------------------------- warm start, bad input, sizes


@pytest.mark.parametrize("n", [2, 6, 20, 60])
def test_warm_potentials_give_the_cold_answer(n: int) -> None:
    """A team moving step by step, potentials carried: every step equals a cold solve + rule."""
    rng = np.random.default_rng(n)
    C = rng.uniform(-2, 2, (n, 2))
    Cc = C - C.mean(0)
    P = rng.uniform(0, 6, (n, 2))
    pot = np.zeros(n)
    prev: np.ndarray | None = None
    kept = 0
    for t in range(90):
        P = P + rng.normal(0, 0.05 if t < 30 else 1e-4, P.shape)  # forming, then formed
        P += 0.2 * (Cc[prev] - (P - P.mean(0))) if prev is not None else 0.0
        cost = np.empty((n, n))
        A.team_cost(P, np.ascontiguousarray(Cc[:, 0]), np.ascontiguousarray(Cc[:, 1]), cost)
        slots, res, pot = _team(A, cost, prev, pot)
        assert slots.tolist() == _rule(cost, prev).tolist()
        kept += res == 0
        prev = slots
    assert kept > 0  # the formed team's steps are proven without a solve


@pytest.mark.parametrize("bad", [[0, 0, 1, 2], [0, 1, 2, 4], [-1, 0, 1, 2], [3, 2, 1, 1]])
def test_previous_that_is_not_a_permutation_is_ignored(bad: list[int]) -> None:
    rng = np.random.default_rng(3)
    cost = rng.random((4, 4))
    v = rng.normal(0, 1, 4)
    slots, res, _ = _team(A, cost, np.array(bad), v)
    assert res == 1 and slots.tolist() == linear_sum_assignment(cost)[1].tolist()
    # and a valid one is ignored when has_prev is False
    out = np.empty(4, dtype=np.int64)
    assert A.assign_team(cost, np.array([3, 2, 1, 0]), False, v.copy(), out) == 1
    assert out.tolist() == linear_sum_assignment(cost)[1].tolist()


@pytest.mark.parametrize("mod", [A, PY], ids=["compiled", "python"])
def test_non_finite_costs(mod: ModuleType) -> None:
    cost = np.arange(9.0).reshape(3, 3)
    prev = np.array([2, 0, 1], dtype=np.int64)
    for bad in (np.nan, -np.inf):
        c = cost.copy()
        c[1, 2] = bad
        slots, res, v = _team(mod, c, prev, np.ones(3))
        assert res == -1 and slots.tolist() == [2, 0, 1] and v.tolist() == [0, 0, 0]
        slots, res, _ = _team(mod, c, None)
        assert res == -1 and slots.tolist() == [0, 1, 2]
    c = np.full((3, 3), np.inf)
    c[:, 0] = 1.0  # one finite column: no finite assignment (scipy: infeasible)
    with pytest.raises(ValueError):
        linear_sum_assignment(c)
    assert _team(mod, c, None)[1] == -1
    assert _team(mod, c, prev)[1] == -1
    c = cost.copy()
    c[0, 0] = c[1, 1] = np.inf  # +inf entries, a finite assignment remains: scipy's
    for p in (None, prev):
        slots, res, _ = _team(mod, c, p)
        assert res == 1 and slots.tolist() == _rule(c, p).tolist()


def test_one_and_two_robots() -> None:
    one = np.array([[3.5]])
    assert _team(A, one, None)[0].tolist() == [0]
    slots, res, _ = _team(A, one, np.array([0]))
    assert slots.tolist() == [0] and res in (0, 1)
    for cost in (np.array([[0.0, 1.0], [1.0, 0.0]]), np.array([[1.0, 0.0], [0.0, 1.0]]),
                 np.ones((2, 2))):
        assert _team(A, cost, None)[0].tolist() == linear_sum_assignment(cost)[1].tolist()
        for prev in ([0, 1], [1, 0]):
            got = _team(A, cost, np.array(prev))[0]
            assert got.tolist() == _rule(cost, np.array(prev)).tolist()
    empty = np.zeros((0, 0))
    assert _team(A, empty, None)[0].shape == (0,)


def test_sizes_are_checked() -> None:
    out = np.empty(3, dtype=np.int64)
    with pytest.raises(ValueError):
        A.assign_team(np.zeros((3, 3)), np.arange(2), True, np.zeros(3), out)
    with pytest.raises(ValueError):
        A.team_cost(np.zeros((3, 2)), np.zeros(3), np.zeros(2), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        A.assign_teams(np.zeros((2, 3, 2)), np.zeros((2, 4, 2)), np.zeros((2, 3), np.int64),
                       False, np.zeros((2, 3)), np.zeros((2, 3), np.int64))


# ----------------------------------------------------------- cost, sums, batches


@pytest.mark.parametrize("n", [1, 2, 9, 40])
def test_team_cost_is_numpys(n: int) -> None:
    rng = np.random.default_rng(n)
    pos = rng.uniform(-5, 5, (n, 2))
    cc = rng.uniform(-1, 1, (n, 2))
    cost = np.empty((n, n))
    cx, cy = A.team_cost(pos, np.ascontiguousarray(cc[:, 0]), np.ascontiguousarray(cc[:, 1]),
                         cost)
    cen = np.add.reduce(pos, 0) / n
    assert [cx, cy] == cen.tolist()
    d = (pos - cen)[:, None, :] - cc[None]
    d *= d
    assert np.array_equal(cost, d[..., 0] + d[..., 1])


@pytest.mark.parametrize("n", [1, 5, 8, 17, 128, 129, 300])
def test_path_cost_is_numpys_sum(n: int) -> None:
    rng = np.random.default_rng(n)
    cost = rng.random((n, n)) * 10.0 ** rng.uniform(-3, 3, (n, n))
    slots = rng.permutation(n).astype(np.int64)
    assert A.path_cost(cost, slots) == cost[np.arange(n), slots].sum()


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), E=st.integers(1, 9), n=st.integers(1, 11),
       jitter=st.sampled_from([1e-9, 1e-3, 0.3]))
def test_teams_are_scipy_and_the_rule_on_strided_views(seed: int, E: int, n: int,
                                                       jitter: float) -> None:
    """assign_teams on the training world's robot-major arrays, transposed (no copy)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 10, (2, n, E))  # robot-major, as the world keeps them
    C = rng.uniform(-3, 3, (2, n, E))
    C -= C.sum(axis=1, keepdims=True) / n
    P, Cc = X.transpose(2, 1, 0), C.transpose(2, 1, 0)
    prev = assign_slots_batch(P + rng.normal(0, jitter, P.shape), Cc)
    pot = np.zeros((n, E))
    slots = np.empty((n, E), dtype=np.int64)
    solved = A.assign_teams(P, Cc, np.ascontiguousarray(prev.T).T, True, pot.T, slots.T)
    assert 0 <= solved <= E
    cost = _sq_cost(P, Cc)
    for e in range(E):
        assert slots[:, e].tolist() == _rule(cost[e], prev[e]).tolist()


def test_batch_wrappers_equal_the_rule() -> None:
    rng = np.random.default_rng(9)
    E, n = 12, 8
    P, C = rng.uniform(0, 10, (E, n, 2)), rng.uniform(-2, 2, (E, n, 2))
    cost = _sq_cost(P, C)
    prev = np.stack([rng.permutation(n) for _ in range(E)])
    prev[0, 0] = prev[0, 1]  # not a permutation: the solver's answer
    want = np.stack([_rule(cost[e], prev[e] if e else None) for e in range(E)])
    assert np.array_equal(assign_slots_batch(P, C, previous=prev), want)
    pot = np.zeros((n, E))
    env_last = np.ascontiguousarray(cost.transpose(1, 2, 0))
    assert np.array_equal(assign_slots_env_last(env_last, prev.T.copy(), pot).T, want)
    again = assign_slots_env_last(env_last, want.T.copy(), pot)  # warm: kept, unsolved
    assert np.array_equal(again.T, want)


def test_world_steps_keep_scipys_assignment() -> None:
    """The training world's every step equals scipy per env with the hysteresis rule."""
    from runtime.decision.observation import ObservationSpec
    from trainer.world.training_world import BatchWorld

    w = BatchWorld(8, 6, ("circle", "line"), ObservationSpec("general"), seed=5, build_obs=False)
    rng = np.random.default_rng(0)
    for _ in range(80):
        prev = w.slots.copy()
        res = w.step(rng.uniform(-1.0, 1.0, (8, 6, 2)))
        cost = _sq_cost(w.positions, w.pattern)
        for e in np.flatnonzero(~res.done):  # finished envs were reset and solved afresh
            assert w.slots[e].tolist() == _rule(cost[e], prev[e]).tolist()


# ------------------------------------------------------ compiled == uncompiled


def test_python_source_gives_the_compiled_numbers() -> None:
    """The .py run as Python: the same slots, returns and potentials, bit for bit."""
    rng = np.random.default_rng(11)
    for t in range(120):
        n = int(rng.integers(1, 12))
        cost = _cost(rng, n, t % 4)
        prev = rng.permutation(n) if t % 3 else np.array(rng.integers(0, n, n))
        v = rng.normal(0, 1, n) if t % 2 else np.zeros(n)
        for p in (None, prev):
            a, b = _team(A, cost, p, v), _team(PY, cost, p, v)
            assert a[0].tolist() == b[0].tolist() and a[1] == b[1]
            assert a[2].tobytes() == b[2].tobytes()
        slots = rng.permutation(n).astype(np.int64)
        assert A.path_cost(cost, slots) == PY.path_cost(cost, slots)
    E, n = 5, 9
    pos, pat = rng.uniform(0, 5, (E, n, 2)), rng.uniform(-1, 1, (E, n, 2))
    prev = np.stack([rng.permutation(n) for _ in range(E)])
    outs = []
    for mod in (A, PY):
        pot, slots = rng.normal(0, 1, (E, n)), np.empty((E, n), np.int64)
        pot[:] = 0.5
        solved = mod.assign_teams(pos, pat, prev, True, pot, slots)
        cost = np.empty((n, n))
        cxy = mod.team_cost(pos[0], pat[0, :, 0].copy(), pat[0, :, 1].copy(), cost)
        outs.append((solved, slots.tolist(), pot.tobytes(), cxy, cost.tobytes()))
    assert outs[0] == outs[1]


@pytest.mark.parametrize("mod", [A, PY], ids=["compiled", "python"])
def test_a_robots_team_assignment_is_scipy_and_the_rule_step_after_step(mod: ModuleType) -> None:
    """The robot's state object: a forming team, warm from step to step, gives scipy's
    assignment with the hysteresis rule against its own last slots, and the centroid."""
    rng = np.random.default_rng(21)
    n = 12
    pattern = rng.uniform(-2, 2, (n, 2))
    cc = pattern - pattern.mean(axis=0)
    goal = rng.uniform(0, 4, (n, 2))
    pos = rng.uniform(0, 10, (n, 2))
    team = mod.TeamAssignment(cc)
    prev = None
    for _ in range(40):
        pos = pos + 0.1 * (goal - pos) + rng.normal(0, 0.01, pos.shape)
        slots = np.empty(n, dtype=np.int64)
        cx, cy = team.step(np.ascontiguousarray(pos), slots)
        assert (cx, cy) == tuple((np.add.reduce(pos, 0) / n).tolist())
        pc = pos - np.array([cx, cy])
        cost = ((pc[:, None, :] - cc[None, :, :]) ** 2).sum(-1)
        want = _rule(cost, prev)
        np.testing.assert_array_equal(slots, want)
        prev = slots
    with pytest.raises(ValueError):
        team.step(np.zeros((n + 1, 2)), np.empty(n + 1, dtype=np.int64))
