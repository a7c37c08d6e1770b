"""What one robot perceived of its team for a decision: :class:`View`, encode beside decode.

Part of the wire messages of :mod:`runtime.wire.messages` (which re-exports it and dispatches
on its tag); it lives in its own file only to keep each file short. Layout, little-endian,
derived from the field tables :data:`~runtime.wire.fields.VIEW_HEAD` and
:data:`~runtime.wire.fields.VIEW_ROW`::

    <BB I Q I>        tag (Tag.VIEW), version, robot_id, step, n           (18 bytes)
    n x <I d d I>     id, x, y, age_steps; ids strictly ascending          (24 bytes each)

A robot under imperfect sensing publishes one now and then (``patternrl robot
--view-every``), so that a log holds what each robot believed beside the world's ground
truth. The decoder bounds the count (:data:`MAX_VIEW_ROBOTS`) and checks it against the
bytes really there before reading anything, then the values (finite positions within
:data:`MAX_VIEW_COORD_M` of the origin), then their meaning (no member twice, the sender
among them).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

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
    uint,
)
from runtime.wire.fields import MAX_VIEW_COORD_M, MAX_VIEW_ROBOTS, VIEW_HEAD, VIEW_ROW

__all__ = [
    "MAX_VIEW_COORD_M",
    "MAX_VIEW_ROBOTS",
    "VIEW_ROW_DTYPE",
    "View",
    "check_view",
    "decode_view",
    "encode_view",
]

_HEAD: Final = VIEW_HEAD.wire_struct()
VIEW_ROW_DTYPE: Final = VIEW_ROW.wire_dtype()
"""One team member's row of a payload (24 bytes, packed)."""
_ROW: Final = VIEW_ROW_DTYPE.itemsize
assert VIEW_ROW.names() == ("id", "x", "y", "age_steps") and _HEAD.size == 18 and _ROW == 24


def _check(ids: npt.NDArray[np.uint32], xy: npt.NDArray[np.float64], robot_id: int) -> None:
    """The values, then the meaning, of a view's rows (MessageError with one line)."""
    if not np.isfinite(xy).all():
        raise MessageError("view: positions must all be finite")
    far = float(np.abs(xy).max(initial=0.0))
    if far > MAX_VIEW_COORD_M:
        raise MessageError(f"view: a position {far:g} m from the origin, "
                           f"at most {MAX_VIEW_COORD_M:g}")
    if ids.shape[0] > 1 and not bool((ids[1:] > ids[:-1]).all()):
        raise MessageError("view.ids must be strictly ascending")
    if not bool((ids == robot_id).any()):
        raise MessageError(f"view of robot {robot_id} lacks its own row")


@dataclass(frozen=True, slots=True, eq=False)
class View:
    """Robot -> anyone: the team as robot ``robot_id`` perceived it for its decision of
    ``step`` (the step of the world's poses it decided from).

    ``ids`` (n,) uint32, strictly ascending: the team of that decision, the robot itself
    among them. ``xy`` (n, 2) float64 metres, world frame, rows in ``ids`` order: where the
    robot believed each member to be at ``step`` (its peer tracker's estimate, or the view
    as sensed where it tracks none); its own row is its own pose. ``age_steps`` (n,)
    uint32: how many steps old each member's last sensed update was (its own row: the age
    of its own pose, 0 with fresh odometry). Read-only arrays.
    """

    robot_id: int
    step: int
    ids: npt.NDArray[np.uint32]
    xy: npt.NDArray[np.float64]
    age_steps: npt.NDArray[np.uint32]

    def __post_init__(self) -> None:
        try:
            ids = np.array(self.ids, dtype=np.int64).reshape(-1)
            xy = np.array(self.xy, dtype=np.float64).reshape(-1, 2)
            age = np.array(self.age_steps, dtype=np.int64).reshape(-1)
        except (TypeError, ValueError, OverflowError) as e:
            raise MessageError(f"view: (n,) ids and age_steps and (n, 2) xy expected: {e}"
                               ) from None
        n = ids.shape[0]
        if xy.shape != (n, 2) or age.shape != (n,):
            raise MessageError(f"view: xy must be ({n}, 2) and age_steps ({n},), "
                               f"got {xy.shape}, {age.shape}")
        for name, a in (("ids", ids), ("age_steps", age)):
            if n and (a.min() < 0 or a.max() > U32):
                raise MessageError(f"view.{name} must be in [0, {U32}]")
        for name, arr in (("ids", ids.astype(np.uint32)), ("xy", xy),
                          ("age_steps", age.astype(np.uint32))):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, View):
            return NotImplemented
        return (self.robot_id == other.robot_id and self.step == other.step
                and np.array_equal(self.ids, other.ids) and np.array_equal(self.xy, other.xy)
                and np.array_equal(self.age_steps, other.age_steps))

    __hash__ = None  # type: ignore[assignment]


def check_view(msg: View) -> View:
    """``msg`` if it can be sent: every check :func:`decode_view` makes (MessageError if not)."""
    w = "view"
    n = msg.ids.shape[0]
    if n > MAX_VIEW_ROBOTS:
        raise MessageError(f"view carries {n} robots, at most {MAX_VIEW_ROBOTS}")
    uint(w, "step", msg.step, U64)
    _check(msg.ids, msg.xy, uint(w, "robot_id", msg.robot_id, U32))
    return msg


def encode_view(msg: View) -> bytes:
    """Encode a :class:`View`: 18 bytes, then 24 bytes per team member."""
    check_view(msg)
    n = msg.ids.shape[0]
    try:
        head = _HEAD.pack(Tag.VIEW, VERSION, msg.robot_id, msg.step, n)
    except (struct.error, TypeError) as e:
        raise MessageError(f"cannot encode view: {e}") from None
    rows = np.empty(n, VIEW_ROW_DTYPE)
    rows["id"] = msg.ids
    rows["x"], rows["y"] = msg.xy[:, 0], msg.xy[:, 1]
    rows["age_steps"] = msg.age_steps
    return head + rows.tobytes()


_new: Final = object.__new__
_set: Final = object.__setattr__


def decode_view(payload: Buffer) -> View:
    """Decode a payload written by :func:`encode_view` (sizes, then values, then meaning)."""
    w = "view"
    view = as_view(payload, w)
    check_header(view, Tag.VIEW)
    r = Reader(view, w, 0)
    _, _, rid, step, n = r.unpack(_HEAD, "the fixed part")
    if n > MAX_VIEW_ROBOTS:
        raise MessageError(f"view claims {n} robots, at most {MAX_VIEW_ROBOTS}")
    raw = r.take(_ROW * n, "rows")
    r.finish()
    rows = np.frombuffer(raw, VIEW_ROW_DTYPE) if n else np.zeros(0, VIEW_ROW_DTYPE)
    ids = rows["id"].astype(np.uint32)
    xy = np.stack([rows["x"], rows["y"]], axis=1).astype(np.float64)
    age = rows["age_steps"].astype(np.uint32)
    _check(ids, xy, rid)
    for a in (ids, xy, age):
        a.setflags(write=False)
    out: View = _new(View)  # fresh, checked arrays: no __post_init__ copies
    _set(out, "robot_id", rid)
    _set(out, "step", step)
    _set(out, "ids", ids)
    _set(out, "xy", xy)
    _set(out, "age_steps", age)
    return out
