"""Wire messages and Zenoh key expressions: round trips, refusals, fuzzing."""

from __future__ import annotations

import dataclasses
import json
import math
import struct
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.wire import fields as wf
from runtime.wire import keys, pose_batch
from runtime.wire import messages as m
from runtime.wire.messages import (
    BrainMsg,
    Command,
    Message,
    MessageError,
    PatternMsg,
    Pose,
    Status,
    Tag,
)

FUZZ = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])

BRAIN_ID = "3f2a9c0b1d4e5f60718293a4b5c6d7e8f90123456789abcdef0123456789abcd"  # 64 hex chars

SAMPLES: dict[str, Message] = {
    "pose": Pose(3, 120, 12.0, 1.5, -2.25, 0.5, -0.5, 20),
    "pose-zero": Pose(0, 0, 0.0, 0.0, -0.0, 0.0, 0.0, 0),
    "pose-extremes": Pose(
        2**32 - 1, 2**64 - 1, 1e300, -1e-300, 5e-324, 1.7e308, -1.7e308, 2**32 - 1
    ),
    "command": Command(7, 41, 0.3, -0.8, BRAIN_ID[:12], True, 0.125, 87.5),
    "command-empty-brain": Command(0, 0, 0.0, 0.0, "", False, 0.0, 0.0),
    "command-64-brain": Command(1, 2, 1.0, -1.0, BRAIN_ID, False, 0.0, 1e6),
    "command-unicode-brain": Command(1, 2, 1.0, -1.0, "cerveau-é-脑-🧠", False, 0.0, 3.0),
    "command-brain-velocity": Command(5, 9, 0.2, 0.0, "rule:assign", True, 1.1, 40.0, 1.3, -0.4),
    "status": Status(
        robot_id=4,
        step=900,
        brain_id=BRAIN_ID[:16],
        decision_latency_us_p50=120.5,
        decision_latency_us_p99=480.0,
        loop_jitter_ms=0.8,
        messages_dropped=3,
        errors=1,
        safety_interventions=12,
        last_error="TimeoutError: no pose for step 899",
        uptime_s=91.25,
    ),
    "status-swap": Status(
        robot_id=0,
        step=0,
        brain_id="",
        decision_latency_us_p50=0.0,
        decision_latency_us_p99=0.0,
        loop_jitter_ms=0.0,
        messages_dropped=0,
        errors=0,
        safety_interventions=0,
        last_error='multi\nline "quoted" \\ ünïcödé 🧠',
        uptime_s=0.0,
        swap_request_id="req-42",
        swap_accepted=True,
        swap_reason="accepted: manifest ok",
        old_brain_id=BRAIN_ID,
    ),
    "pattern": PatternMsg(3, "circle", np.array([[0.0, 0.4], [0.4, 0.0], [-1.5, 2.25]]), 0.025),
    "pattern-empty": PatternMsg(0, "", np.zeros((0, 2)), 0.0),
    "pattern-unicode": PatternMsg(2**64 - 1, "cercle ◯ 圆", np.array([[1.0, 2.0]]), 0.1),
    "brain": BrainMsg("req-1", '{"obs_dim": 10, "act_dim": 2}', b"\x08\x07onnx\x00", (1, 5, 9)),
    "brain-all-robots": BrainMsg("", "", b"", ()),
    "brain-unicode": BrainMsg("requête-é", '{"name": "脑"}', b"\xff" * 3, (2**32 - 1,)),
    "brain-300kb": BrainMsg(
        "big", "{}", np.random.default_rng(0).bytes(300 * 1024), tuple(range(100))
    ),
}

SMALL = {k: v for k, v in SAMPLES.items() if k != "brain-300kb"}

PER_TYPE: dict[type, tuple[Callable[[Any], bytes], Callable[[bytes], Message]]] = {
    Pose: (m.encode_pose, m.decode_pose),
    Command: (m.encode_command, m.decode_command),
    Status: (m.encode_status, m.decode_status),
    PatternMsg: (m.encode_pattern, m.decode_pattern),
    BrainMsg: (m.encode_brain, m.decode_brain),
}
DECODERS: list[Callable[[bytes], Message]] = [m.decode, *(dec for _, dec in PER_TYPE.values())]


def _decodes_or_refuses(payload: bytes) -> None:
    """Every decoder either returns a message or raises MessageError, nothing else."""
    for dec in DECODERS:
        try:
            msg = dec(payload)
        except MessageError as e:
            assert "\n" not in str(e) and str(e)
        else:
            # Whatever decodes also re-encodes, to an equal message.
            assert m.decode(m.encode(msg)) == msg


