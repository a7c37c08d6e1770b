"""The field tables of the wire messages: each message's fields written down once.

A :class:`Field` names one field of a message: its name, its type (``kind``), its unit,
its protobuf field number in a log, the format version that added it and the bounds the
decoder checks. A :class:`FieldTable` is a message's fields in order. From a table follow:

* the :mod:`struct` format of the binary wire encoding (:meth:`FieldTable.wire_struct`):
  the 2-byte header (tag, version), every fixed-size field in table order, then the
  length of every variable-length field (a string: its ``length`` kind), whose bytes
  follow in the same order;
* the numpy structured dtype viewing such payloads as columns
  (:meth:`FieldTable.wire_dtype`): the same layout with named columns;
* the protobuf message of a log (:mod:`sim_bridge.log.schemas` builds its descriptor and
  its fixed layout from the table: :meth:`FieldTable.pb_type`, :attr:`Field.number`).

A field's ``since`` gives each format version its own layout (a version 1 command lacks
``brain_vx``, ``brain_vy``). Messages with repeated fields (a pattern's points, a brain's
target robots) keep their wire layout beside their codec in :mod:`runtime.wire.messages`;
their tables give the protobuf schema and the bounds.

Numpy and the standard library only (no protobuf): the robot runtime imports this.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

import numpy as np

from runtime.wire.codec import U32, U64
from runtime.world_config import MAX_PATTERN_COORD_M

__all__ = [
    "BRAIN",
    "COMMAND",
    "KINDS",
    "MAX_BRAIN_ID_BYTES",
    "MAX_BRAIN_ID_CHARS",
    "MAX_MANIFEST_BYTES",
    "MAX_ONNX_BYTES",
    "MAX_PATTERN_NAME_BYTES",
    "MAX_PATTERN_POINTS",
    "MAX_POSES_ROBOTS",
    "MAX_REQUEST_ID_BYTES",
    "MAX_SLOTS_ROBOTS",
    "MAX_STATUS_BYTES",
    "MAX_TARGET_ROBOTS",
    "MAX_VIEW_COORD_M",
    "MAX_VIEW_ROBOTS",
    "NO_SLOT",
    "PATTERN",
    "POSE",
    "POSES_HEAD",
    "POSES_ROW",
    "SLOTS",
    "SLOTS_HEAD",
    "STATUS",
    "UINT_MAX",
    "VIEW",
    "VIEW_HEAD",
    "VIEW_ROW",
    "Field",
    "FieldTable",
]

MAX_BRAIN_ID_CHARS: Final = 64
MAX_BRAIN_ID_BYTES: Final = 4 * MAX_BRAIN_ID_CHARS
"""The utf-8 bytes of the longest brain id (4 bytes a character at most)."""
MAX_PATTERN_NAME_BYTES: Final = 1024
MAX_PATTERN_POINTS: Final = 4096
"""Points a pattern message may carry: 40x the largest team the design budgets (100)."""
MAX_REQUEST_ID_BYTES: Final = 256
MAX_MANIFEST_BYTES: Final = 1 << 20
MAX_ONNX_BYTES: Final = 64 << 20
MAX_TARGET_ROBOTS: Final = 65_536
MAX_STATUS_BYTES: Final = 64 << 10
MAX_POSES_ROBOTS: Final = 4096
"""Robots one pose batch may carry: 40x the largest team the design budgets (100)."""
MAX_VIEW_ROBOTS: Final = MAX_POSES_ROBOTS
"""Team members one robot's view may carry: as many as a pose batch."""
MAX_SLOTS_ROBOTS: Final = 0xFFFF
"""Team members a leader's assignment may carry (its slots go as uint16 on the wire)."""
NO_SLOT: Final = U32
"""A ``slot`` of a slots message that says the robot holds none (it holds still)."""
MAX_VIEW_COORD_M: Final = 1e6
"""A perceived position farther from the origin is refused: as far as a robot takes a pose
(``runtime.robot.inbox.MAX_COORD_M``)."""

KINDS: Final[dict[str, tuple[str, str, str]]] = {
    # kind: (struct code, protobuf type, protobuf type in a fixed-width message)
    "u8": ("B", "uint32", "uint32"),
    "u16": ("H", "uint32", "uint32"),
    "u32": ("I", "uint32", "fixed32"),
    "u64": ("Q", "uint64", "fixed64"),
    "f64": ("d", "double", "double"),
    "bool": ("B", "bool", "bool"),
    "str": ("", "string", "string"),
    "bytes": ("", "bytes", "bytes"),
}
"""Every field type: its :mod:`struct` code ('' for variable length) and protobuf types."""
UINT_MAX: Final[dict[str, int]] = {"u8": 0xFF, "u16": 0xFFFF, "u32": U32, "u64": U64}
"""The largest value of each unsigned integer kind."""


