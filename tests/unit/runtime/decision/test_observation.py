"""The observation builders (runtime/decision/observation.py) and the general row they share
(runtime/core/general_row.py), the general and plan rows held against a reference
written here from the row's documented layout: every other robot sorted by
(squared distance, id) with Python's ``sorted``, the columns filled one by one."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from support.core_source import python_core
from support.rows import reference_rows

from runtime.core.general_row import GeneralRows
from runtime.decision.formation import assign_slots_batch, slot_positions
from runtime.decision.observation import (
    ObservationError,
    ObservationSpec,
    general_observation,
    neighbours_from_general,
    observe,
    paper_observation,
)
from runtime.decision.patterns import make_pattern
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD
REACH = W.v_max_mps * W.dt_s


def _world(E: int = 3, n: int = 8, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    prev = rng.uniform(0, 10, (E, n, 2))
    pos = prev + rng.uniform(-0.1, 0.1, prev.shape)
    C = make_pattern("heart", n)
    slots = assign_slots_batch(pos, C)
    return pos, prev, slot_positions(pos, C, slots)


@pytest.mark.parametrize("k", [1, 3, 7, 12])
def test_general_selected_rows_are_the_full_rows(k: int) -> None:
    pos, prev, sp = _world()
    obs = general_observation(pos, prev, sp, k)
    assert obs.shape == (3, 8, ObservationSpec("general", k_neighbours=k).dim)
    sel = np.array([5, 0, 3])
    some = general_observation(pos, prev, sp[:, sel], k, robots=sel)
    np.testing.assert_array_equal(some, obs[:, sel])
    for e in range(3):
        for i in range(8):  # one robot of one team: the robot's own decision
            one = general_observation(pos[e], prev[e], sp[e, i], k, robots=[i])
            assert one.shape == (1, obs.shape[-1])
            np.testing.assert_array_equal(one[0], obs[e, i])


def test_general_layout() -> None:
    pos, prev, sp = _world(E=1, n=4)
    k = 5
    obs = general_observation(pos, prev, sp, k)[0]
    i = 2
    np.testing.assert_allclose(obs[i, 0:2], sp[0, i] - pos[0, i])
    assert np.linalg.norm(obs[i, 2:4]) <= 1.0 + 1e-12
    np.testing.assert_allclose(obs[i, 4:6], (pos[0, i] - prev[0, i]) / 0.1)
    rel, rvel, mask = neighbours_from_general(obs[i], k)
    assert mask.tolist() == [True, True, True, False, False]  # 3 others, padded to 5
    d = np.linalg.norm(rel[mask], axis=1)
    assert (np.diff(d) >= 0).all()  # nearest first
    dist = np.linalg.norm(pos[0] - pos[0, i], axis=1)
    j = int(np.argmin(np.where(np.arange(4) == i, np.inf, dist)))
    np.testing.assert_allclose(rel[0], pos[0, j] - pos[0, i])
    vel = (pos[0] - prev[0]) / 0.1
    np.testing.assert_allclose(rvel[0], vel[j] - vel[i])
    assert (rel[~mask] == 0).all()


def test_general_ties_broken_by_index() -> None:
    pos = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]])
    obs = general_observation(pos, pos, pos[0], k=2, robots=[0])[0]
    rel, _, _ = neighbours_from_general(obs, 2)
    np.testing.assert_allclose(rel, [[1.0, 0.0], [-1.0, 0.0]])  # robots 1 then 2


def test_paper_observation_order_and_frames() -> None:
    rng = np.random.default_rng(1)
    n = 5
    f = rng.uniform(0, 10, (2, 3, n, 2))
    obs = paper_observation(f)
    assert obs.shape == (2, n, ObservationSpec("paper", n_robots=n).dim)
    e, i = 1, 3
    o = obs[e, i].reshape(3, n - 1, 2)
    d0 = np.linalg.norm(f[e, 0] - f[e, 0, i], axis=1)
    d0[i] = np.inf
    order = np.argsort(d0, kind="stable")[: n - 1]
    for frame in range(3):
        np.testing.assert_allclose(o[frame], f[e, frame, order] - f[e, frame, i])


def test_paper_selected_rows_are_the_full_rows() -> None:
    rng = np.random.default_rng(8)
    for n in (2, 3, 7, 10):
        frames = rng.uniform(0, 2, (2, 3, n, 2))
        full = paper_observation(frames)
        for i in range(n):
            np.testing.assert_array_equal(paper_observation(frames[1], [i])[0], full[1, i])
        np.testing.assert_array_equal(paper_observation(frames, [n - 1, 0]), full[:, [n - 1, 0]])


def test_observe_dispatches_on_the_spec() -> None:
    pos, prev, sp = _world(E=2, n=6)
    frames = np.stack([pos, prev, prev], axis=1)  # (E, 3, n, 2)
    g = ObservationSpec("general", k_neighbours=3)
    np.testing.assert_array_equal(observe(g, frames, sp), general_observation(pos, prev, sp, 3))
    one = observe(g, [pos[1], prev[1], prev[1]], sp[1, 2], [2])
    np.testing.assert_array_equal(one[0], general_observation(pos, prev, sp, 3)[1, 2])
    p = ObservationSpec("paper", n_robots=6)
    np.testing.assert_array_equal(observe(p, frames, None), paper_observation(frames))
    with pytest.raises(ObservationError):
        observe(g, frames, None)


def test_spec_round_trip_and_errors() -> None:
    for spec in (ObservationSpec("paper", n_robots=10), ObservationSpec("general", k_neighbours=4)):
        assert ObservationSpec.from_dict(spec.to_dict()) == spec
    assert ObservationSpec("general").accepts_team(37)
    assert not ObservationSpec("paper", n_robots=10).accepts_team(9)
    with pytest.raises(ObservationError):
        ObservationSpec("lidar")
    with pytest.raises(ObservationError):
        ObservationSpec("paper", n_robots=1)
    with pytest.raises(ObservationError):
        ObservationSpec.from_dict({"version": 1})



# ------------------------------------------------- the general row against a reference


def assert_rows(got: Any, want: Any) -> None:
    """Equal, but for the step columns 2:4, which divide by a norm or a pace that may be
    rounded differently in the last bit."""
    np.testing.assert_array_equal(got[..., :2], want[..., :2])
    np.testing.assert_array_equal(got[..., 4:], want[..., 4:])
    np.testing.assert_allclose(got[..., 2:4], want[..., 2:4], rtol=1e-14, atol=0)


def teams(rng: np.random.Generator, E: int, n: int, lattice: bool) -> tuple[Any, Any, Any]:
    """E teams: (positions, previous positions, slots); a lattice has exact distance
    ties and coincident robots, and some slots are within one step."""
    if lattice:
        pos = rng.integers(0, 4, (E, n, 2)) * 0.25
        prev = pos - rng.integers(-1, 2, (E, n, 2)) * 0.05
    else:
        pos = rng.uniform(0.0, 4.0, (E, n, 2))
        prev = pos - rng.normal(size=(E, n, 2)) * 0.05
    slots = pos + rng.normal(size=(E, n, 2)) * rng.choice([0.02, 1.0], (E, n, 1))
    return pos, prev, slots


@pytest.mark.parametrize("lattice", [False, True])
@pytest.mark.parametrize("n", [1, 2, 5, 9, 25])
def test_general_and_plan_rows_are_the_reference(n: int, lattice: bool) -> None:
    rng = np.random.default_rng(n + 100 * lattice)
    E = 3
    pos, prev, slots = teams(rng, E, n, lattice)
    K = np.array([1.0, 3.0, 17.5])  # the plan's steps left per team
    for k in sorted({1, 3, n + 2}):
        general = general_observation(pos, prev, slots, k, W)
        plan = general_observation(pos, prev, slots, k, W, steps_left=K)
        assert general.dtype == plan.dtype == np.float64
        assert general.shape == plan.shape == (E, n, 6 + 5 * k)
        for e in range(E):
            assert_rows(general[e], reference_rows(pos[e], prev[e], slots[e], k))
            assert_rows(plan[e], reference_rows(pos[e], prev[e], slots[e], k, W, K[e]))
        # float32: the float64 rows, rounded once
        for steps_left, rows in ((None, general), (K, plan)):
            r32 = general_observation(pos, prev, slots, k, W, steps_left=steps_left,
                                      dtype=np.float32)
            assert r32.dtype == np.float32
            np.testing.assert_array_equal(r32, rows.astype(np.float32))


def test_a_robot_alone_has_only_zero_padding() -> None:
    pos, prev, slot = np.array([[1.0, 2.0]]), np.array([[0.95, 2.0]]), np.array([[1.3, 1.6]])
    row = general_observation(pos, prev, slot, 3, W)[0]
    assert row.shape == (6 + 5 * 3,)
    np.testing.assert_allclose(row[:6], [0.3, -0.4, 0.6, -0.8, 0.5, 0.0], rtol=0, atol=1e-12)
    assert (row[6:] == 0.0).all()


def test_fewer_others_than_k_are_padded_with_zeros() -> None:
    pos = np.array([[0.0, 0.0], [0.0, 0.5], [0.3, 0.0]])
    prev = pos - [[0.0, 0.0], [0.01, 0.0], [0.0, -0.02]]
    row = general_observation(pos, prev, pos[[0]], 5, W, robots=[0])[0]
    rel, rvel, mask = neighbours_from_general(row, 5)
    assert mask.tolist() == [True, True, False, False, False]
    np.testing.assert_array_equal(rel[:2], [[0.3, 0.0], [0.0, 0.5]])  # nearest first
    np.testing.assert_allclose(rvel[:2], [[0.0, -0.2], [0.1, 0.0]], rtol=0, atol=1e-12)
    assert (row[6 + 10 :] == 0.0).all()


def test_exact_distance_ties_go_by_id() -> None:
    # robots 1-4 all 0.5 m from robot 0, 5 farther; k = 3 keeps 1, 2, 3 in id order
    pos = np.array([[0.0, 0.0], [0.0, -0.5], [0.5, 0.0], [-0.5, 0.0], [0.0, 0.5], [0.6, 0.6]])
    rel, _, _ = neighbours_from_general(general_observation(pos, pos, pos, 3, W)[0], 3)
    np.testing.assert_array_equal(rel, [[0.0, -0.5], [0.5, 0.0], [-0.5, 0.0]])
    rel, _, _ = neighbours_from_general(general_observation(pos, pos, pos, 5, W)[4], 5)
    # from robot 4: 0 at 0.5, 5 at (0.6, 0.1), 2 and 3 tied at sqrt(0.5), then 1 at 1
    np.testing.assert_allclose(rel, [[0.0, -0.5], [0.6, 0.1], [0.5, -0.5], [-0.5, -0.5],
                                     [0.0, -1.0]], rtol=0, atol=1e-15)


def test_the_step_columns_by_hand() -> None:
    pos = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    slots = pos + np.array([[0.3, -0.4], [0.03, 0.04], [0.0, 0.0]])
    general = general_observation(pos, pos, slots, 1, W)
    # farther than one step: unit length; within one step: slot vector / (v_max dt); on it: 0
    np.testing.assert_allclose(general[:, 2:4], [[0.6, -0.8], [0.3, 0.4], [0.0, 0.0]],
                               rtol=1e-12)
    plan = general_observation(pos, pos, slots, 1, W, steps_left=4.0)
    # the plan's pace: slot vector / (K v_max dt), K = 4 steps left
    np.testing.assert_allclose(plan[:, 2:4], [[0.75, -1.0], [0.075, 0.1], [0.0, 0.0]],
                               rtol=1e-12)
    np.testing.assert_array_equal(plan[:, :2], general[:, :2])
    np.testing.assert_array_equal(plan[:, 4:], general[:, 4:])


# ------------------------------------------------------------------- GeneralRows


def builder_inputs(rng: np.random.Generator, E: int, n: int) -> tuple[Any, Any, Any, Any]:
    pos, prev, slots = teams(rng, E, n, lattice=bool(n % 2))
    vel = np.ascontiguousarray((pos - prev) / W.dt_s)
    pace = np.where(np.arange(E) % 2 == 1, (np.arange(E) + 2.0) * REACH, 0.0)
    return np.ascontiguousarray(pos, dtype=np.float64), vel, slots, pace


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_one_robots_row_is_its_row_of_the_teams(dtype: Any) -> None:
    rng = np.random.default_rng(5)
    for E, n, k in ((1, 1, 2), (2, 6, 3), (4, 13, 6), (3, 5, 9)):
        pos, vel, slots, pace = builder_inputs(rng, E, n)
        rows = GeneralRows(k, REACH)
        full = np.full((E, n, rows.dim), np.nan, dtype=dtype)
        rows.teams(pos, vel, slots, pace, full)
        one = np.full((1, 1, rows.dim), np.nan, dtype=dtype)
        one_row = rows.robot if dtype == np.float32 else rows.robot_f64
        for e in range(E):
            for i in range(n):
                one_row(e, i, pos, vel, *slots[e, i], pace[e], one)
                np.testing.assert_array_equal(one[0, 0], full[e, i])
            want = reference_rows(pos[e], pos[e] - vel[e] * W.dt_s, slots[e], k, W,
                                  pace[e] / REACH if pace[e] > 0 else None)
            np.testing.assert_allclose(full[e], want, rtol=1e-6 if dtype == np.float32 else 1e-12,
                                       atol=1e-12)


def test_uncompiled_rows_are_the_compiled_rows() -> None:
    """The same source run as Python gives the very same rows (both dtypes, both calls)."""
    py = python_core().general_row
    rng = np.random.default_rng(9)
    for E, n, k in ((1, 1, 1), (2, 7, 3), (3, 12, 6), (2, 4, 8)):
        pos, vel, slots, pace = builder_inputs(rng, E, n)
        for dtype in (np.float64, np.float32):
            got = np.full((E, n, 6 + 5 * k), np.nan, dtype=dtype)
            want = got.copy()
            py.GeneralRows(k, REACH).teams(pos, vel, slots, pace, got)
            GeneralRows(k, REACH).teams(pos, vel, slots, pace, want)
            np.testing.assert_array_equal(got, want)
            one_py, one_c = got[:1, :1].copy(), want[:1, :1].copy()
            i = n - 1
            sx, sy, p = *slots[E - 1, i], pace[E - 1]
            name = "robot" if dtype == np.float32 else "robot_f64"
            getattr(py.GeneralRows(k, REACH), name)(E - 1, i, pos, vel, sx, sy, p, one_py)
            getattr(GeneralRows(k, REACH), name)(E - 1, i, pos, vel, sx, sy, p, one_c)
            np.testing.assert_array_equal(one_py, one_c)
            np.testing.assert_array_equal(one_c[0, 0], want[E - 1, i])


def test_the_builder_refuses_what_does_not_fit() -> None:
    pos = np.zeros((2, 3, 2))
    with pytest.raises(ValueError):
        GeneralRows(-1, REACH)
    rows = GeneralRows(2, REACH)
    assert rows.dim == 16
    for e, i, width, vel in ((2, 0, 16, pos), (0, 3, 16, pos), (0, -1, 16, pos),
                             (0, 0, 15, pos), (0, 0, 16, pos[:1])):
        with pytest.raises(ValueError):
            rows.robot_f64(e, i, pos, vel, 0.0, 0.0, 0.0, np.zeros((1, 1, width)))
    with pytest.raises(ValueError):
        rows.teams(pos, pos, pos, np.zeros(1), np.zeros((2, 3, 16)))  # one pace for two teams
    with pytest.raises(ValueError):
        rows.teams(pos, pos, pos, np.zeros(2), np.zeros((2, 3, 11)))
