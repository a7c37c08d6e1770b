"""The world's scene encoder writes exactly the bytes ``json.dumps`` makes of the scene."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from runtime.world_config import DEFAULT_WORLD
from sim_bridge.live.scene import scene_json, scene_update


def _dumps(update: dict) -> bytes:
    return json.dumps(update, separators=(",", ":"), allow_nan=False).encode()


@pytest.mark.parametrize("n", [0, 1, 7, 100])
def test_scene_json_is_json_dumps_of_scene_update(n: int) -> None:
    rng = np.random.default_rng(n)
    small = replace(DEFAULT_WORLD, radius_m=0.05)
    for trial in range(12):
        ids = rng.permutation(300)[:n].tolist()
        xy = (rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-3, 4)).tolist()
        robots = [(rid, x, y) for rid, (x, y) in zip(ids, xy, strict=True)]
        targets = (None, np.zeros((0, 2)), rng.normal(size=(max(n, 1), 2)))[trial % 3]
        removed = () if trial % 2 else tuple(rng.integers(0, 500, 3).tolist())
        arena = None if trial % 4 == 1 else float(rng.uniform(1, 50))
        world = small if trial % 5 == 4 else DEFAULT_WORLD
        t_ns = int(rng.integers(0, 2**62))
        want = _dumps(scene_update(t_ns, robots, targets, removed, arena, world))
        assert scene_json(t_ns, robots, targets, removed, arena, world) == want


def test_non_finite_or_non_float_coordinates_are_what_json_makes_of_them() -> None:
    with pytest.raises(ValueError):  # allow_nan=False, as the object's encoding
        scene_json(5, [(0, float("nan"), 1.0)], None)
    robots = [(3, 1, 2.5)]  # an int coordinate: json writes it as an int
    assert scene_json(7, robots, None) == _dumps(scene_update(7, robots, None))


def test_perceived_peers_are_translucent_spheres_of_the_robot_and_go_with_it() -> None:
    robots = [(0, 1.0, 2.0), (4, 3.0, 1.5)]
    perceived = [(4, np.array([[1.02, 1.97], [5.0, 5.5]])), (0, np.zeros((0, 2)))]
    update = scene_update(11, robots, None, (2,), 10.0, perceived=perceived,
                          perceived_removed=(2, 6))
    assert scene_json(11, robots, None, (2,), 10.0, perceived=perceived,
                      perceived_removed=(2, 6)) == _dumps(update)
    ents = {e["id"]: e for e in update["entities"]}
    mine = ents["perceived/4"]["spheres"]
    assert [(s["pose"]["position"]["x"], s["pose"]["position"]["y"]) for s in mine] == [
        (1.02, 1.97), (5.0, 5.5)]
    assert all(s["color"]["a"] < 1.0 for s in mine)
    assert mine[0]["color"]["r"] == ents["4"]["cylinders"][0]["color"]["r"]
    assert ents["perceived/0"]["spheres"] == []
    assert [d["id"] for d in update["deletions"]] == ["2", "perceived/2", "perceived/6"]
    plain = scene_update(11, robots, None, (2,), 10.0)  # without views: the scene as before
    assert not any(e["id"].startswith("perceived/") for e in plain["entities"])