@dataclass(frozen=True, slots=True)
class Field:
    """One field of a message.

    ``kind`` is a key of :data:`KINDS`; ``number`` its protobuf field number in a log
    (0: no protobuf field of its own). ``since`` is the wire format version that added
    it: in a log it is a proto3 ``optional`` field when later than 1 (an older log's
    absent field is not 0). ``repeated``: a list of values (protobuf ``repeated``).
    Bounds the decoder checks: floats are always finite, and within [``lo``, ``hi``] where
    given; a string or bytes at most ``max_bytes`` encoded, a string at most ``max_chars``
    characters (-1: no bound); a repeated field at most ``max_items`` values. ``length``
    is the kind of a variable-length field's length on the wire; ``column`` its name in
    the numpy layouts where not ``name`` (a string's length column is ``column + "_len"``).
    """

    name: str
    kind: str
    number: int = 0
    unit: str = ""
    since: int = 1
    repeated: bool = False
    lo: float | None = None
    hi: float | None = None
    max_bytes: int = -1
    max_chars: int = -1
    max_items: int = -1
    length: str = "u16"
    column: str = ""

    def __post_init__(self) -> None:
        assert self.kind in KINDS and self.length in UINT_MAX, self

    @property
    def code(self) -> str:
        """The :mod:`struct` code of its value ('' for variable length)."""
        return KINDS[self.kind][0]

    @property
    def variable(self) -> bool:
        """A string or bytes: its length on the wire, its bytes after the fixed part."""
        return not KINDS[self.kind][0]

    @property
    def col(self) -> str:
        """Its column name in the numpy layouts."""
        return self.column or self.name


