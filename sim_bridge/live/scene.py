"""The Foxglove scene of one step: a disc and a label per robot, the targets, the arena, and
where robots under imperfect sensing believed their peers to be (their latest views).

:func:`scene_update` builds one ``foxglove.SceneUpdate`` as an object (what
``/world/scene`` holds, JSON-encoded); :func:`scene_json` gives the very bytes
``json.dumps`` makes of it, the way the world records every step. At 100 robots
encoding the object cost the world's thread ~30 % of its step (a profile of a
realtime run), time the robots' own processes wait for on 2 shared cores; the
encoder instead fills per-robot JSON templates, cut once from ``json.dumps`` of
the same object with marker values in place of the coordinates and the stamp,
so the structure cannot drift from :func:`scene_update` (tests compare the
bytes).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from typing import Any, Final

import numpy as np

from runtime.world_config import DEFAULT_WORLD, WorldConfig
from sim_bridge.log.layout import SCENE_FRAME

__all__ = ["perceived_id", "scene_json", "scene_update"]

_IDENTITY: Final = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


_IDENTITY: Final = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def _colour(i: int) -> dict[str, float]:
    """A stable, distinct colour per robot id (tab10 cycle)."""
    tab10 = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
             (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
    r, g, b = tab10[i % len(tab10)]
    return {"r": r / 255, "g": g / 255, "b": b / 255, "a": 1.0}


def _entity(stamp: dict[str, int], eid: str, **prims: list[dict[str, Any]]) -> dict[str, Any]:
    ent: dict[str, Any] = {
        "timestamp": stamp, "frame_id": SCENE_FRAME, "id": eid,
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
        "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [],
        "triangles": [], "texts": [], "models": [],
    }
    ent.update(prims)
    return ent


def perceived_id(robot_id: int) -> str:
    """The entity of what robot ``robot_id`` perceived of its peers."""
    return f"perceived/{int(robot_id)}"


def scene_update(
    log_time_ns: int,
    robots: Sequence[tuple[int, float, float]],
    targets: np.ndarray | None,
    removed: Sequence[int] = (),
    arena_m: float | None = None,
    world: WorldConfig = DEFAULT_WORLD,
    *,
    perceived: Sequence[tuple[int, np.ndarray]] = (),
    perceived_removed: Sequence[int] = (),
) -> dict[str, Any]:
    """One ``foxglove.SceneUpdate``: a disc per robot (id = robot id), targets, walls.

    ``perceived``: (robot id, (k, 2) metres) where that robot believed its k peers to be,
    each drawn as a small translucent sphere of its colour, entity :func:`perceived_id`
    (kept until the robot's next view replaces it); ``perceived_removed``: robots whose such
    entity goes."""
    stamp = {"sec": log_time_ns // 1_000_000_000, "nsec": log_time_ns % 1_000_000_000}
    d = 2.0 * world.radius_m
    height = 0.5 * world.radius_m
    entities = []
    for rid, x, y in robots:
        cyl = {"pose": {"position": {"x": x, "y": y, "z": height / 2}, "orientation": _IDENTITY},
               "size": {"x": d, "y": d, "z": height}, "bottom_scale": 1.0, "top_scale": 1.0,
               "color": _colour(rid)}
        label = {"pose": {"position": {"x": x, "y": y, "z": height * 2}, "orientation": _IDENTITY},
                 "billboard": True, "font_size": 12.0, "scale_invariant": True,
                 "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}, "text": str(rid)}
        entities.append(_entity(stamp, str(rid), cylinders=[cyl], texts=[label]))
    if targets is not None and len(targets):
        s = 0.5 * world.radius_m
        grey = {"r": 0.5, "g": 0.5, "b": 0.5, "a": 0.6}
        spheres = [{"pose": {"position": {"x": float(x), "y": float(y), "z": 0.0},
                             "orientation": _IDENTITY},
                    "size": {"x": s, "y": s, "z": s}, "color": grey} for x, y in targets]
        entities.append(_entity(stamp, "targets", spheres=spheres))
    if arena_m is not None:
        a = float(arena_m)
        corners = [{"x": 0.0, "y": 0.0, "z": 0.0}, {"x": a, "y": 0.0, "z": 0.0},
                   {"x": a, "y": a, "z": 0.0}, {"x": 0.0, "y": a, "z": 0.0}]
        loop = {"type": 1, "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                                    "orientation": _IDENTITY},
                "thickness": 0.02, "scale_invariant": False, "points": corners,
                "color": {"r": 0.8, "g": 0.8, "b": 0.8, "a": 1.0}, "colors": [], "indices": []}
        entities.append(_entity(stamp, "arena", lines=[loop]))
    s = 0.6 * world.radius_m
    for rid, peers in perceived:
        colour = {**_colour(rid), "a": 0.35}
        spheres = [{"pose": {"position": {"x": float(x), "y": float(y), "z": 0.0},
                             "orientation": _IDENTITY},
                    "size": {"x": s, "y": s, "z": s}, "color": colour}
                   for x, y in np.asarray(peers, dtype=np.float64).reshape(-1, 2).tolist()]
        entities.append(_entity(stamp, perceived_id(rid), spheres=spheres))
    deletions = [{"timestamp": stamp, "type": 0, "id": str(r)} for r in removed]
    deletions += [{"timestamp": stamp, "type": 0, "id": perceived_id(r)}
                  for r in perceived_removed]
    return {"deletions": deletions, "entities": entities}


# Marker values, never a coordinate or a time: each one's JSON text is cut out of a template.
_SEC, _NSEC = 987_654_321_987_654_321, 876_543_210_876_543_210
_X, _Y = 1.2345678901234567e300, 2.3456789012345678e300
_MARK: Final = {repr(_SEC): "sec", repr(_NSEC): "nsec", repr(_X): "x", repr(_Y): "y"}
_MARK_RE: Final = re.compile("|".join(re.escape(m) for m in _MARK))


def _cut(text: str, want: list[str]) -> list[str]:
    """``text`` cut at its markers: len(want) + 1 fragments around them."""
    found = [_MARK[m] for m in _MARK_RE.findall(text)]
    if found != want:  # the object's layout is not what the encoder fills in
        raise AssertionError(f"scene template markers {found}, expected {want}")
    return _MARK_RE.split(text)


def _dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


class _Templates:
    """The JSON fragments of one world's robot entities (by robot id) and of the targets."""

    def __init__(self, world: WorldConfig) -> None:
        self.world = world
        self._robots: dict[int, list[str]] = {}
        marked = {"sec": _SEC, "nsec": _NSEC}
        one = scene_update(0, [], np.array([[_X, _Y]]), (), None, world)["entities"][0]
        self.sphere = _cut(_dumps(one["spheres"][0]), ["x", "y"])
        before, after = _dumps(_entity(marked, "targets", spheres=[])).split('"spheres":[]')
        self.targets = (_cut(before + '"spheres":[', ["sec", "nsec"]), "]" + after)

    def robot(self, rid: int) -> list[str]:
        t = self._robots.get(rid)
        if t is None:
            ent = scene_update(0, [(rid, _X, _Y)], None, (), None, self.world)["entities"][0]
            ent["timestamp"] = {"sec": _SEC, "nsec": _NSEC}
            t = self._robots[rid] = _cut(_dumps(ent), ["sec", "nsec", "x", "y", "x", "y"])
        return t


_CACHE: dict[WorldConfig, _Templates] = {}


def scene_json(
    log_time_ns: int,
    robots: Sequence[tuple[int, float, float]],
    targets: np.ndarray | None,
    removed: Sequence[int] = (),
    arena_m: float | None = None,
    world: WorldConfig = DEFAULT_WORLD,
    *,
    perceived: Sequence[tuple[int, np.ndarray]] = (),
    perceived_removed: Sequence[int] = (),
) -> bytes:
    """``json.dumps(scene_update(...), separators=(",", ":"), allow_nan=False).encode()``,
    byte for byte, at a fraction of the cost (see the module docstring; the perceived peers,
    drawn only when new views came, take the object's way)."""
    coords = [c for _, x, y in robots for c in (x, y)]
    if targets is not None:
        coords += np.asarray(targets, dtype=np.float64).ravel().tolist()
    if not all(isinstance(c, float) and math.isfinite(c) for c in coords):
        return _dumps(scene_update(log_time_ns, robots, targets, removed, arena_m, world,
                                   perceived=perceived,
                                   perceived_removed=perceived_removed)).encode()
    tpl = _CACHE.get(world)
    if tpl is None:
        tpl = _CACHE[world] = _Templates(world)
    sec, nsec = repr(log_time_ns // 1_000_000_000), repr(log_time_ns % 1_000_000_000)
    out: list[str] = []
    for rid, x, y in robots:
        f = tpl.robot(rid)
        xs, ys = repr(x), repr(y)
        out.append("".join((f[0], sec, f[1], nsec, f[2], xs, f[3], ys, f[4], xs, f[5], ys,
                            f[6])))
    rest = scene_update(log_time_ns, [], None, removed, arena_m, world,  # arena, deletions
                        perceived=perceived, perceived_removed=perceived_removed)
    if targets is not None and len(targets):
        (h, tail), sp = tpl.targets, tpl.sphere
        spheres = ",".join(sp[0] + repr(tx) + sp[1] + repr(ty) + sp[2]
                           for tx, ty in np.asarray(targets, dtype=np.float64).tolist())
        out.append(h[0] + sec + h[1] + nsec + h[2] + spheres + tail)
    out += [_dumps(e) for e in rest["entities"]]
    deletions = _dumps(rest["deletions"])
    return ('{"deletions":' + deletions + ',"entities":[' + ",".join(out) + "]}").encode()
