"""The protobuf messages of a log: our own (``patternrl.*``) and Foxglove's well-known ones.

Every Zenoh payload the recorder takes in is written as a protobuf message whose
schema record holds a whole ``FileDescriptorSet`` (schema encoding ``protobuf``),
so any MCAP tool decodes it (``mcap_protobuf.decoder.DecoderFactory``) without
this project. Our own messages (package ``patternrl``, file ``patternrl/log.proto``) are
built from the field tables of :mod:`runtime.wire.fields` (names, types, field numbers;
``RawSample``'s table is here), as are the fixed layouts below::

    RobotPose     1 robot_id fixed32, 2 step fixed64, 3 time_s double, 4 x double,
                  5 y double, 6 vx double, 7 vy double, 8 n_live fixed32      (m, m/s, s)
    RobotCommand  1 robot_id fixed32, 2 step fixed64, 3 vx double, 4 vy double,
                  5 safety_changed bool, 6 safety_change_mps double,
                  7 decision_us double, 8 brain_id string, 9 brain_vx optional double,
                  10 brain_vy optional double   (the brain's own velocity, m/s, before the
                  clamp and the safety filter; absent in older logs: read as vx, vy)
    RobotStatus   the fields of runtime.wire.messages.Status, numbered in their order
    Pattern       1 version uint64, 2 name string, 3 formed_tol_m double,
                  4 x repeated double, 5 y repeated double                       (metres)
    BrainSwap     1 request_id string, 2 manifest_json string, 3 onnx bytes,
                  4 target_robots repeated uint32
    RobotView     1 robot_id uint32, 2 step uint64, 3 ids repeated uint32,
                  4 x repeated double, 5 y repeated double, 6 age_steps repeated uint32
                  (the team as robot robot_id perceived it for step; metres, steps)
    RobotSlots    1 robot_id uint32, 2 step uint64, 3 pattern_version uint64, 4 slot uint32,
                  5 ids repeated uint32, 6 assignment repeated uint32 (the slot robot_id goes
                  by, 4294967295: none; the leader's whole assignment, else empty)
    RawSample     1 key string, 2 size uint64, 3 reason string, 4 payload bytes

Fixed-width fields make a pose or command the recorder writes one fixed layout
(:data:`POSE_PB_DTYPE`, :func:`command_pb_dtype`): every field in table order, each
after its one-byte protobuf tag, the fixed-size ones first and then the strings (a
one-byte length, the bytes last) -- so a command's fields 9 and 10 come before its brain
id, field 8, and older logs lack them. The reader views a whole run's payloads as numpy
columns at once and parses with protobuf only the payloads of another layout (another
writer, proto3 zeros left out). :func:`encode_pose_pb` and :func:`encode_command_pb`
write that layout with :mod:`struct`; a unit test parses them back with the protobuf
library.
"""

from __future__ import annotations

import struct
from functools import cache
from typing import Any, Final

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.descriptor import FileDescriptor
from google.protobuf.message import DecodeError

from runtime.wire.fields import BRAIN, COMMAND, POSE, SLOTS, STATUS, VIEW, Field, FieldTable
from runtime.wire.fields import PATTERN as PATTERN_FIELDS
from runtime.wire.messages import (
    COMMAND_VERSION,
    BrainMsg,
    Command,
    MessageError,
    PatternMsg,
    Pose,
    Slots,
    Status,
    View,
    check_slots,
    check_view,
    encode_brain,
    encode_command,
    encode_pattern,
    encode_pose,
    encode_slots,
    encode_status,
    encode_view,
)

PROTOBUF: Final = "protobuf"
"""Message and schema encoding of every protobuf channel."""

_F = descriptor_pb2.FieldDescriptorProto