@dataclass(frozen=True, slots=True)
class FieldTable:
    """The fields of one message, in order.

    ``name`` says the message in error texts; ``proto`` is its protobuf message in a log
    ('' when it has none of its own); ``fixed_width``: its integers are ``fixed32`` /
    ``fixed64`` in protobuf (so every record of it has one fixed layout) rather than
    varints; ``header``: its wire payloads start with the tag and version bytes.
    """

    name: str
    proto: str
    fields: tuple[Field, ...]
    fixed_width: bool = False
    header: bool = True

    def __post_init__(self) -> None:
        names = [f.name for f in self.fields]
        assert len(set(names)) == len(names), self.name
        numbers = [f.number for f in self.fields if f.number]
        assert len(set(numbers)) == len(numbers), self.name

    def __getitem__(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(name)

    def names(self, version: int = 1) -> tuple[str, ...]:
        """The names of the fields of format ``version``, in table order."""
        return tuple(f.name for f in self.at(version))

    def at(self, version: int = 1) -> tuple[Field, ...]:
        """The fields of format ``version``, in table order."""
        return tuple(f for f in self.fields if f.since <= version)

    def pb_type(self, f: Field) -> str:
        """The protobuf type of field ``f`` (``"fixed32"``, ``"double"``, ...)."""
        return KINDS[f.kind][2 if self.fixed_width else 1]

    def wire_layout(self, version: int = 1) -> tuple[tuple[str, str], ...]:
        """(column, struct code) of each value of the fixed part of a wire payload of
        format ``version``: header, fixed-size fields, lengths of the variable ones."""
        fs = self.at(version)
        if any(f.repeated for f in fs):
            raise ValueError(f"{self.name} has repeated fields: no fixed wire layout")
        head = (("tag", "B"), ("version", "B")) if self.header else ()
        fixed = tuple((f.col, f.code) for f in fs if not f.variable)
        lengths = tuple((f.col + "_len", KINDS[f.length][0]) for f in fs if f.variable)
        return head + fixed + lengths

    def wire_struct(self, version: int = 1) -> struct.Struct:
        """The :mod:`struct` (little-endian, packed) of the fixed part of format ``version``."""
        return struct.Struct("<" + "".join(code for _, code in self.wire_layout(version)))

    def wire_dtype(self, version: int = 1) -> np.dtype[np.void]:
        """The numpy record of :meth:`wire_struct`: ``np.frombuffer`` of a batch of
        payloads reads exactly what :mod:`struct` writes."""
        dt = np.dtype([(name, "<" + code) for name, code in self.wire_layout(version)])
        assert dt.itemsize == self.wire_struct(version).size
        return dt


_ID = Field("robot_id", "u32", 1)
_STEP = Field("step", "u64", 2)

POSE: Final = FieldTable("pose", "RobotPose", (
    _ID,
    _STEP,
    Field("time_s", "f64", 3, "s"),
    Field("x", "f64", 4, "m"),
    Field("y", "f64", 5, "m"),
    Field("vx", "f64", 6, "m/s"),
    Field("vy", "f64", 7, "m/s"),
    Field("n_live", "u32", 8),
), fixed_width=True)
"""World -> robot: one robot's pose at a step (:class:`runtime.wire.messages.Pose`)."""

COMMAND: Final = FieldTable("command", "RobotCommand", (
    _ID,
    _STEP,
    Field("vx", "f64", 3, "m/s"),
    Field("vy", "f64", 4, "m/s"),
    Field("safety_changed", "bool", 5),
    Field("safety_change_mps", "f64", 6, "m/s"),
    Field("decision_us", "f64", 7, "us"),
    Field("brain_id", "str", 8, max_bytes=MAX_BRAIN_ID_BYTES, max_chars=MAX_BRAIN_ID_CHARS,
          column="brain"),
    Field("brain_vx", "f64", 9, "m/s", since=2),
    Field("brain_vy", "f64", 10, "m/s", since=2),
), fixed_width=True)
"""Robot -> world: a robot's velocity command (:class:`runtime.wire.messages.Command`);
format version 2 added the brain's own velocity (``brain_vx``, ``brain_vy``)."""

POSES_HEAD: Final = FieldTable("poses", "", (
    Field("step", "u64"),
    Field("time_s", "f64", unit="s"),
    Field("n", "u32", hi=MAX_POSES_ROBOTS),
))
"""World -> robots: the fixed part of all poses of a step
(:class:`runtime.wire.pose_batch.PoseBatch`); ``n`` :data:`POSES_ROW` records follow. A log
keeps them as one ``RobotPose`` per robot."""

POSES_ROW: Final = FieldTable("poses", "", (
    Field("robot_id", "u32"),
    Field("x", "f64", unit="m"),
    Field("y", "f64", unit="m"),
    Field("vx", "f64", unit="m/s"),
    Field("vy", "f64", unit="m/s"),
), header=False)
"""One robot's record of a pose batch; robot ids strictly ascending."""

_TEXT = MAX_STATUS_BYTES
STATUS: Final = FieldTable("status", "RobotStatus", (
    Field("robot_id", "u32", 1),
    Field("step", "u64", 2),
    Field("brain_id", "str", 3, max_bytes=_TEXT, max_chars=MAX_BRAIN_ID_CHARS),
    Field("decision_latency_us_p50", "f64", 4, "us"),
    Field("decision_latency_us_p99", "f64", 5, "us"),
    Field("loop_jitter_ms", "f64", 6, "ms"),
    Field("messages_dropped", "u64", 7),
    Field("errors", "u64", 8),
    Field("safety_interventions", "u64", 9),
    Field("last_error", "str", 10, max_bytes=_TEXT),
    Field("uptime_s", "f64", 11, "s"),
    Field("swap_request_id", "str", 12, max_bytes=_TEXT),
    Field("swap_accepted", "bool", 13),
    Field("swap_reason", "str", 14, max_bytes=_TEXT),
    Field("old_brain_id", "str", 15, max_bytes=_TEXT, max_chars=MAX_BRAIN_ID_CHARS),
    Field("nonfinite_fallbacks", "u64", 16),
))
"""Robot -> anyone: a robot's health (:class:`runtime.wire.messages.Status`), the keys of its
JSON object in this order; the whole payload at most :data:`MAX_STATUS_BYTES`."""

PATTERN: Final = FieldTable("pattern", "Pattern", (
    Field("version", "u64", 1),
    Field("name", "str", 2, max_bytes=MAX_PATTERN_NAME_BYTES),
    Field("formed_tol_m", "f64", 3, "m", lo=0.0),
    Field("x", "f64", 4, "m", repeated=True, lo=-MAX_PATTERN_COORD_M, hi=MAX_PATTERN_COORD_M,
          max_items=MAX_PATTERN_POINTS),
    Field("y", "f64", 5, "m", repeated=True, lo=-MAX_PATTERN_COORD_M, hi=MAX_PATTERN_COORD_M,
          max_items=MAX_PATTERN_POINTS),
))
"""Operator/world -> all: the target pattern (:class:`runtime.wire.messages.PatternMsg`); on the
wire its points are n x 2 float64 (x, y interleaved), in a log two repeated fields."""

BRAIN: Final = FieldTable("brain", "BrainSwap", (
    Field("request_id", "str", 1, max_bytes=MAX_REQUEST_ID_BYTES, length="u32"),
    Field("manifest_json", "str", 2, max_bytes=MAX_MANIFEST_BYTES, length="u32"),
    Field("onnx", "bytes", 3, max_bytes=MAX_ONNX_BYTES, length="u32"),
    Field("target_robots", "u32", 4, repeated=True, max_items=MAX_TARGET_ROBOTS),
))
"""Operator -> robots: a brain to swap in (:class:`runtime.wire.messages.BrainMsg`, whose
``onnx_bytes`` is ``onnx`` here); on the wire each field is uint32-length-prefixed."""

VIEW: Final = FieldTable("view", "RobotView", (
    Field("robot_id", "u32", 1),
    Field("step", "u64", 2),
    Field("ids", "u32", 3, repeated=True, max_items=MAX_VIEW_ROBOTS),
    Field("x", "f64", 4, "m", repeated=True, lo=-MAX_VIEW_COORD_M, hi=MAX_VIEW_COORD_M,
          max_items=MAX_VIEW_ROBOTS),
    Field("y", "f64", 5, "m", repeated=True, lo=-MAX_VIEW_COORD_M, hi=MAX_VIEW_COORD_M,
          max_items=MAX_VIEW_ROBOTS),
    Field("age_steps", "u32", 6, "steps", repeated=True, max_items=MAX_VIEW_ROBOTS),
))
"""Robot -> anyone: the team as one robot perceived it for its decision of a step
(:class:`runtime.wire.view.View`); on the wire a fixed part (:data:`VIEW_HEAD`) and one
:data:`VIEW_ROW` per team member, in a log four repeated fields."""

VIEW_HEAD: Final = FieldTable("view", "", (
    Field("robot_id", "u32"),
    Field("step", "u64"),
    Field("n", "u32", hi=MAX_VIEW_ROBOTS),
))
"""The fixed part of a view on the wire; ``n`` :data:`VIEW_ROW` records follow."""

VIEW_ROW: Final = FieldTable("view", "", (
    Field("id", "u32"),
    Field("x", "f64", unit="m", lo=-MAX_VIEW_COORD_M, hi=MAX_VIEW_COORD_M),
    Field("y", "f64", unit="m", lo=-MAX_VIEW_COORD_M, hi=MAX_VIEW_COORD_M),
    Field("age_steps", "u32", unit="steps"),
), header=False)
"""One team member of a view: its id, its perceived position, the age of its last sensed
update; ids strictly ascending, the sender's own among them."""

SLOTS: Final = FieldTable("slots", "RobotSlots", (
    Field("robot_id", "u32", 1),
    Field("step", "u64", 2),
    Field("pattern_version", "u64", 3),
    Field("slot", "u32", 4),
    Field("ids", "u32", 5, repeated=True, max_items=MAX_SLOTS_ROBOTS),
    Field("assignment", "u32", 6, repeated=True, max_items=MAX_SLOTS_ROBOTS),
    Field("frame", "f64", 7, "m", repeated=True, lo=-MAX_VIEW_COORD_M, hi=MAX_VIEW_COORD_M,
          max_items=2),
))
"""Robot -> robots: the slot a robot goes by at a step, and the leader's whole assignment
and its plan's frame (:class:`runtime.wire.slots.Slots`); on the wire a fixed part
(:data:`SLOTS_HEAD`), then the team's ids as uint32, the assignment as uint16 and the frame
as two float64 where there is one, in a log three repeated fields (the frame: none or x, y)."""

SLOTS_HEAD: Final = FieldTable("slots", "", (
    Field("robot_id", "u32"),
    Field("step", "u64"),
    Field("pattern_version", "u64"),
    Field("slot", "u32"),
    Field("n", "u32", hi=MAX_SLOTS_ROBOTS),
))
"""The fixed part of a slots message on the wire; n ids and n slots follow (n = 0: a
claim alone)."""
