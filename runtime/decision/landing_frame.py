"""The frame a landing under noise goes in: the team's centroid as one robot sees it.

Under noise every robot's plan lands in its team's centroid frame, averaged over the landing's
steps (:class:`runtime.decision.settle.Lander`, where the measurements behind each choice are
kept). The pieces every robot and the training world compute alike: the team as a robot sees it
raw (:func:`seen_team`), its centroid (:func:`seen_centroid`; where the robot sees only part of
its team, the one its peers in view show, :func:`view_centroid`), the running average
(:func:`smooth_centroid`), the frame of the team's core (:func:`core_frame`), the assignment of
one moment (:func:`shared_slots`) and the targets in a frame (:func:`centroid_targets`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from runtime.core.plan_frame import steps_left
from runtime.decision.formation import assign_slots_batch, centred
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["CORE_M", "centroid_targets", "core_frame", "seen_centroid", "seen_team",
           "shared_slots", "smooth_centroid", "view_centroid"]

CORE_M = 0.2
"""A robot farther than this (m, two full steps) from the median robot's offset when a landing
outlasts the plan's kept frame is held off its slot and left out of the team's core
(:func:`core_frame`)."""


def smooth_centroid(prev: Array | None, seen: Array, gain: float, gate: Any = math.inf
                    ) -> Array:
    """``prev + g (seen - prev)`` (``seen`` where there is no ``prev``), (..., 2) m, where g
    is ``gain`` for a seen centroid well within ``gate`` (m) of ``prev`` and grows to 1 as it
    comes to it: ``gain + (1 - gain) min(1, (|seen - prev| / gate)^2)``; 1 where ``gate`` is
    0 (no noise)."""
    now = np.asarray(seen, dtype=np.float64)
    if prev is None:
        return now.copy()
    r = now - prev
    g_m = np.asarray(gate, dtype=np.float64)
    far = np.hypot(r[..., 0], r[..., 1]) / np.where(g_m > 0.0, g_m, 1.0)
    off = np.where(g_m > 0.0, np.minimum(1.0, far ** 2), 1.0)  # no noise: at once
    g = gain + (1.0 - gain) * off
    out: Array = prev + np.asarray(g)[..., None] * r
    return out


def seen_team(pos: Array, me: Any, ref: Array | None) -> Array:
    """The team (..., n, 2) m as robot ``me`` (an index, or (...,) of them) sees it raw, every
    robot at the age of its view: each peer's last sensed position (``ref[..., 0:2]``, the
    guard's references of :meth:`runtime.decision.local.Perception.perceive`: never lagging
    as the tracker's smoothing does, with noise that averages out over a landing) and the
    robot itself where it stood when it saw them (the mean of ``ref[..., 2:4]`` over its
    peers): on late views the team of that moment, the same for every robot, where the
    robot's own pose of now would pull each robot's view its own way. ``pos`` (..., n, 2)
    where a view is missing (``ref`` None: ``pos`` alone; no peer's view: the robot's own
    pose now)."""
    p = np.asarray(pos, dtype=np.float64)
    if ref is None:
        return p.copy()
    r = np.asarray(ref, dtype=np.float64)
    raw = np.array(r[..., 0:2])
    bad = ~np.isfinite(raw).all(axis=-1)
    raw[bad] = p[bad]
    idx = np.asarray(me)
    n = p.shape[-2]
    peer = np.arange(n) != (idx[..., None] if idx.ndim else int(idx))  # (..., n)
    then = r[..., 2:4]
    ok = np.isfinite(then).all(axis=-1) & peer
    count = ok.sum(axis=-1)
    own_then = np.where(ok[..., None], then, 0.0).sum(axis=-2) / np.maximum(count, 1)[..., None]
    if idx.ndim == 0:
        own_now = p[..., int(idx), :]
        raw[..., int(idx), :] = np.where((count > 0)[..., None], own_then, own_now)
    else:
        rows = np.arange(idx.size)
        flat = raw.reshape(-1, *raw.shape[-2:])
        own_now = p.reshape(-1, *p.shape[-2:])[rows, idx.reshape(-1)]
        flat[rows, idx.reshape(-1)] = np.where((count.reshape(-1) > 0)[:, None],
                                               own_then.reshape(-1, 2), own_now)
    return raw


def seen_centroid(pos: Array, me: Any, ref: Array | None, points: Array | None = None,
                  in_view: BoolArray | None = None) -> Array:
    """The team's centroid (..., 2) m as robot ``me`` sees it raw: the mean of
    :func:`seen_team`, on late views the team's centroid of one moment; with ``in_view``,
    the one the peers in view show at their slot points ``points`` (:func:`view_centroid`)."""
    team = seen_team(pos, me, ref)
    if in_view is None or points is None:
        out: Array = team.mean(axis=-2)
        return out
    return view_centroid(team, points, in_view)


def view_centroid(team: Array, points: Array, in_view: BoolArray | None) -> Array:
    """The team's centroid (..., 2) m as the robots in view show it: the mean over them of
    each one's position less its slot point (``points`` (..., n, 2), robot j's, centred),
    the frame :func:`centroid_targets` lands in; with every robot in view (or ``in_view``
    None) the team's centroid. A robot that sees only its nearest peers and took the others
    where its own plan put them (:meth:`runtime.decision.local.Perception.perceive`: along
    the plan, out of view) would anchor its frame to its own guess: 8 robots under the
    realistic preset seeing their 4 nearest landed 2-3 cm off the pattern, each in its own
    frame (docs/conditions.md, "Small teams that see few of their peers land in one frame")."""
    t = np.asarray(team, dtype=np.float64)
    if in_view is None:
        out: Array = t.mean(axis=-2)
        return out
    w = np.asarray(in_view, dtype=np.float64)[..., None]
    off = t - centred(np.asarray(points, dtype=np.float64))
    out = (w * off).sum(axis=-2) / np.maximum(w.sum(axis=-2), 1.0)
    return out


def core_frame(team: Array, points: Array, core_m: float) -> Array:
    """The frame (..., 2) m, as a centroid for :func:`centroid_targets`, of the team's core:
    each robot's position less its slot point (``points`` (..., n, 2), centred), averaged over
    the robots within ``core_m`` of the median robot's (per axis the median). With every robot
    in the core it is the centroid frame, which a team landing in it does not move; a robot
    held farther off its slot is left out, where the centroid frame moves by its share of the
    way it is off, every step, and the team walks after it. A team with no robot that near the
    median's (split in two groups apart) is in the median's frame."""
    off = np.asarray(team, dtype=np.float64) - centred(points)
    median = np.median(off, axis=-2, keepdims=True)
    away = off - median
    core = (np.hypot(away[..., 0], away[..., 1]) <= core_m)[..., None]
    count = core.sum(axis=-2)
    mean = np.where(core, off, 0.0).sum(axis=-2) / np.maximum(count, 1)
    out: Array = np.where(count > 0, mean, median[..., 0, :])  # a team in two: the median
    return out


def shared_slots(team: Array, pattern: Array) -> IntArray:
    """The assignment (..., n) of the team (..., n, 2) as one moment shows it
    (:func:`seen_team`) to ``pattern`` (n, 2) or (..., n, 2), solved cold
    (:func:`runtime.decision.formation.assign_slots_batch`): on exact views every robot makes
    the same, where the hysteresis each robot keeps along its own views may hold two robots
    to each other's slots."""
    t = np.asarray(team, dtype=np.float64)
    flat = t.reshape(-1, *t.shape[-2:])
    slots: IntArray = assign_slots_batch(
        flat, np.broadcast_to(np.asarray(pattern, dtype=np.float64), t.shape).reshape(flat.shape)
    ).reshape(t.shape[:-1])
    return slots


def centroid_targets(pos: Array, points: Array, centroid: Array,
                     world: WorldConfig = DEFAULT_WORLD) -> tuple[Array, Array]:
    """The landing plan in the frame of ``centroid``: every robot's target, the pattern's
    points ``points`` (..., n, 2) (robot j's slot point, any translation) centred on
    ``centroid`` (..., 2), and the steps left K (...,), those of the farthest robot at
    v_max (at least 1), as :func:`runtime.decision.rules.plan_targets` counts them."""
    p = np.asarray(points, dtype=np.float64)
    target: Array = p - p.mean(axis=-2, keepdims=True) + np.asarray(centroid)[..., None, :]
    d = target - np.asarray(pos, dtype=np.float64)
    far = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2).max(axis=-1)
    k: Array = steps_left(far, world.v_max_mps * world.dt_s)
    return target, k