RAW_SAMPLE_FIELDS: Final = FieldTable("raw sample", "RawSample", (
    Field("key", "str", 1),
    Field("size", "u64", 2),
    Field("reason", "str", 3),
    Field("payload", "bytes", 4),
))
"""A Zenoh payload kept as it came (too large, or not a message): the log's own message."""
TABLES: Final = (POSE, COMMAND, STATUS, PATTERN_FIELDS, BRAIN, RAW_SAMPLE_FIELDS, VIEW,
                 SLOTS)
"""The field table of each of our messages, in the order of ``patternrl/log.proto``."""


def _file_proto() -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(name="patternrl/log.proto", package="patternrl",
                                             syntax="proto3")
    for table in TABLES:
        m = fdp.message_type.add(name=table.proto)
        for f in table.fields:
            label = _F.LABEL_REPEATED if f.repeated else _F.LABEL_OPTIONAL
            field = m.field.add(name=f.name, number=f.number, label=label, json_name=f.name,
                                type=_F.Type.Value("TYPE_" + table.pb_type(f).upper()))
            if f.since > 1:  # proto3 presence: an old log's absent field is not 0
                field.proto3_optional = True
                field.oneof_index = len(m.oneof_decl)
                m.oneof_decl.add(name=f"_{f.name}")
    return fdp


_POOL: Final = descriptor_pool.DescriptorPool()
_FILE: Final[FileDescriptor] = _POOL.Add(_file_proto())  # type: ignore[func-returns-value]


def message_class(name: str) -> Any:
    """The protobuf class of one of our messages (``"patternrl.RobotPose"``) or Foxglove's
    (``"foxglove.PoseInFrame"``)."""
    pkg, short = name.split(".", 1)
    if pkg == "patternrl":
        return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(name))
    import importlib

    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{short}_pb2"), short)


@cache
def schema_data(name: str) -> bytes:
    """The serialised ``FileDescriptorSet`` of message ``name``, its dependencies first."""
    out = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: FileDescriptor) -> None:
        for dep in fd.dependencies:
            if dep.name not in seen:
                seen.add(dep.name)
                add(dep)
        fd.CopyToProto(out.file.add())

    add(message_class(name).DESCRIPTOR.file)
    return out.SerializeToString()


ROBOT_POSE: Final = "patternrl.RobotPose"
ROBOT_COMMAND: Final = "patternrl.RobotCommand"
ROBOT_STATUS: Final = "patternrl.RobotStatus"
PATTERN: Final = "patternrl.Pattern"
BRAIN_SWAP: Final = "patternrl.BrainSwap"
RAW_SAMPLE: Final = "patternrl.RawSample"
ROBOT_VIEW: Final = "patternrl.RobotView"
ROBOT_SLOTS: Final = "patternrl.RobotSlots"
POSE_IN_FRAME: Final = "foxglove.PoseInFrame"
FRAME_TRANSFORMS: Final = "foxglove.FrameTransforms"


def _tag(field: int, wire_type: int) -> int:
    return (field << 3) | wire_type


# -- fixed layouts --------------------------------------------------------------------------

_D, _Q, _I, _V, _L = 1, 1, 5, 0, 2  # wire types: 64-bit, 64-bit, 32-bit, varint, length
_FIXED: Final[dict[str, tuple[int, str]]] = {
    # protobuf type: (wire type, struct code of its value in the fixed layout)
    "fixed32": (_I, "I"), "fixed64": (_Q, "Q"), "double": (_D, "d"),
    "bool": (_V, "B"),  # 0 or 1: a one-byte varint
    "string": (_L, "B"),  # its length, a one-byte varint; the bytes come last
}


def fixed_layout(table: FieldTable, version: int = 1) -> tuple[tuple[str, int, str], ...]:
    """(column, tag byte, struct code) of each value of ``table``'s fixed protobuf layout
    of format ``version``: the fixed-size fields in table order, then each string's length
    (its bytes follow, in the same order). Only for ``fixed_width`` tables."""
    fs = table.at(version)
    assert table.fixed_width and not any(f.repeated for f in fs), table.name
    out = []
    for f in (*(f for f in fs if not f.variable), *(f for f in fs if f.variable)):
        wire_type, code = _FIXED[table.pb_type(f)]
        out.append((f.col + "_len" if f.variable else f.col, _tag(f.number, wire_type), code))
    return tuple(out)


