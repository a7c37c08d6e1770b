"""The compiled step kernels against the numpy path and scipy: the same numbers.

Each kernel compiles once per process (seconds) or loads from numba's cache;
the hypothesis cases then run in microseconds.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("numba")

from runtime.formation import assign_slots_env_last, linear_sum_assignment
from runtime.observation import ObservationSpec, general_observation_env_last
from runtime.world_config import DEFAULT_WORLD
from trainer import kernels
from trainer.training_world import BatchWorld

PATTERNS = ("circle", "line", "cross", "heart", "triangle")


def _cost(rng: np.random.Generator, n: int, kind: int) -> np.ndarray:
    """Random, integer (tie-heavy), constant, or lattice squared-distance costs."""
    if kind == 0:
        return rng.random((n, n)) * 10.0 ** rng.uniform(-6, 3)
    if kind == 1:
        return rng.integers(0, 3, (n, n)).astype(np.float64)
    if kind == 2:
        return np.full((n, n), float(rng.integers(0, 2)))
    P = rng.integers(0, 3, (n, 2)).astype(np.float64)
    Q = rng.integers(0, 3, (n, 2)).astype(np.float64)
    d = P[:, None] - Q[None]
    return np.asarray(d[..., 0] ** 2 + d[..., 1] ** 2)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 14), kind=st.integers(0, 3))
def test_lsap_is_scipys_assignment_ties_included(seed: int, n: int, kind: int) -> None:
    cost = _cost(np.random.default_rng(seed), n, kind)
    cols = np.empty(n, np.int64)
    assert kernels.lsap(cost, cols)
    ref = linear_sum_assignment(cost)[1]
    rows = np.arange(n)
    assert abs(cost[rows, cols].sum() - cost[rows, ref].sum()) <= 1e-9
    assert np.array_equal(cols, ref)  # the same tie-breaking, not only the same cost


def test_lsap_refuses_nan_and_infeasible() -> None:
    cols = np.empty(3, np.int64)
    assert not kernels.lsap(np.array([[0.0, 1, 2], [1, np.nan, 2], [0, 1, 2]]), cols)
    assert not kernels.lsap(np.full((3, 3), np.inf), cols)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 130))
def test_pairwise_sum_is_numpys(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.random(n) * 10.0 ** rng.uniform(-3, 3, n)
    assert kernels.pairwise_sum(a) == a.sum()


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), E=st.integers(1, 9), n=st.integers(2, 11),
       grid=st.booleans(), jitter=st.sampled_from([0.0, 1e-9, 1e-3, 0.3]))
def test_batched_assignment_is_the_numpy_paths(seed: int, E: int, n: int, grid: bool,
                                               jitter: float) -> None:
    """Slots, slot positions and distances equal the numpy path's (scipy + hysteresis)."""
    rng = np.random.default_rng(seed)
    if grid:  # tie-heavy: robots and slots on a coarse lattice
        X = rng.integers(0, 3, (2, n, E)).astype(np.float64)
        C = rng.integers(0, 3, (2, n, E)).astype(np.float64)
    else:
        X = rng.uniform(0, 10, (2, n, E))
        C = rng.uniform(-3, 3, (2, n, E))
    X = X + rng.normal(0, jitter, X.shape) if jitter else X
    C = C - C.sum(axis=1, keepdims=True) / n
    Cc = C - C.sum(axis=1, keepdims=True) / n
    previous = np.stack([rng.permutation(n) for _ in range(E)], axis=1).astype(np.int64)
    if E > 1:
        previous[:, 0] = np.arange(n)  # often already optimal on a lattice
    pot = rng.normal(0, 1, (n, E)) if seed % 2 else np.zeros((n, E))
    slots, G, dist2, _ = kernels.assign_env_last(X, Cc, C, previous, pot.copy())
    total = X.sum(axis=1, keepdims=True)
    Xc = X - total / n
    dx = Xc[0][:, None, :] - Cc[0][None, :, :]
    dy = Xc[1][:, None, :] - Cc[1][None, :, :]
    dx *= dx
    dy *= dy
    dx += dy
    ref = assign_slots_env_last(dx, previous.copy(), pot.copy())
    assert np.array_equal(slots, ref)
    Q = np.take_along_axis(C, ref[None], axis=1)
    G_ref = Q + total * (1.0 / n)
    gap = X - G_ref
    assert np.array_equal(G, G_ref)
    assert np.array_equal(dist2, gap[0] * gap[0] + gap[1] * gap[1])


