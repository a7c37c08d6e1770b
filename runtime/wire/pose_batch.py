"""The world's poses of one step in ONE message: :class:`PoseBatch`, encode beside decode.

Part of the wire messages of :mod:`runtime.wire.messages` (which re-exports it and dispatches
on its tag); it lives in its own file only to keep each file short. Layout, little-endian,
derived from the field tables :data:`~runtime.wire.fields.POSES_HEAD` and
:data:`~runtime.wire.fields.POSES_ROW`::

    <BB Q d I>        tag (Tag.POSES), version, step, time_s, n          (22 bytes)
    n x <I d d d d>   robot_id, x, y, vx, vy; ids strictly ascending     (36 bytes each)

One message per step instead of one per robot: a robot receives O(1) messages a step
whatever the team size (a per-robot :class:`~runtime.wire.messages.Pose` per robot made it
N messages per robot, N^2 deliveries per step). The decoder bounds the count
(:data:`MAX_POSES_ROBOTS`) and checks it against the bytes really there before reading
anything, then the values (finite floats, no robot twice).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from runtime.types import Array
from runtime.wire.codec import (
    U32,
    U64,
    VERSION,
    Buffer,
    MessageError,
    Reader,
    Tag,
    as_view,
    check_header,
    finite,
    uint,
)
from runtime.wire.fields import MAX_POSES_ROBOTS, POSES_HEAD, POSES_ROW

__all__ = [
    "MAX_POSES_ROBOTS",
    "POSES_ROW_DTYPE",
    "PoseBatch",
    "decode_poses",
    "decode_positions",
    "encode_poses",
]

_HEAD: Final = POSES_HEAD.wire_struct()
POSES_ROW_DTYPE: Final = POSES_ROW.wire_dtype()
"""One robot's row of a payload (36 bytes, packed)."""
_ROW: Final = POSES_ROW_DTYPE.itemsize
_ID_DTYPE: Final = POSES_ROW_DTYPE["robot_id"]
_AT: Final = {name: at for name, (_, at, *_) in (POSES_ROW_DTYPE.fields or {}).items()}
_XYV: Final = _AT["x"]  # x, y, vx, vy: four float64 from this offset
assert POSES_ROW.names() == ("robot_id", "x", "y", "vx", "vy") and _AT["robot_id"] == 0
assert [_AT[c] - _XYV for c in ("x", "y", "vx", "vy")] == [0, 8, 16, 24]


def _ascending(ids: npt.NDArray[np.integer]) -> bool:
    return ids.shape[0] < 2 or bool((ids[1:] > ids[:-1]).all())


@dataclass(frozen=True, slots=True, eq=False)
class PoseBatch:
    """World -> robots: where every live robot is at ``step`` (``time_s`` = step x dt).

    ``robot_ids`` (n,) uint32, strictly ascending: the live robots (a per-robot pose's
    ``n_live`` is n). ``xy`` and ``v`` (n, 2) float64: positions (m) and velocities over
    the last step (m/s), rows in ``robot_ids`` order. Read-only arrays.
    """

    step: int
    time_s: float
    robot_ids: npt.NDArray[np.uint32]
    xy: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]

    def __post_init__(self) -> None:
        try:
            ids = np.array(self.robot_ids, dtype=np.int64).reshape(-1)
            xy = np.array(self.xy, dtype=np.float64).reshape(-1, 2)
            v = np.array(self.v, dtype=np.float64).reshape(-1, 2)
        except (TypeError, ValueError) as e:
            raise MessageError(f"poses: (n,) ids and (n, 2) xy and v expected: {e}") from None
        n = ids.shape[0]
        if xy.shape != (n, 2) or v.shape != (n, 2):
            raise MessageError(f"poses: xy and v must be ({n}, 2), got {xy.shape}, {v.shape}")
        if n and (ids.min() < 0 or ids.max() > U32):
            raise MessageError(f"poses.robot_ids must be in [0, {U32}]")
        u = ids.astype(np.uint32)
        for name, a in (("robot_ids", u), ("xy", xy), ("v", v)):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PoseBatch):
            return NotImplemented
        return (self.step == other.step and self.time_s == other.time_s
                and np.array_equal(self.robot_ids, other.robot_ids)
                and np.array_equal(self.xy, other.xy) and np.array_equal(self.v, other.v))

    __hash__ = None  # type: ignore[assignment]