# -- round trips ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SAMPLES))
def test_round_trip(name: str) -> None:
    msg = SAMPLES[name]
    encode_one, decode_one = PER_TYPE[type(msg)]
    payload = m.encode(msg)
    assert payload == encode_one(msg)
    assert payload[0] == Tag[type(msg).__name__.upper().removesuffix("MSG")]
    assert payload[1] == (m.COMMAND_VERSION if isinstance(msg, Command) else m.VERSION)
    back = m.decode(payload)
    assert type(back) is type(msg)
    assert back == msg
    assert decode_one(payload) == msg
    assert m.encode(back) == payload
    assert m.decode(bytearray(payload)) == msg
    assert m.decode(memoryview(payload)) == msg


def test_pose_is_compact_and_fixed_size() -> None:
    assert len(m.encode(SAMPLES["pose"])) == 58
    assert len(m.encode(SAMPLES["pose-extremes"])) == 58


def test_pose_keeps_float64() -> None:
    pose = Pose(1, 1, 0.1, 0.1 + 1e-15, 1 / 3, math.pi, -math.e, 1)
    assert m.decode(m.encode(pose)) == pose


def test_pattern_points_are_a_readonly_float64_copy() -> None:
    src = np.array([[1, 2], [3, 4]], dtype=np.int32)
    msg = PatternMsg(1, "sq", src, 0.1)  # type: ignore[arg-type]
    src[0, 0] = 99
    assert msg.points.dtype == np.float64 and msg.points.shape == (2, 2)
    assert msg.points[0, 0] == 1.0
    with pytest.raises(ValueError):
        msg.points[0, 0] = 5.0
    back = m.decode_pattern(m.encode(msg))
    assert back.points.dtype == np.float64 and not back.points.flags.writeable
    assert back == msg and back != PatternMsg(1, "sq", np.array([[1.0, 2], [3, 5]]), 0.1)


def test_messages_are_frozen() -> None:
    pose = Pose(3, 120, 12.0, 1.5, -2.25, 0.5, -0.5, 20)
    with pytest.raises(AttributeError):
        pose.x = 1.0  # type: ignore[misc]
    assert hash(m.decode(m.encode(pose))) == hash(pose)


@FUZZ
@given(
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**64 - 1),
    st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=5, max_size=5),
    st.integers(0, 2**32 - 1),
)
def test_pose_round_trip_any(rid: int, step: int, fl: list[float], n_live: int) -> None:
    pose = Pose(rid, step, fl[0], fl[1], fl[2], fl[3], fl[4], n_live)
    assert m.decode_pose(m.encode_pose(pose)) == pose


@FUZZ
@given(
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**64 - 1),
    st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=6, max_size=6),
    st.text(max_size=64),
    st.booleans(),
)
def test_command_round_trip_any(
    rid: int, step: int, fl: list[float], brain: str, changed: bool
) -> None:
    try:
        brain.encode("utf-8")
    except UnicodeEncodeError:
        return  # lone surrogates: refused at encode, tested elsewhere
    cmd = Command(rid, step, fl[0], fl[1], brain, changed, fl[2], fl[3], fl[4], fl[5])
    assert m.decode_command(m.encode_command(cmd)) == cmd


def _command_v1(c: Command) -> bytes:
    """``c`` as a format version 1 payload (written before the brain velocity)."""
    brain = c.brain_id.encode()
    return struct.pack("<BBIQddBddH", Tag.COMMAND, 1, c.robot_id, c.step, c.vx, c.vy,
                       int(c.safety_changed), c.safety_change_mps, c.decision_us,
                       len(brain)) + brain


def test_command_carries_the_brain_velocity() -> None:
    cmd = SAMPLES["command-brain-velocity"]
    assert isinstance(cmd, Command)
    raw = m.encode_command(cmd)
    assert raw[:2] == bytes([Tag.COMMAND, 2]) and len(raw) == 65 + len(cmd.brain_id)
    back = m.decode_command(raw)
    assert (back.brain_vx, back.brain_vy) == (1.3, -0.4) and (back.vx, back.vy) == (0.2, 0.0)
    # left out, the brain velocity is the command's own
    plain = Command(1, 2, 0.5, -0.25, "b", False, 0.0, 1.0)
    assert (plain.brain_vx, plain.brain_vy) == (0.5, -0.25)
    assert m.decode_command(m.encode_command(plain)) == plain