def test_observation_kernel_is_the_runtime_builders_with_ties() -> None:
    """Equal to general_observation_env_last as float32, equidistant neighbours included."""
    rng = np.random.default_rng(4)
    for n, k, E in ((10, 6, 5), (4, 6, 3), (2, 1, 2), (7, 3, 4)):
        X = rng.integers(0, 4, (2, n, E)).astype(np.float64) * 0.5  # many equal distances
        X[:, 0] += 1e-3 * np.arange(E)
        Xp = X - rng.uniform(-0.05, 0.05, X.shape)
        G = X + rng.normal(0, 1, X.shape)
        G[:, 1] = X[:, 1]  # a robot on its slot
        ref = general_observation_env_last(X, Xp, G, k, DEFAULT_WORLD)
        reach = DEFAULT_WORLD.v_max_mps * DEFAULT_WORLD.dt_s
        got = kernels.general_observation(X, Xp, G, k, DEFAULT_WORLD.dt_s, reach)
        assert got.dtype == np.float32 and got.shape == ref.shape
        assert np.array_equal(got, ref)


def _pair(seed: int, E: int = 8, **kw: object) -> tuple[BatchWorld, BatchWorld]:
    spec = ObservationSpec("general")
    return (BatchWorld(E, 10, PATTERNS, spec, seed=seed, compiled=False, **kw),  # type: ignore[arg-type]
            BatchWorld(E, 10, PATTERNS, spec, seed=seed, **kw))  # type: ignore[arg-type]


@pytest.mark.parametrize("E", [1, 8])
def test_compiled_world_steps_bit_for_bit_as_numpy(E: int) -> None:
    """Random moves, jams at the centroid with NaN and huge actions, resets: the same numbers."""
    a, b = _pair(11, E, step_limit=40)
    assert b.compiled and not a.compiled
    rng = np.random.default_rng(0)
    contacts = 0
    for t in range(160):
        if t % 40 < 20:
            act = rng.uniform(-1, 1, (E, 10, 2))
        else:  # everyone at the centroid, faster than v_max: contacts and jams
            g = a.positions.mean(axis=1, keepdims=True) - a.positions
            act = 3.0 * g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-9)
            act[t % E, t % 10] = [np.nan, 1.0]
            act[(t + 3) % E, 0] = [1e300, 1e300]
        with np.errstate(over="ignore"):  # 1e300: a square that overflows holds still
            if t % 5 == 0:  # float32 actions too: widened as the numpy path widens them
                act = act.astype(np.float32)
            ra, rb = a.step(act), b.step(act)
        contacts += int(ra.collisions.sum())
        for f in ("obs", "reward", "done", "formed", "truncated", "collisions"):
            assert np.array_equal(getattr(ra, f), getattr(rb, f)), (t, f)
        assert np.array_equal(a.frames, b.frames) and np.array_equal(a.slots, b.slots)
        assert np.array_equal(a.travel, b.travel)
        assert np.array_equal(a.last_robot_collisions, b.last_robot_collisions)
    assert contacts > 10 * E  # the jams were exercised
    assert np.array_equal(a.episode_collisions, b.episode_collisions)
    assert a.contact_fallbacks == b.contact_fallbacks


def test_compiled_world_refuses_bad_actions_shape() -> None:
    _, b = _pair(0)
    with pytest.raises(ValueError, match="actions must be"):
        b.step(np.zeros((8, 9, 2)))


def test_uncacheable_function_still_compiles() -> None:
    """A function numba cannot cache (no source file here; a read-only install) compiles
    in memory instead of failing."""
    ns: dict[str, object] = {}
    exec("def twice(x):\n    return 2.0 * x\n", ns)
    fn = kernels._jit(ns["twice"])  # type: ignore[arg-type]
    assert fn(1.5) == 3.0
