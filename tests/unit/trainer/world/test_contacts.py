"""The training world's move (trainer/world/contacts.py) against independent references.

A collision is what :func:`runtime.decision.formation.count_collisions` (the closest
approach of :func:`runtime.decision.formation.swept_pair_distance`) says it is; after a
move no two centres are closer than 2R; the speed clamp, the hold-still rule and
the travel are checked by hand; the source run as Python gives the compiled
module's numbers.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import numpy.typing as npt
import pytest

from runtime.decision.formation import count_collisions, min_separation, swept_pair_distance
from runtime.decision.observation import ObservationSpec
from runtime.world_config import DEFAULT_WORLD
from trainer.world import contacts
from trainer.world.contacts import CONTACT_TOL_M, move
from trainer.world.training_world import BatchWorld

W = DEFAULT_WORLD
R = W.radius_m
TWO_R = W.min_separation_m
REACH = W.v_max_mps * W.dt_s
Arr = npt.NDArray[np.float64]
IntArr = npt.NDArray[np.int64]


def robot_major(P: Arr) -> Arr:
    """(E, N, 2) -> (2, N, E), contiguous."""
    return np.ascontiguousarray(P.transpose(2, 1, 0))


def env_major(X: Arr) -> Arr:
    """(2, N, E) -> (E, N, 2)."""
    return np.ascontiguousarray(X.transpose(2, 1, 0))


def step(
    P: Arr, actions: npt.NDArray[np.floating], module: ModuleType = contacts
) -> tuple[Arr, IntArr, IntArr, int, Arr]:
    """One move from positions ``P`` (E, N, 2): (positions (E, N, 2), hits (E, N),
    colliding pairs (E,), fallbacks, travel of this move (E, N))."""
    E, N, _ = P.shape
    travel = np.zeros((N, E))
    X1, hits, pairs, falls = module.move(actions, robot_major(P), travel, W)
    return env_major(X1), hits.T, pairs, falls, travel.T


def within_v_max(rng: np.random.Generator, shape: tuple[int, ...]) -> Arr:
    """Velocities strictly inside the v_max disc: the commanded displacement is a * dt exactly."""
    ang = rng.uniform(0.0, 2.0 * np.pi, shape)
    r = rng.uniform(0.0, 0.999, shape) * W.v_max_mps
    return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=-1)


def packed(rng: np.random.Generator, E: int, n: int, gap: float = 0.02) -> Arr:
    """A jittered grid of ``n`` discs per env, gaps of 0 to ``gap`` m: all apart, tightly."""
    side = int(np.ceil(np.sqrt(n)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n]
    out: Arr = grid * (TWO_R + gap) + rng.uniform(0.0, gap / 2, (E, n, 2))
    return out


# --------------------------------------------------------- what a collision is


@pytest.mark.parametrize("seed", range(5))
def test_isolated_pairs_collide_as_the_definition_says(seed: int) -> None:
    """Pairs far from each other: each pair's count is count_collisions' for the commanded move."""
    rng = np.random.default_rng(seed)
    E, pairs_per_env = 64, 4
    n = 2 * pairs_per_env
    P0 = np.empty((E, n, 2))
    for k in range(pairs_per_env):  # pair k near (10 k, 0); pairs 10 m apart never meet
        a = rng.uniform(-0.2, 0.2, (E, 2))
        b = a + rng.uniform(TWO_R, TWO_R + 0.12, (E, 1)) * np.stack(
            [np.cos(t := rng.uniform(0, 2 * np.pi, E)), np.sin(t)], -1
        )
        P0[:, 2 * k] = a
        P0[:, 2 * k + 1] = b
        P0[:, 2 * k : 2 * k + 2, 0] += 10.0 * k
    V = within_v_max(rng, (E, n))
    P1 = P0 + V * W.dt_s
    P, hits, pairs, falls, _ = step(P0, V)
    want = count_collisions(P0, P1, W, CONTACT_TOL_M)
    np.testing.assert_array_equal(pairs, want)
    assert want.sum() > E // 4  # the pairs did meet, often
    d = swept_pair_distance(P0, P1)
    met = d < TWO_R - CONTACT_TOL_M  # (E, n, n)
    np.testing.assert_array_equal(hits, met.sum(axis=-1))  # charged to both robots
    assert falls == 0
    assert np.all(min_separation(P) >= TWO_R - CONTACT_TOL_M)


@pytest.mark.parametrize("seed", range(4))
def test_every_swept_collision_is_counted_in_a_crowd(seed: int) -> None:
    """In a crowd a push may cause more contacts, never fewer than the definition's."""
    rng = np.random.default_rng(seed)
    E, n = 32, 12
    P0 = np.stack([packed(rng, 1, n, 0.1)[0] for _ in range(E)])  # apart at the start
    V = within_v_max(rng, (E, n))
    _, hits, pairs, _, _ = step(P0, V)
    met = swept_pair_distance(P0, P0 + V * W.dt_s) < TWO_R - CONTACT_TOL_M
    assert np.all(pairs >= count_collisions(P0, P0 + V * W.dt_s, W, CONTACT_TOL_M))
    assert np.all(hits >= met.sum(axis=-1))
    np.testing.assert_array_equal(hits.sum(axis=1), 2 * pairs)
    assert pairs.sum() > 0