@pytest.mark.parametrize("name", [n for n in SAMPLES if n.startswith("command")])
def test_version_1_commands_still_decode(name: str) -> None:
    """A version 1 payload decodes, its brain velocity read as its vx, vy."""
    cmd = SAMPLES[name]
    assert isinstance(cmd, Command)
    old = _command_v1(cmd)
    assert len(old) == len(m.encode_command(cmd)) - 16
    back = m.decode(old)
    assert isinstance(back, Command)
    assert back == Command(cmd.robot_id, cmd.step, cmd.vx, cmd.vy, cmd.brain_id,
                           cmd.safety_changed, cmd.safety_change_mps, cmd.decision_us)
    assert (back.brain_vx, back.brain_vy) == (cmd.vx, cmd.vy)
    (r,) = np.frombuffer(old, m.command_dtype(len(old) - m.COMMAND_HEAD_DTYPE_V1.itemsize, 1))
    assert r["version"] == 1 and r["vx"] == cmd.vx and "brain_vx" not in (r.dtype.names or ())


def test_numpy_columns_read_what_the_encoders_write() -> None:
    """POSE_DTYPE and command_dtype view a batch of payloads as the decoders read each one."""
    poses = [s for s in SAMPLES.values() if isinstance(s, Pose)]
    rec = np.frombuffer(b"".join(m.encode(p) for p in poses), m.POSE_DTYPE)
    assert m.POSE_DTYPE.itemsize == len(m.encode(poses[0]))
    assert (rec["tag"] == Tag.POSE).all() and (rec["version"] == m.VERSION).all()
    for name in m.POSE_DTYPE.names or ():
        if name not in ("tag", "version"):
            assert rec[name].tolist() == [getattr(p, name) for p in poses], name
    cmds = [s for s in SAMPLES.values() if isinstance(s, Command)]
    for c in cmds:
        raw = m.encode(c)
        dt = m.command_dtype(len(raw) - m.COMMAND_HEAD_DTYPE.itemsize)
        (r,) = np.frombuffer(raw, dt)
        assert dt.itemsize == len(raw) and r["tag"] == Tag.COMMAND
        assert (r["robot_id"], r["step"], r["vx"], r["vy"]) == (c.robot_id, c.step, c.vx, c.vy)
        assert (bool(r["safety_changed"]), r["safety_change_mps"], r["decision_us"]) == (
            c.safety_changed, c.safety_change_mps, c.decision_us)
        brain = bytes(r["brain"]).decode() if "brain" in (dt.names or ()) else ""
        assert r["brain_len"] == len(c.brain_id.encode()) and brain == c.brain_id
        assert (r["brain_vx"], r["brain_vy"]) == (c.brain_vx, c.brain_vy)


def test_field_tables_give_todays_wire_formats() -> None:
    """The struct formats and numpy layouts derived from the field tables: the bytes on the
    wire are these (a table edit that moves a byte fails here), sizes equal itemsizes."""
    want = {(wf.POSE, 1): "<BBIQdddddI", (wf.COMMAND, 1): "<BBIQddBddH",
            (wf.COMMAND, 2): "<BBIQddBddddH", (wf.POSES_HEAD, 1): "<BBQdI",
            (wf.POSES_ROW, 1): "<Idddd"}
    for (table, version), fmt in want.items():
        st_, dt = table.wire_struct(version), table.wire_dtype(version)
        assert st_.format == fmt and st_.size == dt.itemsize, (table.name, version)
        assert dt.names == tuple(name for name, _ in table.wire_layout(version))
    assert m.POSE_DTYPE == wf.POSE.wire_dtype() and m.POSE_DTYPE.itemsize == 58
    assert m.COMMAND_HEAD_DTYPE.itemsize == 65 and m.COMMAND_HEAD_DTYPE_V1.itemsize == 49
    assert m.command_dtype(0, 1) == m.COMMAND_HEAD_DTYPE_V1
    assert m.command_dtype(5).itemsize == 70 and m.command_dtype(5).names[-2:] == (
        "brain_len", "brain")
    assert pose_batch.POSES_ROW_DTYPE.itemsize == 36
    # the tables and the dataclasses name the same fields
    assert wf.POSE.names() == tuple(f.name for f in dataclasses.fields(Pose))
    assert wf.STATUS.names() == tuple(f.name for f in dataclasses.fields(Status))
    assert set(wf.COMMAND.names(2)) == {f.name for f in dataclasses.fields(Command)}
    assert set(wf.COMMAND.names(2)) - set(wf.COMMAND.names(1)) == {"brain_vx", "brain_vy"}
    with pytest.raises(ValueError, match="repeated"):
        wf.PATTERN.wire_struct()