def _fixed_struct(layout: tuple[tuple[str, int, str], ...]) -> struct.Struct:
    return struct.Struct("<" + "".join("B" + code for _, _, code in layout))


def _fixed_dtype(layout: tuple[tuple[str, int, str], ...]) -> np.dtype[np.void]:
    dt = np.dtype([f for k, (col, _, code) in enumerate(layout, start=1)
                   for f in ((f"t{k}", "u1"), (col, "<" + code))])
    assert dt.itemsize == _fixed_struct(layout).size
    return dt


def _fixed_tags(layout: tuple[tuple[str, int, str], ...]) -> dict[str, int]:
    return {f"t{k}": tag for k, (_, tag, _) in enumerate(layout, start=1)}


_POSE_LAYOUT: Final = fixed_layout(POSE)
_POSE_PB: Final = _fixed_struct(_POSE_LAYOUT)
_POSE_TAGS: Final = tuple(tag for _, tag, _ in _POSE_LAYOUT)
POSE_PB_DTYPE: Final = _fixed_dtype(_POSE_LAYOUT)
"""A :func:`encode_pose_pb` payload as one numpy record (tag bytes ``t1``..``t8``)."""
POSE_PB_TAGS: Final = _fixed_tags(_POSE_LAYOUT)
assert POSE_PB_DTYPE.itemsize == _POSE_PB.size == 64

_CMD_LAYOUTS: Final = {v: fixed_layout(COMMAND, v) for v in (1, COMMAND_VERSION)}
_CMD_PB: Final = _fixed_struct(_CMD_LAYOUTS[COMMAND_VERSION])
_CMD_TAGS: Final = tuple(tag for _, tag, _ in _CMD_LAYOUTS[COMMAND_VERSION])
_CMD_HEADS: Final = {v: _fixed_dtype(layout) for v, layout in _CMD_LAYOUTS.items()}
COMMAND_PB_TAGS: Final = _fixed_tags(_CMD_LAYOUTS[COMMAND_VERSION])
"""Tag byte of each field of :func:`command_pb_dtype` (``t1``..``t10``, in layout order)."""
COMMAND_PB_TAGS_V1: Final = _fixed_tags(_CMD_LAYOUTS[1])
"""The same for the older layout (:func:`command_pb_dtype` with ``old=True``)."""
MAX_FIXED_BRAIN_BYTES: Final = 127
"""Brain ids up to this many bytes keep a one-byte length: the fixed layout."""


def command_pb_dtype(brain_len: int, old: bool = False) -> np.dtype[np.void]:
    """A :func:`encode_command_pb` payload whose brain id is ``brain_len`` bytes; ``old``:
    one of a log written before fields 9 and 10 (brain_vx, brain_vy)."""
    head = _CMD_HEADS[1 if old else COMMAND_VERSION]
    return np.dtype([*head.descr, ("brain", f"S{brain_len}")]) if brain_len else head


def encode_pose_pb(p: Pose) -> bytes:
    """A wire :class:`~runtime.wire.messages.Pose` as a ``patternrl.RobotPose`` (64 bytes)."""
    t = _POSE_TAGS
    return _POSE_PB.pack(t[0], p.robot_id, t[1], p.step, t[2], p.time_s, t[3], p.x, t[4], p.y,
                         t[5], p.vx, t[6], p.vy, t[7], p.n_live)