def test_head_on_pair_ends_exactly_two_r_apart_with_one_collision() -> None:
    """Hand-worked: 0.3 m apart, both at v_max (0.1 m per step) toward each other: they
    would end 0.1 m apart; each is pushed back 0.05 m, to 2R = 0.2 m around the midpoint."""
    assert (R, REACH) == (0.1, 0.1)
    P0 = np.array([[[0.0, 0.0], [0.3, 0.0], [5.0, 5.0]]])
    a = np.array([[[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0]]])
    P, hits, pairs, falls, travel = step(P0, a)
    np.testing.assert_allclose(P[0, :2], [[0.05, 0.0], [0.25, 0.0]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(P[0, 1] - P[0, 0]), TWO_R, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(P[0, 2], [5.0, 5.0])
    np.testing.assert_array_equal(pairs, [1])
    np.testing.assert_array_equal(hits, [[1, 1, 0]])
    assert falls == 0
    np.testing.assert_allclose(travel, [[0.05, 0.05, 0.0]], rtol=0, atol=1e-15)
    # pushing on: they stay at contact, and every step they push is a collision
    P2, hits2, pairs2, _, travel2 = step(P, a)
    np.testing.assert_allclose(P2, P, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(pairs2, [1])
    np.testing.assert_array_equal(hits2, [[1, 1, 0]])
    np.testing.assert_allclose(travel2, 0.0, atol=1e-15)


def test_near_miss_is_no_collision() -> None:
    P0 = np.array([[[0.0, 0.0], [0.15, TWO_R + 0.01]]])
    a = np.array([[[1.0, 0.0], [-1.0, 0.0]]])  # they pass by, 1 cm apart
    P, hits, pairs, _, _ = step(P0, a)
    np.testing.assert_array_equal(pairs, [0])
    np.testing.assert_array_equal(hits, [[0, 0]])
    np.testing.assert_allclose(P, P0 + a * W.dt_s, rtol=0, atol=0)


# ------------------------------------------------------------- no overlap, ever


@pytest.mark.parametrize(("E", "n"), [(8, 3), (16, 10), (4, 30)])
def test_centres_stay_two_r_apart_after_every_move(E: int, n: int) -> None:
    rng = np.random.default_rng(E * n)
    P = packed(rng, E, n)
    assert np.all(min_separation(P) >= TWO_R)
    total = 0
    for t in range(60):
        a = rng.uniform(-2.0, 2.0, (E, n, 2))
        if t % 2:  # everyone at the centroid, faster than v_max
            g = P.mean(axis=1, keepdims=True) - P
            a = 1.5 * g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-9)
        P, _, pairs, _, _ = step(P, a)
        assert np.all(np.isfinite(P))
        assert np.all(min_separation(P) >= TWO_R - CONTACT_TOL_M)
        total += int(pairs.sum())
    assert total > E * n


def test_a_jam_at_the_centroid_resolves_without_overlap() -> None:
    """Twenty robots on a tight grid driven at their centroid for 40 steps: they close in
    to a packed cluster, every step collides, and no two ever interpenetrate."""
    rng = np.random.default_rng(7)
    E, n = 4, 20
    P = packed(rng, E, n, gap=0.3)
    spread0 = np.linalg.norm(P - P.mean(axis=1, keepdims=True), axis=-1).max(axis=1)
    falls = 0
    for _ in range(40):
        g = P.mean(axis=1, keepdims=True) - P
        a = 1.5 * W.v_max_mps * g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-9)
        P, _, pairs, f, _ = step(P, a)
        falls += f
        assert np.all(min_separation(P) >= TWO_R - CONTACT_TOL_M)
    assert np.all(pairs > 0)  # still pushing at the end
    spread = np.linalg.norm(P - P.mean(axis=1, keepdims=True), axis=-1).max(axis=1)
    assert np.all(spread < 0.7 * spread0)  # closed in
    assert np.all(spread < 4.0 * TWO_R)  # packed: 20 discs fit within 4 diameters


def test_a_jam_that_does_not_clear_holds_its_robots_still(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(contacts, "CONTACT_SWEEPS", 1)  # too few sweeps for a chain
    P0 = np.array([[[0.0, 0.0], [TWO_R + 0.01, 0.0], [2 * TWO_R + 0.02, 0.0], [5.0, 5.0]]])
    a = np.zeros((1, 4, 2))
    a[0, 0, 0], a[0, 2, 0] = 1.0, -1.0  # squeeze the middle robot from both sides
    P, _, pairs, falls, _ = step(P0, a)
    assert falls > 0
    assert min_separation(P[0]) >= TWO_R - CONTACT_TOL_M
    assert pairs[0] >= 2


# ------------------------------------------------------- actions, speed, travel


def test_non_finite_actions_hold_still() -> None:
    P0 = np.array([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0], [5.0, 0.0]]])
    a = np.array(
        [
            [
                [np.nan, 1.0],
                [1.0, np.inf],
                [-np.inf, 0.0],
                [1e300, 1e300],
                [np.nan, np.nan],
                [0.3, 0.4],
            ]
        ]
    )
    before = a.copy()
    with np.errstate(over="ignore"):  # 1e300: a square that overflows holds still
        P, hits, pairs, _, travel = step(P0, a)
    np.testing.assert_array_equal(P[0, :5], P0[0, :5])
    np.testing.assert_allclose(P[0, 5], P0[0, 5] + [0.03, 0.04], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(travel[0, :5], 0.0)
    np.testing.assert_array_equal(hits, 0)
    np.testing.assert_array_equal(pairs, 0)
    np.testing.assert_array_equal(a, before)  # the caller's array is untouched


def test_speed_is_clamped_to_v_max_direction_kept() -> None:
    P0 = np.array([[[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]]])
    a = np.array([[[30.0, 40.0], [0.3, 0.4], [-W.v_max_mps, 0.0]]], dtype=np.float32)
    P, _, _, _, travel = step(P0, a)
    moved = P[0] - P0[0]
    np.testing.assert_allclose(moved[0], [0.6 * REACH, 0.8 * REACH], rtol=1e-12)
    widened = np.array([0.3, 0.4], np.float32).astype(np.float64)  # float32 taken exactly
    np.testing.assert_allclose(moved[1], widened * W.dt_s, rtol=1e-12)
    np.testing.assert_allclose(moved[2], [-REACH, 0.0], rtol=1e-12)
    np.testing.assert_allclose(travel[0], [REACH, 0.05, REACH], rtol=1e-7)
    assert np.all(np.linalg.norm(moved, axis=-1) <= REACH * (1 + 1e-12))


def test_travel_is_the_summed_displacement_norms() -> None:
    rng = np.random.default_rng(3)
    E, n = 8, 10
    P = packed(rng, E, n, gap=0.05)
    total = np.zeros((E, n))
    travel = np.ones((n, E))  # added to in place, not overwritten
    for _ in range(30):
        a = rng.uniform(-1.5, 1.5, (E, n, 2))
        X1, _, _, _ = move(a, robot_major(P), travel, W)
        P1 = env_major(X1)
        d = P1 - P
        total += np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)
        P = P1
    np.testing.assert_allclose(travel.T - 1.0, total, rtol=1e-12, atol=1e-12)


