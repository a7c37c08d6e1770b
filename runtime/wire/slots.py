"""What one robot tells its team of its slots: :class:`Slots`, encode beside decode.

Part of the wire messages of :mod:`runtime.wire.messages` (which re-exports it and dispatches
on its tag); it lives in its own file only to keep each file short. Layout, little-endian,
derived from the field table :data:`~runtime.wire.fields.SLOTS_HEAD`::

    <BB I Q Q I I>    tag (Tag.SLOTS), version, robot_id, step, pattern_version, slot, n
                                                                                (30 bytes)
    n x <I>           the team's ids, strictly ascending, the sender among them
    n x <H>           the assignment: robot ids[k] goes to slot assignment[k] (a permutation)
    <dd>              the leader's plan frame x, y (m), where it has one (n > 0 only)

Every robot that agrees on its slots (``patternrl robot --agree``, under imperfect sensing:
:mod:`runtime.decision.agreement`) sends one each step it decides: its slot (``NO_SLOT``:
none), n = 0; the team's leader, its lowest id, also its whole assignment and, under
noise, the frame its plan goes in, which the team goes by too. The decoder
bounds the count (:data:`MAX_SLOTS_ROBOTS`) and checks it against the bytes really there
before reading anything, then the values (ids ascending, slots below n), then their meaning
(the sender among the ids, the assignment a permutation, the sender's slot its own entry,
a frame only beside an assignment).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
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
from runtime.wire.fields import MAX_SLOTS_ROBOTS, MAX_VIEW_COORD_M, NO_SLOT, SLOTS_HEAD

__all__ = ["MAX_SLOTS_ROBOTS", "NO_SLOT", "Slots", "check_slots", "decode_slots",
           "encode_slots"]

_HEAD: Final = SLOTS_HEAD.wire_struct()
assert _HEAD.size == 30
_FRAME: Final = struct.Struct("<dd")


def _check(rid: int, slot: int, ids: npt.NDArray[np.uint32],
           assignment: npt.NDArray[np.uint16], frame: tuple[float, float] | None) -> None:
    """The values, then the meaning (MessageError with one line)."""
    n = ids.shape[0]
    if assignment.shape != (n,):
        raise MessageError(f"slots: {n} ids but {assignment.shape[0]} slots")
    if frame is not None:
        if not all(math.isfinite(v) and abs(v) <= MAX_VIEW_COORD_M for v in frame):
            raise MessageError(f"slots.frame must be finite, within {MAX_VIEW_COORD_M:g} m")
        if n == 0:
            raise MessageError("slots.frame comes only with the leader's assignment")
    if n > 1 and not bool((ids[1:] > ids[:-1]).all()):
        raise MessageError("slots.ids must be strictly ascending")
    if n == 0:
        if slot != NO_SLOT and slot >= MAX_SLOTS_ROBOTS:
            raise MessageError(f"slots.slot {slot} is beyond any team")
        return
    if int(assignment.max()) >= n or np.bincount(assignment, minlength=n).max() != 1:
        raise MessageError(f"slots.assignment must give each of the {n} robots its own slot")
    me = np.flatnonzero(ids == rid)
    if me.size == 0:
        raise MessageError(f"slots of robot {rid}: the sender is not among the ids")
    if slot != int(assignment[me[0]]):
        raise MessageError(f"slots of robot {rid}: slot {slot} is not its own in the "
                           f"assignment ({int(assignment[me[0]])})")


@dataclass(frozen=True, slots=True, eq=False)
class Slots:
    """Robot -> robots: the slot robot ``robot_id`` goes by at ``step`` for the pattern of
    ``pattern_version`` (:data:`NO_SLOT`: none), and, from the team's leader, the whole
    assignment: ``ids`` (n,) uint32 strictly ascending, the sender among them, and
    ``assignment`` (n,) uint16, robot ``ids[k]``'s slot; both empty from the others; and
    under noise the leader's plan ``frame`` (x, y) m (None: none). Read-only arrays."""

    robot_id: int
    step: int
    pattern_version: int
    slot: int
    ids: npt.NDArray[np.uint32] = field(default_factory=lambda: np.zeros(0, np.uint32))
    assignment: npt.NDArray[np.uint16] = field(default_factory=lambda: np.zeros(0, np.uint16))
    frame: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.frame is not None:
            try:
                fx, fy = (float(v) for v in self.frame)
            except (TypeError, ValueError) as e:
                raise MessageError(f"slots.frame: (x, y) expected: {e}") from None
            object.__setattr__(self, "frame", (fx, fy))
        try:
            ids = np.array(self.ids, dtype=np.int64).reshape(-1)
            a = np.array(self.assignment, dtype=np.int64).reshape(-1)
        except (TypeError, ValueError, OverflowError) as e:
            raise MessageError(f"slots: (n,) ids and assignment expected: {e}") from None
        if ids.size and (ids.min() < 0 or ids.max() > U32):
            raise MessageError(f"slots.ids must be in [0, {U32}]")
        if a.size and (a.min() < 0 or a.max() >= MAX_SLOTS_ROBOTS):
            raise MessageError(f"slots.assignment must be in [0, {MAX_SLOTS_ROBOTS})")
        for name, arr in (("ids", ids.astype(np.uint32)), ("assignment", a.astype(np.uint16))):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Slots):
            return NotImplemented
        return (self.robot_id == other.robot_id and self.step == other.step
                and self.pattern_version == other.pattern_version and self.slot == other.slot
                and np.array_equal(self.ids, other.ids)
                and np.array_equal(self.assignment, other.assignment)
                and self.frame == other.frame)

    __hash__ = None  # type: ignore[assignment]