def test_the_codecs_check_the_bounds_of_the_tables() -> None:
    brain = wf.COMMAND["brain_id"]
    assert (brain.max_chars, brain.max_bytes) == (m.MAX_BRAIN_ID_CHARS, 4 * m.MAX_BRAIN_ID_CHARS)
    too_long = Command(1, 2, 0.0, 0.0, "x" * (brain.max_chars + 1), False, 0.0, 0.0)
    with pytest.raises(MessageError, match=f"at most {brain.max_chars}"):
        m.encode_command(too_long)
    tol = wf.PATTERN["formed_tol_m"]
    assert tol.lo == 0.0
    with pytest.raises(MessageError, match=">= 0"):
        m.encode_pattern(PatternMsg(1, "p", np.zeros((1, 2)), -0.5))
    far = wf.PATTERN["x"].hi
    assert far == m.MAX_PATTERN_COORD_M
    with pytest.raises(MessageError, match="from the origin"):
        m.encode_pattern(PatternMsg(1, "p", [[2 * far, 0.0]], 0.1))
    status = SAMPLES["status"]
    assert isinstance(status, Status)
    with pytest.raises(MessageError, match="old_brain_id"):
        m.encode_status(dataclasses.replace(status, old_brain_id="y" * 65))


# -- refusals at encode ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "msg",
    [
        Pose(1, 1, 0.0, math.nan, 0.0, 0.0, 0.0, 1),
        Pose(1, 1, math.inf, 0.0, 0.0, 0.0, 0.0, 1),
        Pose(-1, 1, 0.0, 0.0, 0.0, 0.0, 0.0, 1),
        Pose(1, -1, 0.0, 0.0, 0.0, 0.0, 0.0, 1),
        Pose(2**32, 1, 0.0, 0.0, 0.0, 0.0, 0.0, 1),
        Pose(1, 1, 0.0, 0.0, 0.0, 0.0, 0.0, -3),
        Pose(1.5, 1, 0.0, 0.0, 0.0, 0.0, 0.0, 1),  # type: ignore[arg-type]
        Pose(1, 1, "0", 0.0, 0.0, 0.0, 0.0, 1),  # type: ignore[arg-type]
        Command(1, 1, math.nan, 0.0, "", False, 0.0, 0.0),
        Command(1, 1, 0.0, 0.0, "", False, 0.0, -math.inf),
        Command(1, 1, 0.0, 0.0, "x" * 65, False, 0.0, 0.0),
        Command(1, 1, 0.0, 0.0, "\ud800", False, 0.0, 0.0),
        Command(1, 1, 0.0, 0.0, "", 1, 0.0, 0.0),  # type: ignore[arg-type]
        Command(-1, 1, 0.0, 0.0, "", False, 0.0, 0.0),
        Command(1, 1, 0.0, 0.0, "", False, 0.0, 0.0, math.inf, 0.0),
        Command(1, 1, 0.0, 0.0, "", False, 0.0, 0.0, 0.0, -math.inf),
        Status(1, 1, "", math.nan, 0.0, 0.0, 0, 0, 0, "", 0.0),
        Status(1, 1, "", 0.0, 0.0, 0.0, -1, 0, 0, "", 0.0),
        Status(1, 1, "", 0.0, 0.0, 0.0, 0, True, 0, "", 0.0),
        Status(1, 1, "x" * 65, 0.0, 0.0, 0.0, 0, 0, 0, "", 0.0),
        Status(1, 1, "", 0.0, 0.0, 0.0, 0, 0, 0, "e" * 70_000, 0.0),
        Status(1, 1, "", 0.0, 0.0, 0.0, 0, 0, 0, "", 0.0, swap_accepted=1),  # type: ignore[arg-type]
        PatternMsg(1, "p", np.array([[0.0, math.nan]]), 0.1),
        PatternMsg(1, "p", np.zeros((1, 2)), -0.1),
        PatternMsg(-1, "p", np.zeros((1, 2)), 0.1),
        PatternMsg(1, "n" * 2000, np.zeros((1, 2)), 0.1),
        BrainMsg("r", "{}", b"", (1, 1)),
        BrainMsg("r", "{}", b"", (-1,)),
        BrainMsg("r", "{}", "not bytes", ()),  # type: ignore[arg-type]
        BrainMsg("r" * 300, "{}", b"", ()),
    ],
)
def test_encode_refuses_unsendable(msg: Message) -> None:
    with pytest.raises(MessageError):
        m.encode(msg)