def test_bad_shapes_are_refused() -> None:
    X0 = np.zeros((2, 3, 4))
    with pytest.raises(ValueError, match="actions must be"):
        move(np.zeros((4, 2, 2)), X0, np.zeros((3, 4)), W)
    with pytest.raises(ValueError, match="travel must be"):
        move(np.zeros((4, 3, 2)), X0, np.zeros((4, 3)), W)
    w = BatchWorld(8, 10, "circle", ObservationSpec("general"), build_obs=False)
    with pytest.raises(ValueError, match="actions must be"):
        w.step(np.zeros((8, 9, 2)))


# ------------------------------------------------------------- in the world


def test_world_step_counts_and_travel_are_the_moves() -> None:
    """The world's collisions, per-robot hits, fallbacks and travel are those of its moves."""
    w = BatchWorld(6, 8, "circle", ObservationSpec("general"), build_obs=False, step_limit=10**6)
    rng = np.random.default_rng(5)
    travel = np.zeros((6, 8))
    collisions = np.zeros(6, dtype=np.int64)
    falls = 0
    for _ in range(50):
        P = w.positions
        g = P.mean(axis=1, keepdims=True) - P
        a = 1.5 * g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-9)
        a += rng.normal(0.0, 0.3, a.shape)
        P1, hits, pairs, f, t = step(P, a)
        res = w.step(a)
        np.testing.assert_array_equal(w.positions, P1)
        np.testing.assert_array_equal(res.collisions, pairs)
        np.testing.assert_array_equal(w.last_robot_collisions, hits)
        travel += t
        collisions += pairs
        falls += f
        d = w.positions - w.prev_positions
        assert np.all(min_separation(w.positions) >= TWO_R - CONTACT_TOL_M)
        np.testing.assert_allclose(t, np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2), rtol=1e-12)
    np.testing.assert_array_equal(w.travel, travel)
    np.testing.assert_array_equal(w.episode_collisions, collisions)
    assert w.contact_fallbacks == falls
    assert collisions.sum() > 0