def check_slots(msg: Slots) -> Slots:
    """``msg`` if it can be sent: every check :func:`decode_slots` makes (MessageError if
    not)."""
    w = "slots"
    n = msg.ids.shape[0]
    if n > MAX_SLOTS_ROBOTS:
        raise MessageError(f"slots carries {n} robots, at most {MAX_SLOTS_ROBOTS}")
    uint(w, "step", msg.step, U64)
    uint(w, "pattern_version", msg.pattern_version, U64)
    _check(uint(w, "robot_id", msg.robot_id, U32), uint(w, "slot", msg.slot, U32),
           msg.ids, msg.assignment, msg.frame)
    return msg


def encode_slots(msg: Slots) -> bytes:
    """Encode a :class:`Slots`: 30 bytes, then 6 bytes per team member and 16 for a frame
    (the leader's)."""
    check_slots(msg)
    n = msg.ids.shape[0]
    try:
        head = _HEAD.pack(Tag.SLOTS, VERSION, msg.robot_id, msg.step, msg.pattern_version,
                          msg.slot, n)
    except (struct.error, TypeError) as e:
        raise MessageError(f"cannot encode slots: {e}") from None
    return (head + msg.ids.astype("<u4").tobytes()
            + msg.assignment.astype("<u2").tobytes()
            + (b"" if msg.frame is None else _FRAME.pack(*msg.frame)))


def decode_slots(payload: Buffer) -> Slots:
    """Decode a payload written by :func:`encode_slots` (sizes, then values, then meaning)."""
    w = "slots"
    view = as_view(payload, w)
    check_header(view, Tag.SLOTS)
    r = Reader(view, w, 0)
    _, _, rid, step, version, slot, n = r.unpack(_HEAD, "the fixed part")
    if n > MAX_SLOTS_ROBOTS:
        raise MessageError(f"slots claims {n} robots, at most {MAX_SLOTS_ROBOTS}")
    ids = np.frombuffer(r.take(4 * n, "ids"), "<u4").astype(np.uint32)
    a = np.frombuffer(r.take(2 * n, "assignment"), "<u2").astype(np.uint16)
    frame = None
    if len(view) - (_HEAD.size + 6 * n) == _FRAME.size:
        frame = _FRAME.unpack(r.take(_FRAME.size, "frame"))
    r.finish()
    _check(rid, slot, ids, a, frame)
    ids.setflags(write=False)
    a.setflags(write=False)
    out: Slots = object.__new__(Slots)  # fresh, checked arrays: no __post_init__ copies
    for name, v in (("robot_id", rid), ("step", step), ("pattern_version", version),
                    ("slot", slot), ("ids", ids), ("assignment", a), ("frame", frame)):
        object.__setattr__(out, name, v)
    return out