def test_encode_refuses_non_message() -> None:
    with pytest.raises(MessageError, match="not a message"):
        m.encode(42)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "points", [[1.0, 2.0], [[1.0, 2.0, 3.0]], "abc", [[1.0, "x"]], [[1.0, object()]]]
)
def test_pattern_refuses_bad_points(points: object) -> None:
    with pytest.raises(MessageError):
        PatternMsg(1, "p", points, 0.1)  # type: ignore[arg-type]


# -- refusals at decode ---------------------------------------------------------------------


def _status_payload(body: object, raw: bytes | None = None) -> bytes:
    text = raw if raw is not None else json.dumps(body).encode()
    return bytes([Tag.STATUS, m.VERSION]) + text


def _status_body(**changes: object) -> dict[str, object]:
    body: dict[str, object] = json.loads(m.encode(SAMPLES["status"])[2:])
    body.update(changes)
    return body


_GOOD_POSE = m.encode(SAMPLES["pose"])
_GOOD_CMD = m.encode(SAMPLES["command"])
_GOOD_BRAIN = m.encode(SAMPLES["brain"])

BAD_PAYLOADS: dict[str, bytes] = {
    "empty": b"",
    "tag only": bytes([Tag.POSE]),
    "unknown tag": bytes([0, 1]) + _GOOD_POSE[2:],
    "unknown tag 255": bytes([255, 1]),
    "version 0": _GOOD_POSE[:1] + b"\x00" + _GOOD_POSE[2:],
    "version 2": _GOOD_POSE[:1] + b"\x02" + _GOOD_POSE[2:],
    "pose truncated": _GOOD_POSE[:-1],
    "pose trailing": _GOOD_POSE + b"\x00",
    "pose nan": struct.pack("<BBIQdddddI", 1, 1, 0, 0, 0.0, math.nan, 0.0, 0.0, 0.0, 1),
    "pose -inf": struct.pack("<BBIQdddddI", 1, 1, 0, 0, 0.0, 0.0, 0.0, 0.0, -math.inf, 1),
    "command inf": struct.pack("<BBIQddBddH", 2, 1, 0, 0, math.inf, 0.0, 0, 0.0, 0.0, 0),
    "command nan decision": struct.pack("<BBIQddBddH", 2, 1, 0, 0, 0.0, 0.0, 0, 0.0, math.nan, 0),
    "command bool 2": struct.pack("<BBIQddBddH", 2, 1, 0, 0, 0.0, 0.0, 2, 0.0, 0.0, 0),
    "command brain too long": struct.pack("<BBIQddBddH", 2, 1, 0, 0, 0.0, 0.0, 0, 0.0, 0.0, 65535)
    + b"a" * 65535,
    "command version 3": bytes([Tag.COMMAND, 3]) + _GOOD_CMD[2:],
    "command brain_vx nan": struct.pack("<BBIQddBddddH", 2, 2, 0, 0, 0.0, 0.0, 0, 0.0, 0.0,
                                        math.nan, 0.0, 0),
    "command v2 as v1": bytes([Tag.COMMAND, 1]) + _GOOD_CMD[2:],
    "command v1 as v2": struct.pack("<BBIQddBddH", 2, 2, 0, 0, 0.0, 0.0, 0, 0.0, 0.0, 0),
    "command 65 chars": struct.pack("<BBIQddBddH", 2, 1, 0, 0, 0.0, 0.0, 0, 0.0, 0.0, 65)
    + b"a" * 65,
    "command bad utf-8": struct.pack("<BBIQddBddH", 2, 1, 0, 0, 0.0, 0.0, 0, 0.0, 0.0, 2)
    + b"\xc3\x28",
    "command trailing": _GOOD_CMD + b"x",
    "command short brain": _GOOD_CMD[:-1],
    "status not utf-8": _status_payload(None, b'{"a": "\xff"}'),
    "status not json": _status_payload(None, b"{robot_id: 1"),
    "status empty": _status_payload(None, b""),
    "status list": _status_payload([1, 2]),
    "status nan": _status_payload(None, json.dumps(_status_body(uptime_s=math.nan)).encode()),
    "status infinity": _status_payload(
        None, json.dumps(_status_body(loop_jitter_ms=math.inf)).encode()
    ),
    "status negative count": _status_payload(_status_body(errors=-1)),
    "status negative robot": _status_payload(_status_body(robot_id=-4)),
    "status float count": _status_payload(_status_body(messages_dropped=1.0)),
    "status bool count": _status_payload(_status_body(errors=True)),
    "status string float": _status_payload(_status_body(uptime_s="1.0")),
    "status huge float": _status_payload(
        None,
        json.dumps(_status_body(uptime_s=0))
        .replace('"uptime_s": 0', '"uptime_s": 1' + "0" * 400)
        .encode(),
    ),
    "status huge int digits": _status_payload(
        None,
        json.dumps(_status_body(errors=0))
        .replace('"errors": 0', '"errors": 1' + "0" * 5000)
        .encode(),
    ),
    "status missing key": _status_payload(
        {k: v for k, v in _status_body().items() if k != "uptime_s"}
    ),
    "status extra key": _status_payload(_status_body(color="red")),
    "status duplicate key": _status_payload(
        None, json.dumps(_status_body())[:-1].encode() + b', "errors": 2}'
    ),
    "status surrogate": _status_payload(
        None,
        json.dumps(_status_body())[:-1]
        .replace('"last_error": "', '"last_error": "\\ud800')
        .encode()
        + b"}",
    ),
    "status deep nesting": _status_payload(None, b"[" * 30_000 + b"]" * 30_000),
    "status too large": _status_payload(None, b" " * m.MAX_STATUS_BYTES),
    "pattern absurd points": struct.pack("<BBQdHI", 4, 1, 1, 0.1, 0, 0xFFFFFFFF),
    "pattern short points": struct.pack("<BBQdHI", 4, 1, 1, 0.1, 0, 2) + b"\x00" * 31,
    "pattern trailing": struct.pack("<BBQdHI", 4, 1, 1, 0.1, 0, 1) + b"\x00" * 17,
    "pattern nan point": struct.pack("<BBQdHI", 4, 1, 1, 0.1, 0, 1)
    + struct.pack("<dd", 0.0, math.nan),
    "pattern nan tol": struct.pack("<BBQdHI", 4, 1, 1, math.nan, 0, 0),
    "pattern negative tol": struct.pack("<BBQdHI", 4, 1, 1, -1.0, 0, 0),
    "pattern name too long": struct.pack("<BBQdHI", 4, 1, 1, 0.1, 65535, 0) + b"a" * 65535,
    "pattern bad utf-8": struct.pack("<BBQdHI", 4, 1, 1, 0.1, 1, 0) + b"\x80",
    "brain absurd length": bytes([5, 1]) + struct.pack("<I", 0xFFFFFFFF),
    "brain length past end": bytes([5, 1]) + struct.pack("<I", 10) + b"abc",
    "brain bad utf-8 request": bytes([5, 1]) + struct.pack("<I", 1) + b"\xfe",
    "brain absurd target count": _GOOD_BRAIN[: -4 * 3 - 4] + struct.pack("<I", 0xFFFFFFFF),
    "brain duplicate targets": _GOOD_BRAIN[: -4 * 3 - 4] + struct.pack("<I3I", 3, 1, 1, 2),
    "brain trailing": _GOOD_BRAIN + b"\x00",
    "brain truncated": _GOOD_BRAIN[:-2],
}


