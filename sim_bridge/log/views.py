"""What the robots perceived, beside the truth: the views of a log and their estimation error.

A robot under imperfect sensing publishes now and then the team as it perceived it for one
decision (:class:`runtime.wire.messages.View`, ``K/robot/<id>/view``). :func:`decode_views`
turns a log's view payloads into flat columns (:class:`Views`); :func:`estimation_error`
measures each peer's perceived position against the world's pose of that peer at the very
step the view was used for (the log's poses, :class:`sim_bridge.log.columns.Frames`):

=====================  ==============================================================
figure                 computed as
=====================  ==============================================================
error of one peer      ||perceived position - the world's pose of the same step|| (m);
                       the robot's own row is left out (its own pose, not an
                       estimate), as is a peer without a pose of that step
mean, p95, max         over every peer error of one robot's views, and of all views
views                  views of the robot (all robots) with at least one peer measured
=====================  ==============================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from runtime.types import Array, IntArray
from runtime.wire.messages import MessageError, View, decode_view
from sim_bridge.log import schemas as pb
from sim_bridge.log.columns import Frames

__all__ = ["ErrorStats", "Estimation", "Views", "decode_views", "estimation_error", "peer_errors",
           "select"]

_STEP_MAX = (1 << 63) - 1


@dataclass
class Views:
    """Every view of a log, flat: view k's team members are rows ``start[k]:start[k+1]``.

    ``robot_id`` (V,) the robot that perceived, ``step`` (V,) the step of its decision;
    ``peer`` (R,) each member's id, ``xy`` (R, 2) its perceived position (m), ``age`` (R,)
    the age of its last sensed update (steps). Views in file order.
    """

    robot_id: IntArray
    step: IntArray
    start: IntArray
    peer: IntArray
    xy: Array
    age: IntArray

    @staticmethod
    def empty() -> Views:
        z = np.zeros(0, np.int64)
        return Views(z, z.copy(), np.zeros(1, np.int64), z.copy(), np.zeros((0, 2)), z.copy())

    def __len__(self) -> int:
        return len(self.robot_id)

    def sender(self) -> IntArray:
        """(R,) the robot that perceived each row."""
        return np.repeat(self.robot_id, np.diff(self.start))

    def row_step(self) -> IntArray:
        """(R,) the step of each row's view."""
        return np.repeat(self.step, np.diff(self.start))


def _view(raw: bytes, wire: bool) -> View:
    if wire:
        return decode_view(raw)
    try:
        m = pb.parse(pb.ROBOT_VIEW, raw)
    except ValueError as e:
        raise MessageError(str(e)) from None
    return pb.view_of(m)


def decode_views(raw: list[bytes], wire: list[bool], key_rid: list[int]) -> tuple[Views, int]:
    """The views of payloads ``raw`` (``wire``: the old wire layout, else protobuf), each
    recorded on the key of robot ``key_rid``. Returns (the good views, how many were
    malformed: not decodable, or of another robot than their key's)."""
    good: list[View] = []
    bad = 0
    for b, w, rid in zip(raw, wire, key_rid, strict=True):
        try:
            v = _view(b, w)
        except MessageError:
            bad += 1
            continue
        if v.robot_id != rid:
            bad += 1
            continue
        good.append(v)
    if not good:
        return Views.empty(), bad
    sizes = np.array([len(v.ids) for v in good], np.int64)
    return Views(
        robot_id=np.array([v.robot_id for v in good], np.int64),
        step=np.array([min(v.step, _STEP_MAX) for v in good], np.int64),  # past it: no step
        start=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        peer=np.concatenate([v.ids for v in good]).astype(np.int64),
        xy=np.concatenate([v.xy for v in good]).reshape(-1, 2),
        age=np.concatenate([v.age_steps for v in good]).astype(np.int64),
    ), bad


def select(v: Views, keep: np.ndarray) -> Views:
    """The views ``keep`` (V,) bool says."""
    if keep.all():
        return v
    rows = np.repeat(keep, np.diff(v.start))
    sizes = np.diff(v.start)[keep]
    return Views(v.robot_id[keep], v.step[keep],
                 np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
                 v.peer[rows], v.xy[rows], v.age[rows])


@dataclass
class ErrorStats:
    """Estimation error of a set of peer positions (metres)."""

    mean_m: float
    p95_m: float
    max_m: float
    peers: int
    """peer positions measured"""
    views: int
    """views with at least one peer measured"""

    @staticmethod
    def of(err: Array, views: int) -> ErrorStats:
        return ErrorStats(round(float(err.mean()), 6), round(float(np.percentile(err, 95)), 6),
                          round(float(err.max()), 6), len(err), int(views))


@dataclass
class Estimation:
    """The estimation error of a log's views: all robots together, and per robot."""

    overall: ErrorStats
    per_robot: dict[int, ErrorStats]
    views: int
    """every view of the log (measured or not)"""

    def to_dict(self) -> dict[str, Any]:
        return {"views": self.views, "overall": vars(self.overall),
                "per_robot": {str(r): vars(s) for r, s in sorted(self.per_robot.items())}}


def peer_errors(views: Views, frames: Frames) -> tuple[Array, IntArray]:
    """(error (m) of every peer row with a pose of its view's step, the index of its view)."""
    if not len(views) or not len(frames.steps):
        return np.zeros(0), np.zeros(0, np.int64)
    which = np.repeat(np.arange(len(views)), np.diff(views.start))
    step = views.step[which]
    srow = np.searchsorted(frames.steps, step)
    scol = np.searchsorted(frames.ids, views.peer)
    srow_c = np.minimum(srow, len(frames.steps) - 1)
    scol_c = np.minimum(scol, len(frames.ids) - 1)
    ok = ((frames.steps[srow_c] == step) & (frames.ids[scol_c] == views.peer)
          & (views.peer != views.robot_id[which]))
    ok[ok] = frames.present[srow_c[ok], scol_c[ok]]
    truth = frames.xy[srow_c[ok], scol_c[ok]]
    err = np.hypot(*(views.xy[ok] - truth).T)
    return err, which[ok]


def estimation_error(views: Views, frames: Frames) -> Estimation | None:
    """The estimation error of ``views`` against the poses ``frames``; None without a view
    or without any peer measured."""
    err, which = peer_errors(views, frames)
    if not len(err):
        return None
    sender = views.robot_id[which]
    per = {int(r): ErrorStats.of(err[sender == r], len(np.unique(which[sender == r])))
           for r in np.unique(sender).tolist()}
    return Estimation(ErrorStats.of(err, len(np.unique(which))), per, len(views))
