from __future__ import annotations

import numpy as np
import pytest

from runtime.formation import assign_slots_batch, slot_positions
from runtime.observation import (
    ObservationError,
    ObservationSpec,
    frame_velocities,
    general_observation,
    general_row,
    neighbours_from_general,
    observe,
    paper_observation,
)
from runtime.patterns import make_pattern


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


def test_general_row_is_the_builders_row() -> None:
    pos, prev, sp = _world(E=1, n=9)
    full = general_observation(pos, prev, sp, 4)[0]
    L = pos[0].tolist()
    V = frame_velocities(L, prev[0].tolist(), 0.1)
    np.testing.assert_array_equal(np.array(V), (pos[0] - prev[0]) / 0.1)
    for i in range(9):
        row = general_row(i, L, V, (float(sp[0, i, 0]), float(sp[0, i, 1])), 4)
        np.testing.assert_array_equal(row, full[i])


def test_general_batch_rows_are_the_robot_rows_on_ties() -> None:
    """On a lattice (many equal distances) the batch kernel and the robot's row kernel agree."""
    rng = np.random.default_rng(7)
    E, n, k = 6, 9, 6
    pos = rng.integers(0, 3, (E, n, 2)).astype(float) * 0.5
    prev = pos + rng.integers(-1, 2, (E, n, 2)) * 0.1
    sp = pos + rng.normal(0, 1.0, pos.shape)
    full = general_observation(pos, prev, sp, k)
    for e in range(E):
        L = pos[e].tolist()
        V = frame_velocities(L, prev[e].tolist(), 0.1)
        for i in range(n):
            row = general_row(i, L, V, (float(sp[e, i, 0]), float(sp[e, i, 1])), k)
            np.testing.assert_array_equal(row, full[e, i])