@pytest.mark.parametrize("name", list(BAD_PAYLOADS))
def test_decode_refuses_malformed(name: str) -> None:
    payload = BAD_PAYLOADS[name]
    for dec in DECODERS:
        with pytest.raises(MessageError) as info:
            dec(payload)
        assert type(info.value) is MessageError
        assert str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("name", list(SMALL))
def test_decoder_of_another_type_refuses(name: str) -> None:
    payload = m.encode(SAMPLES[name])
    for cls, (_, dec) in PER_TYPE.items():
        if cls is type(SAMPLES[name]):
            continue
        with pytest.raises(MessageError, match="expected"):
            dec(payload)


@pytest.mark.parametrize("payload", ["text", 12, None, [1, 1], np.zeros((2, 2))[:, 0]])
def test_decode_refuses_non_bytes(payload: object) -> None:
    for dec in DECODERS:
        with pytest.raises(MessageError):
            dec(payload)  # type: ignore[arg-type]


def test_error_messages_say_what_is_wrong() -> None:
    with pytest.raises(MessageError, match=r"expected pose \(tag 1\), got command \(tag 2\)"):
        m.decode_pose(_GOOD_CMD)
    with pytest.raises(MessageError, match="version 2"):
        m.decode(BAD_PAYLOADS["version 2"])
    with pytest.raises(MessageError, match=r"unsupported command version 3 \(this build reads "
                                           r"1 or 2\)"):
        m.decode(BAD_PAYLOADS["command version 3"])
    with pytest.raises(MessageError, match=r"command\.brain_vx must be finite"):
        m.decode(BAD_PAYLOADS["command brain_vx nan"])
    with pytest.raises(MessageError, match="pose must be 58 bytes, got 57"):
        m.decode(BAD_PAYLOADS["pose truncated"])
    with pytest.raises(MessageError, match=r"pose\.x must be finite"):
        m.decode(BAD_PAYLOADS["pose nan"])
    with pytest.raises(MessageError, match="trailing"):
        m.decode(BAD_PAYLOADS["brain trailing"])
    with pytest.raises(MessageError, match="unknown message tag 0"):
        m.decode(BAD_PAYLOADS["unknown tag"])


