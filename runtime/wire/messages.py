"""Every message of Pattern-RL, with its ``encode`` right beside its ``decode``.

Wire format: compact little-endian binary built with :mod:`struct`, never pickle. Every
payload starts with a 1-byte message tag and a 1-byte format version (:data:`VERSION`,
but :data:`COMMAND_VERSION` for a command; decoders also read older ones)::

    Pose     <BB I Q d d d d d I>                 tag, version, robot_id, step, time_s,
                                                  x, y, vx, vy, n_live           (58 bytes)
    Command  <BB I Q d d B d d d d H> + brain_id   tag, version (2), robot_id, step, vx, vy,
                                                  safety_changed, safety_change_mps,
                                                  decision_us, brain_vx, brain_vy,
                                                  len(brain_id)  + utf-8; version 1 had
                                                  no brain_vx, brain_vy (read as vx, vy)
    Status   <BB> + utf-8 JSON object             once a second: readability beats bytes
    Pattern  <BB Q d H I> + name + points         tag, version, pattern version, formed_tol_m,
                                                  len(name), n points; utf-8 name; n x 2 f64
    Brain    <BB> + 3 x (<I> + bytes) + <I> + ids  request_id, manifest_json (utf-8),
                                                  onnx bytes, then n target ids as uint32
    Poses    <BB Q d I> + n x <I d d d d>         all poses of a step: runtime/pose_batch.py
    View     <BB I Q I> + n x <I d d I>           tag, version, robot_id, step, n; per team
                                                  member id, x, y, age_steps: the team as the
                                                  robot perceived it (runtime/wire/view.py)
    Slots    <BB I Q Q I I> + n x <I> + n x <H>   tag, version, robot_id, step, pattern_version,
                                                  slot, n; the leader's team ids and its
                                                  assignment (runtime/wire/slots.py)

Every decoder bounds a message before it uses it: sizes first (a length or count field is
checked against its documented maximum, ``MAX_*`` below, and against the bytes that are
really there before anything is allocated), then values (finite floats; pattern points
within ``MAX_PATTERN_COORD_M`` = 1e4 m of the origin). Decoding anything malformed (wrong
tag or version, truncated, trailing bytes, non-finite or absurd floats, absurd or
negative lengths and counts, invalid utf-8, bad JSON) raises
:class:`MessageError` -- a ``ValueError`` with a one-line reason -- and nothing else.
Encoding a message whose fields cannot be sent raises :class:`MessageError` as well, so
what one side encodes the other side always decodes to an equal message.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, Final, TypeAlias

import numpy as np
import numpy.typing as npt

from runtime.wire.codec import (
    COMMAND_VERSION,
    HEADER,
    LEN32,
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
    json_object,
    read_text,
    uint,
    utf8,
)
from runtime.wire.fields import (
    COMMAND,
    MAX_BRAIN_ID_CHARS,
    MAX_MANIFEST_BYTES,
    MAX_ONNX_BYTES,
    MAX_PATTERN_NAME_BYTES,
    MAX_PATTERN_POINTS,
    MAX_POSES_ROBOTS,
    MAX_REQUEST_ID_BYTES,
    MAX_STATUS_BYTES,
    MAX_TARGET_ROBOTS,
    POSE,
    STATUS,
    UINT_MAX,
    Field,
)
from runtime.wire.pose_batch import PoseBatch, decode_poses, encode_poses
from runtime.wire.slots import (
    MAX_SLOTS_ROBOTS,
    NO_SLOT,
    Slots,
    check_slots,
    decode_slots,
    encode_slots,
)
from runtime.wire.view import MAX_VIEW_ROBOTS, View, check_view, decode_view, encode_view
from runtime.world_config import MAX_PATTERN_COORD_M

# The layouts below (struct formats, numpy records, the fields a decoder checks) follow from
# the field tables of runtime.wire.fields. The module docstring is the data of the wire schema
# records of patternrl-wire logs (sim_bridge.log.layout.WIRE_SCHEMA_DATA): keep it as is.

__all__ = [
    "COMMAND_HEAD_DTYPE",
    "COMMAND_HEAD_DTYPE_V1",
    "COMMAND_VERSION",
    "MAX_BRAIN_ID_CHARS",
    "MAX_MANIFEST_BYTES",
    "MAX_ONNX_BYTES",
    "MAX_PATTERN_COORD_M",
    "MAX_PATTERN_NAME_BYTES",
    "MAX_PATTERN_POINTS",
    "MAX_POSES_ROBOTS",
    "MAX_REQUEST_ID_BYTES",
    "MAX_SLOTS_ROBOTS",
    "MAX_STATUS_BYTES",
    "MAX_TARGET_ROBOTS",
    "MAX_VIEW_ROBOTS",
    "NO_SLOT",
    "POSE_DTYPE",
    "VERSION",
    "BrainMsg",
    "Buffer",
    "Command",
    "Message",
    "MessageError",
    "PatternMsg",
    "Pose",
    "PoseBatch",
    "Slots",
    "Status",
    "Tag",
    "View",
    "check_slots",
    "check_view",
    "command_dtype",
    "decode",
    "decode_brain",
    "decode_command",
    "decode_pattern",
    "decode_pose",
    "decode_poses",
    "decode_slots",
    "decode_status",
    "decode_view",
    "encode",
    "encode_brain",
    "encode_command",
    "encode_pattern",
    "encode_pose",
    "encode_poses",
    "encode_slots",
    "encode_status",
    "encode_view",
]

# -- Pose -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Pose:
    """World -> robot: where robot ``robot_id`` is at ``step``.

    ``n_live`` is how many robots are live in the world this step, so a robot in lockstep
    knows when it holds every pose of step ``step``.
    """

    robot_id: int
    step: int
    time_s: float
    x: float
    y: float
    vx: float
    vy: float
    n_live: int


assert POSE.names() == tuple(f.name for f in fields(Pose))
_POSE: Final = POSE.wire_struct()
POSE_DTYPE: Final = POSE.wire_dtype()
"""A pose payload as one numpy record: ``np.frombuffer(b"".join(payloads), POSE_DTYPE)``."""
_new: Final = object.__new__
_POSE_FLOATS: Final = tuple(f.name for f in POSE.fields if f.kind == "f64")


def _pose_bad_float(p: tuple[float, ...]) -> MessageError | None:
    for name, v in zip(_POSE_FLOATS, p, strict=True):
        if not math.isfinite(v):
            return MessageError(f"pose.{name} must be finite, got {v!r}")
    return None


def encode_pose(msg: Pose) -> bytes:
    """Encode a :class:`Pose` into 58 bytes."""
    isf = math.isfinite
    t, x, y, vx, vy = msg.time_s, msg.x, msg.y, msg.vx, msg.vy
    try:
        if not (isf(t) and isf(x) and isf(y) and isf(vx) and isf(vy)):
            raise _pose_bad_float((t, x, y, vx, vy)) or MessageError("pose: non-finite float")
        return _POSE.pack(Tag.POSE, VERSION, msg.robot_id, msg.step, t, x, y, vx, vy, msg.n_live)
    except (struct.error, TypeError) as e:
        raise MessageError(f"cannot encode pose: {e}") from None


def decode_pose(payload: Buffer) -> Pose:
    """Decode a payload written by :func:`encode_pose`."""
    try:
        tag, ver, rid, step, t, x, y, vx, vy, n_live = _POSE.unpack(payload)
    except (struct.error, TypeError, ValueError):
        view = as_view(payload, "pose")
        check_header(view, Tag.POSE)
        raise MessageError(f"pose must be {_POSE.size} bytes, got {len(view)}") from None
    if tag != Tag.POSE or ver != VERSION:
        check_header(as_view(payload, "pose"), Tag.POSE)
    isf = math.isfinite
    if not (isf(t) and isf(x) and isf(y) and isf(vx) and isf(vy)):
        raise _pose_bad_float((t, x, y, vx, vy)) or MessageError("pose: non-finite float")
    # Pose(...) without its frozen __init__ (eight object.__setattr__ calls, ~1 us of the
    # ~2 us a decode would take): fill the instance dict directly. Pose has no __post_init__.
    pose: Pose = _new(Pose)
    pose.__dict__.update(robot_id=rid, step=step, time_s=t, x=x, y=y, vx=vx, vy=vy, n_live=n_live)
    return pose


# -- Command --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Command:
    """Robot -> world: the velocity robot ``robot_id`` commands for ``step``.

    ``brain_id`` names the brain that decided (a sha256 hex prefix, at most 64 chars).
    ``safety_changed`` tells whether the safety filter altered the brain's output, by
    ``safety_change_mps``; ``decision_us`` is how long the decision took. ``brain_vx``,
    ``brain_vy`` (m/s) is what the brain asked for, before the clamp and the filter; left
    out (NaN), and in a version 1 payload, it is the command's own ``vx``, ``vy``.
    """

    robot_id: int
    step: int
    vx: float
    vy: float
    brain_id: str
    safety_changed: bool
    safety_change_mps: float
    decision_us: float
    brain_vx: float = math.nan
    brain_vy: float = math.nan

    def __post_init__(self) -> None:
        if self.brain_vx != self.brain_vx:  # NaN: not given
            object.__setattr__(self, "brain_vx", self.vx)
        if self.brain_vy != self.brain_vy:
            object.__setattr__(self, "brain_vy", self.vy)


assert set(COMMAND.names(COMMAND_VERSION)) == {f.name for f in fields(Command)}
_COMMAND: Final = COMMAND.wire_struct(COMMAND_VERSION)
_COMMAND_V1: Final = COMMAND.wire_struct(1)
COMMAND_HEAD_DTYPE: Final = COMMAND.wire_dtype(COMMAND_VERSION)
"""The fixed part of a command payload as one numpy record (the brain id follows it)."""
COMMAND_HEAD_DTYPE_V1: Final = COMMAND.wire_dtype(1)
"""The same for a version 1 payload (no brain_vx, brain_vy)."""
# the fixed part's floats, in layout order: what decode_command checks
_COMMAND_FLOATS: Final = tuple(f.name for f in COMMAND.at(COMMAND_VERSION) if f.kind == "f64")
assert COMMAND_HEAD_DTYPE.names == ("tag", "version", "robot_id", "step", "vx", "vy",
                                    "safety_changed", "safety_change_mps", "decision_us",
                                    "brain_vx", "brain_vy", "brain_len")


def command_dtype(brain_len: int, version: int = COMMAND_VERSION) -> np.dtype[np.void]:
    """A command payload of format ``version``, brain id ``brain_len`` bytes (``brain``)."""
    head = COMMAND_HEAD_DTYPE if version == COMMAND_VERSION else COMMAND_HEAD_DTYPE_V1
    return np.dtype([*head.descr, ("brain", f"S{brain_len}")]) if brain_len else head


_BRAIN_ID: Final = COMMAND["brain_id"]
_MAX_BRAIN_ID_BYTES: Final = _BRAIN_ID.max_bytes


def encode_command(msg: Command) -> bytes:
    """Encode a :class:`Command` (version 2): 65 bytes plus the utf-8 brain id."""
    w = "command"
    brain = utf8(w, "brain_id", msg.brain_id, _MAX_BRAIN_ID_BYTES, _BRAIN_ID.max_chars)
    if not isinstance(msg.safety_changed, bool):
        raise MessageError(
            f"command.safety_changed must be a bool, got {type(msg.safety_changed).__name__}"
        )
    try:
        head = _COMMAND.pack(
            Tag.COMMAND, COMMAND_VERSION, uint(w, "robot_id", msg.robot_id, U32),
            uint(w, "step", msg.step, U64), finite(w, "vx", msg.vx), finite(w, "vy", msg.vy),
            int(msg.safety_changed), finite(w, "safety_change_mps", msg.safety_change_mps),
            finite(w, "decision_us", msg.decision_us), finite(w, "brain_vx", msg.brain_vx),
            finite(w, "brain_vy", msg.brain_vy), len(brain))
    except (struct.error, TypeError) as e:
        raise MessageError(f"cannot encode command: {e}") from None
    return head + brain


def decode_command(payload: Buffer) -> Command:
    """Decode a payload written by :func:`encode_command`, of format version 1 or 2."""
    w = "command"
    view = as_view(payload, w)
    r = Reader(view, w, 0)
    if check_header(view, Tag.COMMAND) == 1:
        _, _, rid, step, vx, vy, changed, change, dec_us, n = r.unpack(_COMMAND_V1, "the head")
        bvx, bvy = vx, vy
    else:
        _, _, rid, step, vx, vy, changed, change, dec_us, bvx, bvy, n = r.unpack(
            _COMMAND, "the fixed part")
    if changed not in (0, 1):
        raise MessageError(f"command.safety_changed must be 0 or 1, got {changed}")
    for name, v in zip(_COMMAND_FLOATS, (vx, vy, change, dec_us, bvx, bvy), strict=True):
        finite(w, name, v)
    if n > _MAX_BRAIN_ID_BYTES:
        raise MessageError(f"command.brain_id claims {n} bytes, at most {_MAX_BRAIN_ID_BYTES}")
    brain = read_text(w, "brain_id", r.take(n, "brain_id"), _BRAIN_ID.max_chars)
    r.finish()
    return Command(rid, step, vx, vy, brain, bool(changed), change, dec_us, bvx, bvy)


# -- Status ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Status:
    """Robot -> anyone, about once a second: health of one robot.

    The ``swap_*`` fields and ``old_brain_id`` answer a brain swap request: they stay at
    their defaults ('' / False) when this status answers none.
    """

    robot_id: int
    step: int
    brain_id: str
    decision_latency_us_p50: float
    decision_latency_us_p99: float
    loop_jitter_ms: float
    messages_dropped: int
    errors: int
    safety_interventions: int
    last_error: str
    uptime_s: float
    swap_request_id: str = ""
    swap_accepted: bool = False
    swap_reason: str = ""
    old_brain_id: str = ""
    nonfinite_fallbacks: int = 0
    """Steps whose brain output was not finite, decided by the robot's fallback instead
    (``patternrl robot --nonfinite-fallback``); a status without the key (older robots) reads 0."""


_STATUS_OPTIONAL: Final = frozenset({"nonfinite_fallbacks"})
"""Status keys that may be missing (added later; their default then)."""
_STATUS_FIELDS: Final[dict[str, Field]] = {f.name: f for f in STATUS.fields}
assert tuple(_STATUS_FIELDS) == tuple(f.name for f in fields(Status))


def _status_field(name: str, value: object) -> object:
    """Check one status field; return it in its canonical Python type."""
    w = "status"
    field = _STATUS_FIELDS[name]
    kind = field.kind
    if kind in UINT_MAX:
        return uint(w, name, value, UINT_MAX[kind])
    if kind == "f64":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MessageError(f"status.{name} must be a number, got {type(value).__name__}")
        try:
            return finite(w, name, float(value))
        except OverflowError:
            raise MessageError(f"status.{name} is out of float range") from None
    if kind == "bool":
        if not isinstance(value, bool):
            raise MessageError(f"status.{name} must be a bool, got {type(value).__name__}")
        return value
    utf8(w, name, value, field.max_bytes, field.max_chars)
    return value


def encode_status(msg: Status) -> bytes:
    """Encode a :class:`Status` as tag, version and a compact utf-8 JSON object."""
    body = {name: _status_field(name, getattr(msg, name)) for name in _STATUS_FIELDS}
    raw = json.dumps(body, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    out = HEADER.pack(Tag.STATUS, VERSION) + raw.encode("utf-8")
    if len(out) > MAX_STATUS_BYTES:
        raise MessageError(
            f"status is {len(out)} bytes, at most {MAX_STATUS_BYTES}: trim last_error"
        )
    return out


def decode_status(payload: Buffer) -> Status:
    """Decode a payload written by :func:`encode_status`."""
    view = as_view(payload, "status")
    check_header(view, Tag.STATUS)
    if len(view) > MAX_STATUS_BYTES:
        raise MessageError(f"status is {len(view)} bytes, at most {MAX_STATUS_BYTES}")
    text = read_text("status", "body", view[2:])
    body = json_object("status", text)
    missing = [k for k in _STATUS_FIELDS if k not in body and k not in _STATUS_OPTIONAL]
    if missing:
        raise MessageError(f"status JSON lacks {', '.join(missing)}")
    extra = sorted(k for k in body if k not in _STATUS_FIELDS)
    if extra:
        raise MessageError(f"status JSON has unknown keys {', '.join(map(repr, extra))}")
    return Status(**{name: _status_field(name, body[name])  # type: ignore[arg-type]
                     for name in _STATUS_FIELDS if name in body})


# -- Pattern --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class PatternMsg:
    """Operator/world -> all: the current target pattern.

    ``version`` grows monotonically with every new pattern. ``points`` is an (n, 2) float64
    array of target slots (n may be 0); it is copied and made read-only on construction.
    """

    version: int
    name: str
    points: npt.NDArray[np.float64]
    formed_tol_m: float

    def __post_init__(self) -> None:
        try:
            pts = np.array(self.points, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise MessageError(f"pattern.points is not an array of floats: {e}") from None
        if pts.size == 0:
            pts = pts.reshape(0, 2)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise MessageError(f"pattern.points must have shape (n, 2), got {pts.shape}")
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PatternMsg):
            return NotImplemented
        return (
            self.version == other.version
            and self.name == other.name
            and self.formed_tol_m == other.formed_tol_m
            and np.array_equal(self.points, other.points)
        )

    __hash__ = None  # type: ignore[assignment]


_PATTERN: Final = struct.Struct("<BBQdHI")


def encode_pattern(msg: PatternMsg) -> bytes:
    """Encode a :class:`PatternMsg`: 24 bytes, the utf-8 name, then n x 2 float64."""
    w = "pattern"
    name = utf8(w, "name", msg.name, MAX_PATTERN_NAME_BYTES)
    pts = msg.points
    n = pts.shape[0]
    if n > MAX_PATTERN_POINTS:
        raise MessageError(f"pattern has {n} points, at most {MAX_PATTERN_POINTS}")
    _check_points(pts)
    tol = finite(w, "formed_tol_m", msg.formed_tol_m)
    if tol < 0:
        raise MessageError(f"pattern.formed_tol_m must be >= 0, got {tol!r}")
    try:
        head = _PATTERN.pack(
            Tag.PATTERN, VERSION, uint(w, "version", msg.version, U64), tol, len(name), n
        )
    except (struct.error, TypeError) as e:
        raise MessageError(f"cannot encode pattern: {e}") from None
    return head + name + pts.astype("<f8", copy=False).tobytes()


def decode_pattern(payload: Buffer) -> PatternMsg:
    """Decode a payload written by :func:`encode_pattern`."""
    w = "pattern"
    view = as_view(payload, w)
    check_header(view, Tag.PATTERN)
    r = Reader(view, w, 0)
    _, _, version, tol, name_len, n = r.unpack(_PATTERN, "the fixed part")
    finite(w, "formed_tol_m", tol)
    if tol < 0:
        raise MessageError(f"pattern.formed_tol_m must be >= 0, got {tol!r}")
    if name_len > MAX_PATTERN_NAME_BYTES:
        raise MessageError(
            f"pattern.name claims {name_len} bytes, at most {MAX_PATTERN_NAME_BYTES}"
        )
    if n > MAX_PATTERN_POINTS:
        raise MessageError(f"pattern claims {n} points, at most {MAX_PATTERN_POINTS}")
    name = read_text(w, "name", r.take(name_len, "name"))
    raw = r.take(16 * n, "points")
    r.finish()
    pts = np.frombuffer(raw, dtype="<f8").reshape(n, 2)
    _check_points(pts)
    return PatternMsg(version, name, pts, tol)


def _check_points(pts: npt.NDArray[np.float64]) -> None:
    if not np.isfinite(pts).all():
        raise MessageError("pattern.points must all be finite")
    far = float(np.abs(pts).max(initial=0.0))
    if far > MAX_PATTERN_COORD_M:
        raise MessageError(
            f"pattern.points reach {far:g} m from the origin, at most {MAX_PATTERN_COORD_M:g}"
        )


# -- Brain ----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BrainMsg:
    """Operator -> robots: a new brain to swap in.

    ``manifest_json`` is carried as text, unparsed: the brain loader judges it.
    ``target_robots`` lists the robots that should swap; empty means all of them.
    """

    request_id: str
    manifest_json: str
    onnx_bytes: bytes
    target_robots: tuple[int, ...] = ()


def encode_brain(msg: BrainMsg) -> bytes:
    """Encode a :class:`BrainMsg`: header, then uint32-length-prefixed fields."""
    w = "brain"
    req = utf8(w, "request_id", msg.request_id, MAX_REQUEST_ID_BYTES)
    manifest = utf8(w, "manifest_json", msg.manifest_json, MAX_MANIFEST_BYTES)
    onnx = msg.onnx_bytes
    if not isinstance(onnx, (bytes, bytearray, memoryview)):
        raise MessageError(f"brain.onnx_bytes must be bytes, got {type(onnx).__name__}")
    onnx = bytes(onnx)
    if len(onnx) > MAX_ONNX_BYTES:
        raise MessageError(f"brain.onnx_bytes is {len(onnx)} bytes, at most {MAX_ONNX_BYTES}")
    targets = msg.target_robots
    if not isinstance(targets, tuple):
        raise MessageError(f"brain.target_robots must be a tuple, got {type(targets).__name__}")
    if len(targets) > MAX_TARGET_ROBOTS:
        raise MessageError(f"brain targets {len(targets)} robots, at most {MAX_TARGET_ROBOTS}")
    ids = [uint(w, "target_robots[]", t, U32) for t in targets]
    if len(set(ids)) != len(ids):
        raise MessageError("brain.target_robots repeats a robot id")
    return b"".join(
        (
            HEADER.pack(Tag.BRAIN, VERSION),
            LEN32.pack(len(req)),
            req,
            LEN32.pack(len(manifest)),
            manifest,
            LEN32.pack(len(onnx)),
            onnx,
            LEN32.pack(len(ids)),
            struct.pack(f"<{len(ids)}I", *ids),
        )
    )


def decode_brain(payload: Buffer) -> BrainMsg:
    """Decode a payload written by :func:`encode_brain`."""
    w = "brain"
    view = as_view(payload, w)
    check_header(view, Tag.BRAIN)
    r = Reader(view, w, HEADER.size)

    def chunk(name: str, limit: int) -> memoryview:
        (n,) = r.unpack(LEN32, f"len({name})")
        if n > limit:
            raise MessageError(f"brain.{name} claims {n} bytes, at most {limit}")
        return r.take(n, name)

    req = read_text(w, "request_id", chunk("request_id", MAX_REQUEST_ID_BYTES))
    manifest = read_text(w, "manifest_json", chunk("manifest_json", MAX_MANIFEST_BYTES))
    onnx = bytes(chunk("onnx_bytes", MAX_ONNX_BYTES))
    (n,) = r.unpack(LEN32, "len(target_robots)")
    if n > MAX_TARGET_ROBOTS:
        raise MessageError(f"brain claims {n} target robots, at most {MAX_TARGET_ROBOTS}")
    targets = struct.unpack(f"<{n}I", r.take(4 * n, "target_robots"))
    r.finish()
    if len(set(targets)) != n:
        raise MessageError("brain.target_robots repeats a robot id")
    return BrainMsg(req, manifest, onnx, targets)


# -- any message ----------------------------------------------------------------------------

Message: TypeAlias = Pose | Command | Status | PatternMsg | BrainMsg | PoseBatch | View | Slots

_ENCODERS: Final[dict[type, Callable[[Any], bytes]]] = {
    Pose: encode_pose,
    Command: encode_command,
    Status: encode_status,
    PatternMsg: encode_pattern,
    BrainMsg: encode_brain,
    PoseBatch: encode_poses,
    View: encode_view,
    Slots: encode_slots,
}

_DECODERS: Final[dict[int, Callable[[Buffer], Message]]] = {
    Tag.POSE: decode_pose,
    Tag.COMMAND: decode_command,
    Tag.STATUS: decode_status,
    Tag.PATTERN: decode_pattern,
    Tag.BRAIN: decode_brain,
    Tag.POSES: decode_poses,
    Tag.VIEW: decode_view,
    Tag.SLOTS: decode_slots,
}


def encode(msg: Message) -> bytes:
    """Encode any message; the leading tag tells :func:`decode` which one it is."""
    encoder = _ENCODERS.get(type(msg))
    if encoder is None:
        raise MessageError(f"cannot encode {type(msg).__name__}: not a message")
    return encoder(msg)


def decode(payload: Buffer) -> Message:
    """Decode any message, dispatching on its leading tag byte."""
    view = payload if type(payload) is bytes else as_view(payload, "message")
    if not view:
        raise MessageError("empty payload: no message tag")
    decoder = _DECODERS.get(view[0])
    if decoder is None:
        raise MessageError(f"unknown message tag {view[0]}")
    return decoder(view)