def encode_command_pb(c: Command) -> bytes:
    """A wire :class:`~runtime.wire.messages.Command` as a ``patternrl.RobotCommand``."""
    brain = c.brain_id.encode("utf-8")
    t = _CMD_TAGS
    if len(brain) > MAX_FIXED_BRAIN_BYTES:  # never for a sha256 prefix; kept exact anyway
        m = message_class(ROBOT_COMMAND)(
            robot_id=c.robot_id, step=c.step, vx=c.vx, vy=c.vy,
            safety_changed=c.safety_changed, safety_change_mps=c.safety_change_mps,
            decision_us=c.decision_us, brain_id=c.brain_id, brain_vx=c.brain_vx,
            brain_vy=c.brain_vy)
        return bytes(m.SerializeToString())
    return _CMD_PB.pack(t[0], c.robot_id, t[1], c.step, t[2], c.vx, t[3], c.vy, t[4],
                        int(c.safety_changed), t[5], c.safety_change_mps, t[6], c.decision_us,
                        t[7], c.brain_vx, t[8], c.brain_vy, t[9], len(brain)) + brain


def status_pb(s: Status) -> bytes:
    m = message_class(ROBOT_STATUS)(**{f: getattr(s, f) for f in STATUS.names()})
    return bytes(m.SerializeToString())


def pattern_pb(p: PatternMsg) -> bytes:
    m = message_class(PATTERN)(version=p.version, name=p.name, formed_tol_m=p.formed_tol_m,
                               x=p.points[:, 0].tolist(), y=p.points[:, 1].tolist())
    return bytes(m.SerializeToString())


def brain_pb(b: BrainMsg) -> bytes:
    m = message_class(BRAIN_SWAP)(request_id=b.request_id, manifest_json=b.manifest_json,
                                  onnx=b.onnx_bytes, target_robots=list(b.target_robots))
    return bytes(m.SerializeToString())


def view_pb(v: View) -> bytes:
    m = message_class(ROBOT_VIEW)(robot_id=v.robot_id, step=v.step, ids=v.ids.tolist(),
                                  x=v.xy[:, 0].tolist(), y=v.xy[:, 1].tolist(),
                                  age_steps=v.age_steps.tolist())
    return bytes(m.SerializeToString())


def view_of(m: Any) -> View:
    """A parsed ``patternrl.RobotView`` as a :class:`~runtime.wire.messages.View`, checked as
    the wire's decoder checks one (:class:`~runtime.wire.messages.MessageError` if not)."""
    n = len(m.ids)
    if not len(m.x) == len(m.y) == len(m.age_steps) == n:
        raise MessageError(f"view: {n} ids, but {len(m.x)} x, {len(m.y)} y and "
                           f"{len(m.age_steps)} ages")
    xy = np.stack([np.asarray(m.x, float), np.asarray(m.y, float)], axis=1).reshape(n, 2)
    return check_view(View(m.robot_id, m.step, np.asarray(m.ids, np.int64), xy,
                           np.asarray(m.age_steps, np.int64)))


def slots_pb(v: Slots) -> bytes:
    m = message_class(ROBOT_SLOTS)(robot_id=v.robot_id, step=v.step,
                                   pattern_version=v.pattern_version, slot=v.slot,
                                   ids=v.ids.tolist(), assignment=v.assignment.tolist(),
                                   frame=[] if v.frame is None else list(v.frame))
    return bytes(m.SerializeToString())


def slots_of(m: Any) -> Slots:
    """A parsed ``patternrl.RobotSlots`` as a :class:`~runtime.wire.messages.Slots`, checked
    as the wire's decoder checks one (:class:`~runtime.wire.messages.MessageError` if not)."""
    if len(m.frame) not in (0, 2):
        raise MessageError(f"slots.frame: none or (x, y), got {len(m.frame)} values")
    return check_slots(Slots(m.robot_id, m.step, m.pattern_version, m.slot,
                             np.asarray(m.ids, np.int64), np.asarray(m.assignment, np.int64),
                             tuple(m.frame) if len(m.frame) else None))  # type: ignore[arg-type]


def raw_sample_pb(key: str, size: int, reason: str, payload: bytes) -> bytes:
    m = message_class(RAW_SAMPLE)(key=key, size=size, reason=reason, payload=payload)
    return bytes(m.SerializeToString())