# ----------------------------------------------------- one source, two builds


def _source_module() -> ModuleType:
    """trainer/world/contacts.py run as Python, whether or not a compiled module shadows it."""
    path = Path(contacts.__file__).with_name("contacts.py")
    spec = importlib.util.spec_from_file_location("contacts_source", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_source_run_as_python_gives_the_compiled_numbers() -> None:
    # the install compiles it; a source that runs as Python here is a broken install
    assert contacts.__file__ is not None and not contacts.__file__.endswith(".py"), (
        "trainer/world/contacts.py is not compiled (scripts/setup.sh builds it)")
    source = _source_module()
    assert source.__file__ is not None and source.__file__.endswith(".py")
    rng = np.random.default_rng(11)
    for t in range(40):
        E, n = int(rng.integers(1, 6)), int(rng.integers(2, 16))
        P = packed(rng, E, n, gap=float(rng.choice([0.0, 0.02, 0.2])))
        a = rng.uniform(-2.0, 2.0, (E, n, 2))
        if t % 2:  # at the centroid: jams
            g = P.mean(axis=1, keepdims=True) - P
            a = 2.0 * g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 1e-9)
        a[rng.random((E, n)) < 0.05] = np.nan
        if t % 5 == 0:
            a = a.astype(np.float32)
        got = step(P, a)
        want = step(P, a, source)
        for x, y in zip(got, want, strict=True):
            np.testing.assert_array_equal(x, y)