def test_message_error_is_value_error() -> None:
    assert issubclass(MessageError, ValueError)


# -- mutation and fuzzing -------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SMALL))
def test_every_truncation_refused(name: str) -> None:
    payload = m.encode(SAMPLES[name])
    for cut in range(len(payload)):
        for dec in DECODERS:
            with pytest.raises(MessageError):
                dec(payload[:cut])


def test_large_brain_truncations_refused() -> None:
    payload = m.encode(SAMPLES["brain-300kb"])
    for cut in [*range(0, 64), *range(len(payload) - 600, len(payload), 7)]:
        with pytest.raises(MessageError):
            m.decode(payload[:cut])


@FUZZ
@given(st.binary(max_size=512))
def test_random_bytes_only_raise_message_error(payload: bytes) -> None:
    _decodes_or_refuses(payload)


@FUZZ
@given(st.sampled_from([*Tag, 0, 6, 255]), st.integers(0, 3), st.binary(max_size=512))
def test_random_bodies_only_raise_message_error(tag: int, version: int, body: bytes) -> None:
    _decodes_or_refuses(bytes([tag, version]) + body)


@FUZZ
@given(st.sampled_from(sorted(SMALL)), st.data())
def test_flipped_bytes_only_raise_message_error(name: str, data: st.DataObject) -> None:
    payload = bytearray(m.encode(SAMPLES[name]))
    for _ in range(data.draw(st.integers(1, 4))):
        pos = data.draw(st.integers(0, len(payload) - 1))
        payload[pos] = data.draw(st.integers(0, 255))
    _decodes_or_refuses(bytes(payload))


@FUZZ
@given(st.sampled_from(sorted(SMALL)), st.data())
def test_spliced_bytes_only_raise_message_error(name: str, data: st.DataObject) -> None:
    payload = m.encode(SAMPLES[name])
    pos = data.draw(st.integers(0, len(payload)))
    cut = data.draw(st.integers(0, 8))
    insert = data.draw(st.binary(max_size=8))
    _decodes_or_refuses(payload[:pos] + insert + payload[pos + cut :])


# -- keys -----------------------------------------------------------------------------------


def test_key_layout() -> None:
    assert keys.pose_key("s1", 3) == "patternrl/s1/robot/3/pose"
    assert keys.cmd_key("s1", 3) == "patternrl/s1/robot/3/cmd"
    assert keys.status_key("s1", 3) == "patternrl/s1/robot/3/status"
    assert keys.all_poses("s1") == "patternrl/s1/robot/*/pose"
    assert keys.all_cmds("s1") == "patternrl/s1/robot/*/cmd"
    assert keys.all_status("s1") == "patternrl/s1/robot/*/status"
    assert keys.pattern_key("s1") == "patternrl/s1/pattern"
    assert keys.brain_key("s1") == "patternrl/s1/brain"
    assert keys.alive_key("s1", 3) == "patternrl/s1/alive/3"
    assert keys.alive_key("s1", "world") == "patternrl/s1/alive/world"
    assert keys.alive_key("s1", keys.WORLD_ID) == "patternrl/s1/alive/world"
    assert keys.all_alive("s1") == "patternrl/s1/alive/*"
    assert keys.swarm_root("My_Swarm-2") == "patternrl/My_Swarm-2/**"