def parse(name: str, data: bytes) -> Any:
    """Parse one payload of message ``name``; ``ValueError`` if it is not one."""
    m = message_class(name)()
    try:
        m.ParseFromString(data)
    except (DecodeError, RuntimeError) as e:
        raise ValueError(f"not a {name}: {e}") from None
    return m


def brain_velocity(m: Any) -> tuple[float, float]:
    """A parsed ``patternrl.RobotCommand``'s brain velocity (m/s): its vx, vy where the
    log predates fields 9 and 10."""
    return (m.brain_vx if m.HasField("brain_vx") else m.vx,
            m.brain_vy if m.HasField("brain_vy") else m.vy)


def to_wire(name: str, data: bytes) -> bytes:
    """The Zenoh payload a recorded protobuf message stands for (play-back puts it back)."""
    m = parse(name, data)
    if name == ROBOT_POSE:
        return encode_pose(Pose(*(getattr(m, f) for f in POSE.names())))
    if name == ROBOT_COMMAND:
        return encode_command(Command(m.robot_id, m.step, m.vx, m.vy, m.brain_id,
                                      m.safety_changed, m.safety_change_mps, m.decision_us,
                                      *brain_velocity(m)))
    if name == ROBOT_STATUS:
        return encode_status(Status(**{f: getattr(m, f) for f in STATUS.names()}))
    if name == PATTERN:
        pts = np.stack([np.asarray(m.x, float), np.asarray(m.y, float)], axis=1).reshape(-1, 2)
        return encode_pattern(PatternMsg(m.version, m.name, pts, m.formed_tol_m))
    if name == BRAIN_SWAP:
        return encode_brain(BrainMsg(m.request_id, m.manifest_json, bytes(m.onnx),
                                     tuple(m.target_robots)))
    if name == ROBOT_VIEW:
        return encode_view(view_of(m))
    if name == ROBOT_SLOTS:
        return encode_slots(slots_of(m))
    if name == RAW_SAMPLE:
        return bytes(m.payload)
    raise ValueError(f"{name} is not a Zenoh message")


# -- Foxglove's poses and transforms, written by hand (the library's builders cost ~5x) ----


def _varint(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _field(number: int, body: bytes) -> bytes:
    """A length-delimited field (a string or a nested message)."""
    return bytes((_tag(number, _L),)) + _varint(len(body)) + body


_XY: Final = struct.Struct("<BdBd")
_IDENTITY_Q: Final = _field(2, struct.pack("<Bd", _tag(4, _D), 1.0))  # orientation w = 1


def _timestamp(t_ns: int) -> bytes:
    sec, nsec = divmod(max(int(t_ns), 0), 1_000_000_000)
    body = (bytes((_tag(1, _V),)) + _varint(sec) if sec else b"") + (
        bytes((_tag(2, _V),)) + _varint(nsec) if nsec else b"")
    return _field(1, body)


def _vector_xy(number: int, x: float, y: float) -> bytes:
    return _field(number, _XY.pack(_tag(1, _D), x, _tag(2, _D), y))


def pose_in_frame_pb(t_ns: int, frame: str, x: float, y: float) -> bytes:
    """A ``foxglove.PoseInFrame`` at (x, y, 0) metres, identity orientation, time ``t_ns``."""
    pose = _vector_xy(1, x, y) + _IDENTITY_Q
    return _timestamp(t_ns) + _field(2, frame.encode()) + _field(3, pose)


def frame_transforms_pb(t_ns: int, parent: str, children: list[tuple[str, float, float]]
                        ) -> bytes:
    """A ``foxglove.FrameTransforms``: ``parent`` -> each (child frame, x, y) metres."""
    stamp = _timestamp(t_ns)
    par = _field(2, parent.encode())
    rot = _field(5, struct.pack("<Bd", _tag(4, _D), 1.0))
    return b"".join(
        _field(1, stamp + par + _field(3, c.encode()) + _vector_xy(4, x, y) + rot)
        for c, x, y in children)