def encode_poses(msg: PoseBatch) -> bytes:
    """Encode a :class:`PoseBatch`: 22 bytes, then 36 bytes per robot."""
    w = "poses"
    ids = msg.robot_ids
    n = ids.shape[0]
    if n > MAX_POSES_ROBOTS:
        raise MessageError(f"poses carries {n} robots, at most {MAX_POSES_ROBOTS}")
    if not _ascending(ids):
        raise MessageError("poses.robot_ids must be strictly ascending")
    if not (np.isfinite(msg.xy).all() and np.isfinite(msg.v).all()):
        raise MessageError("poses: positions and velocities must all be finite")
    try:
        head = _HEAD.pack(Tag.POSES, VERSION, uint(w, "step", msg.step, U64),
                          finite(w, "time_s", msg.time_s), n)
    except (struct.error, TypeError) as e:
        raise MessageError(f"cannot encode poses: {e}") from None
    rows = np.empty(n, POSES_ROW_DTYPE)
    rows["robot_id"] = ids
    rows["x"], rows["y"] = msg.xy[:, 0], msg.xy[:, 1]
    rows["vx"], rows["vy"] = msg.v[:, 0], msg.v[:, 1]
    return head + rows.tobytes()


_new: Final = object.__new__
_set: Final = object.__setattr__


def _rows(payload: Buffer) -> tuple[int, float, int, memoryview]:
    """The fixed part of a poses payload, checked, and a view of its n rows."""
    w = "poses"
    view = as_view(payload, w)
    check_header(view, Tag.POSES)
    r = Reader(view, w, 0)
    _, _, step, t, n = r.unpack(_HEAD, "the fixed part")
    finite(w, "time_s", t)
    if n > MAX_POSES_ROBOTS:
        raise MessageError(f"poses claims {n} robots, at most {MAX_POSES_ROBOTS}")
    raw = r.take(_ROW * n, "rows")
    r.finish()
    return step, t, n, raw


def decode_poses(payload: Buffer) -> PoseBatch:
    """Decode a payload written by :func:`encode_poses` (size, then values, then ids)."""
    step, t, n, raw = _rows(payload)
    # two strided views of the rows, copied once each (no per-field passes)
    if n:
        ids = np.ndarray((n,), _ID_DTYPE, raw, 0, (_ROW,)).copy()
        xyv = np.ndarray((n, 4), "<f8", raw, _XYV, (_ROW, 8)).copy()
    else:  # no rows: nothing to view (an offset into an empty buffer is refused)
        ids, xyv = np.zeros(0, np.uint32), np.zeros((0, 4))
    if not np.isfinite(xyv).all():
        raise MessageError("poses: positions and velocities must all be finite")
    if not _ascending(ids):
        raise MessageError("poses.robot_ids must be strictly ascending")
    xy, v = xyv[:, :2], xyv[:, 2:]
    for a in (ids, xy, v):
        a.setflags(write=False)
    out: PoseBatch = _new(PoseBatch)  # fresh, checked arrays: no __post_init__ copies
    _set(out, "step", step)
    _set(out, "time_s", t)
    _set(out, "robot_ids", ids)
    _set(out, "xy", xy)
    _set(out, "v", v)
    return out


def decode_positions(payload: Buffer, max_abs_m: float) -> tuple[int, list[int], Array]:
    """What a robot reads of a :class:`PoseBatch`: (step, robot ids, positions (n, 2) m).

    The checks of :func:`decode_poses` (sizes, every value finite, ids strictly
    ascending) plus a bound on the coordinates (``|x|, |y| <= max_abs_m``), with
    about a third of its numpy calls: the velocities are checked, not copied,
    and the positions are a read-only view of the payload (copy them to keep
    them past it). A robot decodes one of these a step, in a process that shares
    its cores with a hundred others: every call it saves is a cold one.
    """
    step, _, n, raw = _rows(payload)
    if not n:
        return step, [], np.zeros((0, 2))
    xyv = np.ndarray((n, 4), "<f8", raw, _XYV, (_ROW, 8))
    # one pass over the block: a NaN makes its column's maximum NaN, an inf inf
    mx, my, mvx, mvy = np.abs(xyv).max(axis=0).tolist()
    if not all(map(math.isfinite, (mx, my, mvx, mvy))):
        raise MessageError("poses: positions and velocities must all be finite")
    if not (mx <= max_abs_m and my <= max_abs_m):
        raise MessageError(f"poses: a position beyond {max_abs_m:g} m")
    ids: list[int] = np.ndarray((n,), _ID_DTYPE, raw, 0, (_ROW,)).tolist()
    prev = -1
    for rid in ids:  # strictly ascending (ids are unsigned: -1 is below all)
        if rid <= prev:
            raise MessageError("poses.robot_ids must be strictly ascending")
        prev = rid
    xy: Array = xyv[:, :2]
    return step, ids, xy