@pytest.mark.parametrize("make", [keys.pose_key, keys.cmd_key, keys.status_key, keys.alive_key])
@pytest.mark.parametrize("robot_id", [0, 1, 9, 10, 123, 2**32 - 1, 10**12])
def test_parse_robot_id_round_trip(make: object, robot_id: int) -> None:
    assert callable(make)
    assert keys.parse_robot_id(make("swarm_A-1", robot_id)) == robot_id


@pytest.mark.parametrize(
    "key",
    [
        "",
        "patternrl/s/robot/3",
        "patternrl/s/robot/3/pose/x",
        "patternrl/s/robot//pose",
        "patternrl/s/robot/*/pose",
        "patternrl/s/robot/-3/pose",
        "patternrl/s/robot/03/pose",
        "patternrl/s/robot/3a/pose",
        "patternrl/s/robot/٣/pose",
        "patternrl/s/robot/3/velocity",
        "patternrl/s/pattern",
        "patternrl/s/brain",
        "patternrl/s/alive/world",
        "patternrl/s/alive/*",
        "patternrl//robot/3/pose",
        "patternrl/a b/robot/3/pose",
        "other/s/robot/3/pose",
        "/patternrl/s/robot/3/pose",
        "patternrl/s/robot/3/pose/",
    ],
)
def test_parse_robot_id_rejects_malformed(key: str) -> None:
    assert keys.parse_robot_id(key) is None


@pytest.mark.parametrize("swarm", ["", "a/b", "a b", "*", "**", "s$", "é", "a\nb", "a.b"])
def test_invalid_swarm_refused(swarm: str) -> None:
    makers = [
        keys.swarm_root,
        keys.all_poses,
        keys.all_cmds,
        keys.all_status,
        keys.pattern_key,
        keys.brain_key,
        keys.all_alive,
    ]
    for make in makers:
        with pytest.raises(ValueError, match="invalid swarm name") as info:
            make(swarm)
        assert "\n" not in str(info.value)
    for make_id in (keys.pose_key, keys.cmd_key, keys.status_key, keys.alive_key):
        with pytest.raises(ValueError, match="invalid swarm name"):
            make_id(swarm, 1)


@pytest.mark.parametrize("robot_id", [-1, True, 1.0, "3"])
def test_invalid_robot_id_refused(robot_id: object) -> None:
    with pytest.raises(ValueError, match="invalid robot id"):
        keys.pose_key("s", robot_id)  # type: ignore[arg-type]


@pytest.mark.parametrize("alive_id", ["", "a/b", "*", "wor ld"])
def test_invalid_alive_id_refused(alive_id: str) -> None:
    with pytest.raises(ValueError, match="invalid liveliness id"):
        keys.alive_key("s", alive_id)


def test_keys_are_valid_zenoh_key_expressions() -> None:
    zenoh = pytest.importorskip("zenoh")
    for k in (
        keys.pose_key("s", 1),
        keys.all_poses("s"),
        keys.swarm_root("s"),
        keys.alive_key("s", "world"),
        keys.all_alive("s"),
    ):
        assert str(zenoh.KeyExpr(k)) == k
    assert zenoh.KeyExpr(keys.all_poses("s")).intersects(zenoh.KeyExpr(keys.pose_key("s", 7)))
    assert zenoh.KeyExpr(keys.swarm_root("s")).includes(zenoh.KeyExpr(keys.status_key("s", 7)))


def test_pattern_messages_are_bounded_before_use() -> None:
    import struct

    from runtime.wire.messages import MAX_PATTERN_POINTS, Tag, decode_pattern

    def raw(n_claimed: int, pts: np.ndarray) -> bytes:
        head = struct.pack("<BBQdHI", Tag.PATTERN, 1, 1, 0.025, 0, n_claimed)
        return head + np.asarray(pts, "<f8").tobytes()

    ok = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert decode_pattern(raw(2, ok)).points.shape == (2, 2)
    with pytest.raises(MessageError, match="at most"):  # the count, before any allocation
        decode_pattern(raw(MAX_PATTERN_POINTS + 1, np.zeros((MAX_PATTERN_POINTS + 1, 2))))
    with pytest.raises(MessageError, match="truncated"):  # a count the bytes do not hold
        decode_pattern(raw(MAX_PATTERN_POINTS, ok))
    with pytest.raises(MessageError, match="from the origin"):
        decode_pattern(raw(2, np.array([[1e308, 0.0], [0.0, 0.0]])))
    with pytest.raises(MessageError, match="from the origin"):
        m.encode_pattern(PatternMsg(1, "far", np.array([[2e4, 0.0], [0.0, 0.0]]), 0.025))
