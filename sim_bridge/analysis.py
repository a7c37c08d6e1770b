"""What happened in a run, from its MCAP log alone.

Input: a log written by :mod:`sim_bridge.recorder` (its module docstring is the
channel layout). Nothing here trusts the world's own verdicts: every figure of
the report is recomputed from the recorded poses, and the world's ``phase_end``
figures are kept beside them only to be compared (``world`` and ``mismatches``
in each phase).

Reading (:func:`iter_messages`)
    A small, fast MCAP reader for this project's logs: it walks the records of
    the file, decompresses each chunk whole (zstd, lz4 or none), checks its CRC
    and yields its messages. A log whose writer was killed ends inside a record:
    reading stops after the last complete chunk and :class:`Recovery` says how
    much was read, how far into the file, and whether the log was finished
    (footer present). The same messages as mcap's own ``NonSeekingReader``
    (tests compare them, whole and cut at many offsets), several times faster:
    what lets a 10,000-step, 20-robot log be read and analysed at over
    100 k messages/s (``benchmarks/replay_speed.py``).

Decoding (:func:`read_log` -> :class:`LogData`)
    Poses and commands are decoded column-wise with numpy structured dtypes (the
    layouts of :mod:`runtime.messages`; a payload that does not decode is counted
    as malformed and dropped, as the robots and the world drop it). Events and
    metrics are parsed as JSON; the Foxglove scene is counted, not parsed.

Phases (:func:`analyse` -> :class:`RunReport`)
    A phase starts at a ``pattern`` event with reason ``phase`` (logs without
    events fall back on the wire pattern messages: a new pattern name is a new
    phase, a new size of the same pattern is a resize). A phase's patterns are
    its first one and its resizes; at step ``s`` the pattern in force is the
    phase's last one published at a step <= s.

    ============================  ===============================================
    figure                        computed from the recorded poses as
    ============================  ===============================================
    steps (formed)                first step ``s >= start`` at which every robot
                                  is within the pattern's ``formed_tol_m`` of its
                                  slot under the centred optimal assignment;
                                  steps = s - start. Not formed: the phase's
                                  recorded length
    lower bounds                  :func:`runtime.formation.lower_bounds` of the
                                  poses at the phase's first step
    travel per robot              sum of ||p(s+1) - p(s)|| over the phase's steps
                                  where the robot is present at both
    collisions                    robot pairs whose discs overlap at any time of
                                  a step (swept test, straight-line motion), each
                                  counted when it starts overlapping
    min separation                smallest centre distance after any step
    final error                   formation error at the phase's last step
    ============================  ===============================================

    From the log's records, not the poses: deadline misses (``deadline_miss``
    events), brain swaps (``brain_swap`` events; a swap logged between two phases
    belongs to the next one, as the world swaps before it publishes a pattern),
    robots joined and lost (``join``/``leave`` events after the first phase
    began), the brains that decided (the ``brain_id`` of every recorded command)
    and the safety filter's interventions (``safety_changed`` of the commands).

    Known difference: the world counts the travel of a robot during the step in
    which it leaves, but the log has no pose of it after that step, so that last
    step of a leaving robot is not in the recomputed travel.

Counterfactual (:func:`counterfactual`)
    Another brain, run at every recorded step exactly as a robot runs it: one
    :class:`runtime.controller.Controller` per robot (shared assignment with
    hysteresis, the brain's observation builder, clamp, the ORCA filter unless
    ``safety`` is None) fed the recorded poses of that step (robots sorted by id)
    and the pattern in force when those poses were published (the last pattern
    message recorded before the step's first pose: the world publishes a new
    pattern before the poses of its first step). Deviation = ||v_other - v_recorded||
    in m/s per (robot, step) with a recorded command. In realtime logs the robots
    decided at their own pace on slightly different frames; there the deviation
    includes that timing.

Repair (:func:`repair`)
    Writes every recovered message (same channels, schemas, log and publish
    times, sequence numbers) into a new, finished, indexed MCAP file.
"""

from __future__ import annotations

import json
import math
import struct
import time
import zlib
from collections import Counter, defaultdict
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from runtime import keys
from runtime.errors import InputError
from runtime.formation import lower_bounds, swept_pair_distance
from runtime.messages import VERSION as WIRE_VERSION
from runtime.messages import MessageError, PatternMsg, Tag, decode_pattern
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

EVENTS_TOPIC: Final = "/world/events"
METRICS_TOPIC: Final = "/world/metrics"
SCENE_TOPIC: Final = "/world/scene"
WIRE_ENCODING: Final = "patternrl-wire"


class LogError(InputError):
    """A file that is not a readable MCAP log; the message is one line."""


# ============================================================================ reading

MAGIC: Final = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_REC: Final = struct.Struct("<BQ")  # opcode, record length
_MSG: Final = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK: Final = struct.Struct("<QQQI")  # start time, end time, uncompressed size, crc
_U16: Final = struct.Struct("<H")
_U32: Final = struct.Struct("<I")
_U64: Final = struct.Struct("<Q")


@dataclass(frozen=True)
class ChannelInfo:
    """One MCAP channel with its schema (schema id 0: none)."""

    id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]
    schema_id: int
    schema_name: str
    schema_encoding: str
    schema_data: bytes


@dataclass
class Recovery:
    """How much of a log could be read.

    ``finished``: the writer wrote its footer (a complete, indexed log).
    ``bytes_read``: where the last whole record read ends; the rest of the file
    (``file_bytes - bytes_read``) was an incomplete record, lost.
    """

    messages: int = 0
    chunks: int = 0
    bytes_read: int = 0
    file_bytes: int = 0
    finished: bool = False
    error: str = ""
    profile: str = ""
    library: str = ""


def _string(buf: bytes | memoryview, p: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, p)
    end = p + 4 + n
    if end > len(buf):
        raise ValueError("string runs past its record")
    return bytes(buf[p + 4 : end]).decode("utf-8"), end


def _schema(body: bytes | memoryview) -> tuple[int, str, str, bytes]:
    (sid,) = _U16.unpack_from(body, 0)
    name, p = _string(body, 2)
    enc, p = _string(body, p)
    (n,) = _U32.unpack_from(body, p)
    return sid, name, enc, bytes(body[p + 4 : p + 4 + n])


def _channel(body: bytes | memoryview) -> tuple[int, int, str, str, dict[str, str]]:
    cid, sid = struct.unpack_from("<HH", body, 0)
    topic, p = _string(body, 4)
    enc, p = _string(body, p)
    (n,) = _U32.unpack_from(body, p)
    p += 4
    end = p + n
    meta: dict[str, str] = {}
    while p < end:
        k, p = _string(body, p)
        v, p = _string(body, p)
        meta[k] = v
    return cid, sid, topic, enc, meta


def _decompress(compression: str, data: bytes | memoryview, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        return bytes(zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size))
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(bytes(data)))
    raise ValueError(f"unsupported chunk compression {compression!r}")


Raw = tuple[ChannelInfo, int, int, int, bytes]
"""(channel, log_time_ns, publish_time_ns, sequence, payload)"""


class _Records:
    """Parses the records of one log (or one chunk) into messages, keeping channel state."""

    def __init__(self) -> None:
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, ChannelInfo] = {}

    def block(self, buf: bytes, out: list[Raw]) -> None:
        """Schemas, channels and messages of a chunk's records, appended to ``out``."""
        unpack_rec, unpack_msg = _REC.unpack_from, _MSG.unpack_from
        channels = self.channels
        p, n = 0, len(buf)
        while p < n:
            if p + 9 > n:
                raise ValueError("chunk ends inside a record header")
            op, length = unpack_rec(buf, p)
            s = p + 9
            p = s + length
            if p > n:
                raise ValueError("chunk record runs past the chunk")
            if op == _OP_MESSAGE:
                cid, seq, lt, pt = unpack_msg(buf, s)
                out.append((channels[cid], lt, pt, seq, buf[s + 22 : p]))
            else:
                self.other(op, memoryview(buf)[s:p])

    def other(self, op: int, body: memoryview) -> None:
        if op == _OP_SCHEMA:
            sid, name, enc, data = _schema(body)
            self.schemas[sid] = (name, enc, data)
        elif op == _OP_CHANNEL:
            cid, sid, topic, enc, meta = _channel(body)
            if sid != 0 and sid not in self.schemas:
                raise ValueError(f"channel {cid} names unknown schema {sid}")
            sname, senc, sdata = self.schemas.get(sid, ("", "", b""))
            self.channels[cid] = ChannelInfo(cid, topic, enc, meta, sid, sname, senc, sdata)


def check_log_file(path: str | Path) -> Path:
    """``path`` if it is a readable file starting with the MCAP magic, else :class:`LogError`."""
    p = Path(path)
    if not p.exists():
        raise LogError(f"{p}: no such file")
    if not p.is_file():
        raise LogError(f"{p}: not a file")
    try:
        with open(p, "rb") as f:
            head = f.read(len(MAGIC))
    except OSError as e:
        raise LogError(f"{p}: cannot read: {e.strerror or e}") from None
    if head != MAGIC:
        raise LogError(f"{p}: not an MCAP file (no MCAP magic at the start)")
    return p


def _blocks(path: str | Path, rec: Recovery) -> Iterator[bytes]:
    """The log's content as record sequences, up to the last complete chunk.

    Yields each chunk's records (decompressed, CRC checked) and each top-level
    schema, channel or message record (chunkless writers) as the bytes of that
    one record; consumers walk them with the same loop. Raises :class:`LogError` for a file that
    is missing or not an MCAP file; a log cut short is not an error: it stops,
    and ``rec`` says where and why.
    """
    p = check_log_file(path)
    data = p.read_bytes()
    n = len(data)
    rec.file_bytes = n
    pos = len(MAGIC)
    rec.bytes_read = pos
    while True:
        if pos + 9 > n:
            rec.error = ("the file ends without a footer: the writer did not finish"
                         if pos == n else f"incomplete record header at byte {pos}")
            break
        op, length = _REC.unpack_from(data, pos)
        s = pos + 9
        end = s + length
        if end > n:
            rec.error = f"incomplete record (opcode {op}) at byte {pos}: {end - n} bytes missing"
            break
        out: bytes | None = None
        try:
            if op == _OP_CHUNK:
                _, _, size, crc = _CHUNK.unpack_from(data, s)
                comp, q = _string(data, s + 28)
                (clen,) = _U64.unpack_from(data, q)
                if q + 8 + clen > end:
                    raise ValueError("chunk data runs past its record")
                out = _decompress(comp, memoryview(data)[q + 8 : q + 8 + clen], size)
                if len(out) != size:
                    raise ValueError(f"chunk decompressed to {len(out)} bytes, expected {size}")
                if crc != 0 and zlib.crc32(out) != crc:
                    raise ValueError("chunk CRC mismatch")
                rec.chunks += 1
            elif op == _OP_MESSAGE or op == _OP_SCHEMA or op == _OP_CHANNEL:
                out = data[pos:end]
            elif op == _OP_FOOTER:
                rec.finished = True
                rec.bytes_read = end
                if data[end : end + len(MAGIC)] == MAGIC:
                    rec.bytes_read = end + len(MAGIC)
                break
            elif op == _OP_HEADER:
                rec.profile, q = _string(data, s)
                rec.library, _ = _string(data, q)
        except (ValueError, struct.error, UnicodeDecodeError) as e:
            rec.error = f"unreadable record (opcode {op}) at byte {pos}: {e}"[:200]
            break
        except Exception as e:  # a decompressor's own error types
            rec.error = f"unreadable chunk at byte {pos}: {type(e).__name__}: {e}"[:200]
            break
        pos = end
        rec.bytes_read = end
        if out is not None:
            yield out
    if rec.bytes_read <= len(MAGIC) and not rec.profile and rec.error:
        raise LogError(f"{p}: not a readable MCAP log ({rec.error})")


def iter_messages(path: str | Path, recovery: Recovery | None = None) -> Iterator[Raw]:
    """Every message of a log, in file order, up to the last complete chunk.

    Raises :class:`LogError` for a file that is missing or not an MCAP file; a
    log cut short is not an error: iteration stops and ``recovery`` tells.
    """
    rec = recovery if recovery is not None else Recovery()
    state = _Records()
    batch: list[Raw] = []
    for buf in _blocks(path, rec):
        try:
            state.block(buf, batch)  # the whole chunk first: a bad chunk yields nothing
        except (ValueError, KeyError, struct.error, UnicodeDecodeError) as e:
            rec.error = f"unreadable record inside a chunk: {e}"[:200]
            return
        rec.messages += len(batch)
        yield from batch
        batch.clear()


# ============================================================================ decoding

# runtime.messages layouts, as numpy dtypes (little-endian, packed)
POSE_DTYPE: Final = np.dtype([
    ("tag", "u1"), ("version", "u1"), ("robot_id", "<u4"), ("step", "<u8"), ("time_s", "<f8"),
    ("x", "<f8"), ("y", "<f8"), ("vx", "<f8"), ("vy", "<f8"), ("n_live", "<u4")])
_CMD_FIXED: Final = [
    ("tag", "u1"), ("version", "u1"), ("robot_id", "<u4"), ("step", "<u8"), ("vx", "<f8"),
    ("vy", "<f8"), ("safety_changed", "u1"), ("safety_change_mps", "<f8"),
    ("decision_us", "<f8"), ("brain_len", "<u2")]
_CMD_FIXED_SIZE: Final = int(np.dtype(_CMD_FIXED).itemsize)


@dataclass
class Commands:
    """Every recorded command, column-wise (length m)."""

    robot_id: IntArray
    step: IntArray
    v: Array
    """(m, 2) m/s"""
    safety_changed: BoolArray
    brain: list[str]
    """brain id of each command"""

    @staticmethod
    def empty() -> Commands:
        return Commands(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)),
                        np.zeros(0, bool), [])


@dataclass
class Frames:
    """The recorded poses as a dense table: one row per recorded step, one column per robot.

    ``xy`` (S, m, 2) metres, NaN where a robot has no pose at that step;
    ``first_msg`` (S,) the message index of each step's first pose (file order).
    """

    steps: IntArray
    ids: IntArray
    xy: Array
    present: BoolArray
    first_msg: IntArray

    def row(self, step: int) -> int:
        """Row of ``step``, or -1 when no pose of it was recorded."""
        k = int(np.searchsorted(self.steps, step))
        return k if k < len(self.steps) and self.steps[k] == step else -1


@dataclass
class PatternMark:
    """A new pattern version on the wire, and where in the log it arrived."""

    msg: PatternMsg
    msg_index: int
    log_time_ns: int


@dataclass
class LogData:
    """One log, decoded."""

    path: str
    recovery: Recovery
    events: list[dict[str, Any]]
    metrics: list[dict[str, Any]]
    frames: Frames
    commands: Commands
    patterns: list[PatternMark]
    topics: dict[str, int]
    malformed: int
    first_log_ns: int
    last_log_ns: int
    world: WorldConfig

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e.get("kind") == kind]


def _robot_of(topic: str) -> int:
    rid = keys.parse_robot_id(topic)
    return -1 if rid is None else rid


def _decode_poses(raw: list[bytes], idx: list[int], key_rid: list[int]
                  ) -> tuple[NDArray[Any], IntArray, int]:
    """Structured pose records and their message indices; (records, indices, malformed)."""
    size = POSE_DTYPE.itemsize
    bad = 0
    if set(map(len, raw)) - {size}:  # rare: payloads of the wrong size are malformed
        ok_len = [k for k, b in enumerate(raw) if len(b) == size]
        bad = len(raw) - len(ok_len)
        raw = [raw[k] for k in ok_len]
        idx = [idx[k] for k in ok_len]
        key_rid = [key_rid[k] for k in ok_len]
    rec = np.frombuffer(b"".join(raw), dtype=POSE_DTYPE)
    good = (
        (rec["tag"] == Tag.POSE) & (rec["version"] == WIRE_VERSION)
        & np.isfinite(rec["x"]) & np.isfinite(rec["y"]) & np.isfinite(rec["time_s"])
        & np.isfinite(rec["vx"]) & np.isfinite(rec["vy"])
        & (rec["robot_id"].astype(np.int64) == np.asarray(key_rid, np.int64))
    )
    bad += int((~good).sum())
    return rec[good], np.asarray(idx, np.int64)[good], bad


def _decode_commands(raw: list[bytes], key_rid: list[int]) -> tuple[Commands, int]:
    lengths = list(map(len, raw))
    by_len: dict[int, list[int]] = {}
    if len(set(lengths)) == 1:  # the usual case: one brain id length for the whole run
        by_len[lengths[0]] = list(range(len(raw)))
    else:
        for k, n in enumerate(lengths):
            by_len.setdefault(n, []).append(k)
    cols: list[tuple[IntArray, IntArray, Array, BoolArray, list[str], IntArray]] = []
    bad = 0
    for length, ks in by_len.items():
        blen = length - _CMD_FIXED_SIZE
        if blen < 0:
            bad += len(ks)
            continue
        dt = np.dtype([*_CMD_FIXED, ("brain", f"S{blen}")]) if blen else np.dtype(_CMD_FIXED)
        joined = b"".join(raw) if len(ks) == len(raw) else b"".join([raw[k] for k in ks])
        rec = np.frombuffer(joined, dtype=dt)
        good = (
            (rec["tag"] == Tag.COMMAND) & (rec["version"] == WIRE_VERSION)
            & (rec["brain_len"] == blen) & (rec["safety_changed"] <= 1)
            & np.isfinite(rec["vx"]) & np.isfinite(rec["vy"])
            & (rec["robot_id"].astype(np.int64) == np.asarray([key_rid[k] for k in ks]))
        )
        bad += int((~good).sum())
        rec = rec[good]
        order = np.asarray(ks, np.int64)[good]
        if blen:
            names, inv = np.unique(rec["brain"], return_inverse=True)
            text = [bytes(b).decode("utf-8", "replace") for b in names]
            brains = [text[i] for i in inv.tolist()]
        else:
            brains = [""] * len(rec)
        cols.append((rec["robot_id"].astype(np.int64), rec["step"].astype(np.int64),
                     np.stack([rec["vx"], rec["vy"]], axis=1).astype(np.float64),
                     rec["safety_changed"].astype(bool), brains, order))
    if not cols:
        return Commands.empty(), bad
    order = np.argsort(np.concatenate([c[5] for c in cols]), kind="stable")
    brains_all = [b for c in cols for b in c[4]]
    return Commands(
        np.concatenate([c[0] for c in cols])[order], np.concatenate([c[1] for c in cols])[order],
        np.concatenate([c[2] for c in cols])[order], np.concatenate([c[3] for c in cols])[order],
        [brains_all[i] for i in order.tolist()],
    ), bad


def _frames(rec: NDArray[Any], idx: IntArray) -> Frames:
    if len(rec) == 0:
        return Frames(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 0, 2)),
                      np.zeros((0, 0), bool), np.zeros(0, np.int64))
    step = rec["step"].astype(np.int64)
    rid = rec["robot_id"].astype(np.int64)
    steps, srow = np.unique(step, return_inverse=True)
    ids, rcol = np.unique(rid, return_inverse=True)
    xy = np.full((len(steps), len(ids), 2), np.nan)
    xy[srow, rcol, 0] = rec["x"]  # a pose recorded twice: the later one stands
    xy[srow, rcol, 1] = rec["y"]
    present = np.zeros((len(steps), len(ids)), bool)
    present[srow, rcol] = True
    first = np.full(len(steps), np.iinfo(np.int64).max, np.int64)
    np.minimum.at(first, srow, idx)
    return Frames(steps, ids, xy, present, first)


def _world_from(events: list[dict[str, Any]]) -> WorldConfig:
    for e in events:
        if e.get("kind") == "run_start" and isinstance(e.get("world"), dict):
            names = {f.name for f in fields(WorldConfig)}
            try:
                return WorldConfig(**{k: v for k, v in e["world"].items() if k in names})
            except (TypeError, ValueError):
                break
    return DEFAULT_WORLD


_OTHER, _POSE, _CMD, _PATTERN, _EVENT, _METRIC = range(6)


def _kind(ch: ChannelInfo) -> tuple[int, int]:
    """(what the analysis does with a channel's messages, robot id on its key or -1)."""
    if ch.message_encoding == WIRE_ENCODING:
        tail = ch.topic.rsplit("/", 1)[-1]
        k = {"pose": _POSE, "cmd": _CMD, "pattern": _PATTERN}.get(tail, _OTHER)
    else:
        k = {EVENTS_TOPIC: _EVENT, METRICS_TOPIC: _METRIC}.get(ch.topic, _OTHER)
    return k, _robot_of(ch.topic)


def read_log(path: str | Path) -> LogData:
    """Read and decode a log (finished or cut short); :class:`LogError` if it is no log.

    One pass over the records: pose and command payloads are only collected here
    (decoded column-wise afterwards), JSON is parsed for events and metrics only,
    every other message is just counted.
    """
    recovery = Recovery()
    state = _Records()
    kind: dict[int, int] = {}
    key_rid: dict[int, int] = {}
    counts: dict[int, int] = {}
    pose_raw: list[bytes] = []
    pose_idx: list[int] = []
    pose_rid: list[int] = []
    cmd_raw: list[bytes] = []
    cmd_rid: list[int] = []
    json_msgs: list[tuple[int, bytes]] = []
    patterns: list[PatternMark] = []
    malformed = 0
    first_ns = last_ns = -1
    i = 0  # messages so far
    unpack_rec, unpack_msg = _REC.unpack_from, _MSG.unpack_from
    for buf in _blocks(path, recovery):
        p, n = 0, len(buf)
        try:
            while p < n:
                op, length = unpack_rec(buf, p)
                s = p + 9
                p = s + length
                if p > n:
                    raise ValueError("record runs past its chunk")
                if op != _OP_MESSAGE:
                    state.other(op, memoryview(buf)[s:p])
                    for cid, ch in state.channels.items():
                        if cid not in kind:
                            kind[cid], key_rid[cid] = _kind(ch)
                            counts[cid] = 0
                    continue
                cid, _seq, lt, _pt = unpack_msg(buf, s)
                k = kind[cid]
                counts[cid] += 1
                if first_ns < 0:
                    first_ns = lt
                last_ns = lt
                if k == _POSE:
                    pose_raw.append(buf[s + 22 : p])
                    pose_idx.append(i)
                    pose_rid.append(key_rid[cid])
                elif k == _CMD:
                    cmd_raw.append(buf[s + 22 : p])
                    cmd_rid.append(key_rid[cid])
                elif k == _EVENT or k == _METRIC:
                    json_msgs.append((k, buf[s + 22 : p]))
                elif k == _PATTERN:
                    try:
                        pm = decode_pattern(buf[s + 22 : p])
                    except MessageError:
                        malformed += 1
                    else:
                        if not patterns or patterns[-1].msg.version != pm.version:
                            patterns.append(PatternMark(pm, i, lt))
                i += 1
        except (ValueError, KeyError, struct.error, UnicodeDecodeError) as e:
            recovery.error = f"unreadable record inside a chunk: {e}"[:200]
            break
    recovery.messages = i
    events: list[dict[str, Any]] = []
    metrics: list[dict[str, Any]] = []
    for k, raw in json_msgs:
        try:
            obj = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            obj = None
        if isinstance(obj, dict):
            (events if k == _EVENT else metrics).append(obj)
        else:
            malformed += 1
    prec, pidx, bad_p = _decode_poses(pose_raw, pose_idx, pose_rid)
    cmds, bad_c = _decode_commands(cmd_raw, cmd_rid)
    topics = {state.channels[cid].topic: c for cid, c in counts.items() if c}
    return LogData(
        path=str(path), recovery=recovery, events=events, metrics=metrics,
        frames=_frames(prec, pidx), commands=cmds, patterns=patterns, topics=topics,
        malformed=malformed + bad_p + bad_c, first_log_ns=max(first_ns, 0),
        last_log_ns=max(last_ns, 0), world=_world_from(events),
    )


# ============================================================================ phases


@dataclass
class PhasePattern:
    """A pattern in force from ``step`` on (the phase's first, or a resize)."""

    step: int
    points: Array
    formed_tol_m: float
    version: int


@dataclass
class _PhaseLog:
    """What the log's records say about one phase (before any recomputation)."""

    index: int
    name: str
    start_step: int
    patterns: list[PhasePattern]
    end_step: int | None = None
    world_start: dict[str, Any] | None = None
    world_end: dict[str, Any] | None = None
    joined: list[int] = field(default_factory=list)
    lost: list[int] = field(default_factory=list)
    swaps: list[dict[str, Any]] = field(default_factory=list)
    deadline_misses: int = 0


def _phases_from_events(events: list[dict[str, Any]], world: WorldConfig) -> list[_PhaseLog]:
    phases: list[_PhaseLog] = []
    cur: _PhaseLog | None = None
    pending_swaps: list[dict[str, Any]] = []
    for e in events:
        kind = e.get("kind")
        step = int(e.get("step", 0))
        if kind == "pattern":
            pts = np.asarray(e.get("points", []), dtype=np.float64).reshape(-1, 2)
            pat = PhasePattern(step, pts, float(e.get("formed_tol_m", world.formed_tol_m)),
                               int(e.get("version", 0)))
            if e.get("reason", "phase") == "phase" or cur is None:
                cur = _PhaseLog(len(phases), str(e.get("name", "?")), step, [pat])
                cur.swaps, pending_swaps = pending_swaps, []
                phases.append(cur)
            else:
                cur.patterns.append(pat)
        elif kind == "phase_start" and cur is not None:
            cur.world_start = e
        elif kind == "phase_end" and cur is not None:
            cur.world_end = e
            cur.end_step = int(e.get("end_step", step))
            cur = None
        elif kind == "brain_swap":
            (cur.swaps if cur is not None else pending_swaps).append(e)
        elif cur is not None and kind in ("join", "leave"):
            (cur.joined if kind == "join" else cur.lost).append(int(e.get("robot", -1)))
        elif cur is not None and kind == "deadline_miss":
            cur.deadline_misses += len(e.get("robots", []))
    return phases


def _phases_from_wire(data: LogData) -> list[_PhaseLog]:
    """Phases from the pattern messages alone (a log without events)."""
    fr = data.frames
    phases: list[_PhaseLog] = []
    for mark in data.patterns:
        k = int(np.searchsorted(fr.first_msg, mark.msg_index))  # the first step published after
        if k >= len(fr.steps):
            continue
        step = int(fr.steps[k])
        pat = PhasePattern(step, np.asarray(mark.msg.points), mark.msg.formed_tol_m,
                           mark.msg.version)
        if phases and phases[-1].name == mark.msg.name:
            phases[-1].patterns.append(pat)
        else:
            phases.append(_PhaseLog(len(phases), mark.msg.name, step, [pat]))
    return phases


@dataclass
class PhaseReport:
    """One pattern phase, recomputed from the log (see the module docstring)."""

    index: int
    pattern: str
    n_robots: int
    start_step: int
    end_step: int
    complete: bool
    """The phase ended in the log (formed, gave up, or the next phase began)."""
    formed: bool
    steps: int
    lower_bound_steps: int | None
    lower_bound_travel_m: float | None
    travel_m: float
    travel_per_robot_m: dict[int, float]
    collisions: int
    min_separation_m: float | None
    final_error_m: float | None
    deadline_misses: int
    commands_missing: int
    safety_interventions: int
    brains: dict[str, int]
    """brain id -> commands it decided in this phase"""
    swaps_accepted: int
    """Robots that took a new brain (``brain_swap`` accepted, old brain != new brain)."""
    swaps_refused: int
    swaps_unchanged: int
    """Swaps answered "already running": the robot had that brain."""
    swapped_to: list[str]
    joined: list[int]
    lost: list[int]
    world: dict[str, Any] | None
    """The world's own ``phase_end`` figures, for comparison."""
    mismatches: list[str]
    """Figures where the recomputation and the world's ``phase_end`` disagree."""

    @property
    def steps_ratio(self) -> float | None:
        lb = self.lower_bound_steps
        return self.steps / lb if lb else None

    @property
    def travel_ratio(self) -> float | None:
        lb = self.lower_bound_travel_m
        return self.travel_m / lb if lb else None


@dataclass
class StepSeries:
    """One phase, per recorded step from its start to its end: (S,) arrays for the error plot.

    A phase's last step is also the next phase's first (measured against each one's
    pattern), so it appears in both.
    """

    phase: int
    step: IntArray
    time_s: Array
    formation_error_m: Array
    min_separation_m: Array


@dataclass
class RunReport:
    """A whole log: how much was read, the run's facts and every phase."""

    path: str
    recovery: Recovery
    finished: bool
    messages: int
    steps_recorded: int
    first_step: int | None
    last_step: int | None
    wall_s: float
    robots: list[int]
    mode: str
    outcome: str
    malformed: int
    topics: dict[str, int]
    phases: list[PhaseReport]
    series: list[StepSeries]
    world: WorldConfig
    phase_patterns: list[list[PhasePattern]] = field(default_factory=list)
    """Each phase's patterns (its first and its resizes), for pictures; not in the JSON."""
    timing: dict[str, float] = field(default_factory=dict)
    """Seconds spent on the phases: ``phases_s`` in all, ``lower_bounds_s`` of it (not in JSON)."""

    def pattern_at(self, phase: int, step: int) -> Array | None:
        """The pattern in force in ``phase`` at ``step``."""
        if not 0 <= phase < len(self.phase_patterns) or not self.phase_patterns[phase]:
            return None
        pats = self.phase_patterns[phase]
        k = max(0, int(np.searchsorted([p.step for p in pats], step, side="right")) - 1)
        return pats[k].points

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``--json``)."""
        phases = []
        for ph in self.phases:
            d = asdict(ph)
            d["travel_per_robot_m"] = {str(k): v for k, v in ph.travel_per_robot_m.items()}
            d["steps_ratio"] = _r(ph.steps_ratio, 4)
            d["travel_ratio"] = _r(ph.travel_ratio, 4)
            if d["world"] is not None:
                d["world"] = {k: v for k, v in d["world"].items()
                              if k not in ("kind", "time_s", "brain_ids")}
            phases.append(d)
        rec = asdict(self.recovery)
        return {
            "path": self.path, "finished": self.finished, "messages": self.messages,
            "recovery": rec, "steps_recorded": self.steps_recorded,
            "first_step": self.first_step, "last_step": self.last_step,
            "wall_s": round(self.wall_s, 3), "robots": self.robots, "mode": self.mode,
            "outcome": self.outcome, "malformed": self.malformed, "topics": self.topics,
            "world": asdict(self.world), "phases": phases,
        }


def _r(x: float | None, nd: int = 6) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def _formation(xy: Array, C: Array) -> tuple[Array, Array]:
    """(formation error, farthest robot from its slot) per row of xy (T, n, 2), metres.

    The world's measure, row by row: the assignment minimising the summed squared
    distance between the centred team and the centred pattern, then each robot's
    distance to its slot (the pattern placed on the team's centroid).
    """
    from scipy.optimize import linear_sum_assignment

    centroid = xy.mean(axis=1, keepdims=True)
    Cc = C - C.mean(axis=0, keepdims=True)
    d = (xy - centroid)[:, :, None, :] - Cc[None, None, :, :]
    cost = np.einsum("tijk,tijk->tij", d, d)
    cols = np.empty(xy.shape[:2], np.int64)
    for t in range(len(xy)):
        cols[t] = linear_sum_assignment(cost[t])[1]
    dist = np.linalg.norm((xy - centroid) - Cc[cols], axis=-1)
    err: Array = np.sqrt(np.mean(dist * dist, axis=1))
    far: Array = dist.max(axis=1)
    return err, far


def _min_sep_rows(xy: Array) -> Array:
    """Smallest centre distance per row of xy (T, m, 2), NaN for absent robots (inf if < 2)."""
    m = xy.shape[1]
    if m < 2 or len(xy) == 0:
        return np.full(len(xy), np.inf)
    iu, ju = np.triu_indices(m, 1)
    diff = xy[:, iu, :] - xy[:, ju, :]
    d2 = np.einsum("tpk,tpk->tp", diff, diff)
    d2 = np.where(np.isnan(d2), np.inf, d2)
    out: Array = np.sqrt(d2.min(axis=1))
    return out


def _collisions(xy: Array, ids: IntArray, sep: Array, min_sep_m: float) -> int:
    """Pairs that start overlapping during a step, over consecutive rows of xy (T, m, 2).

    The swept test of :func:`runtime.formation.swept_pair_distance` runs only on
    steps where two discs could meet: the closest pair at either end within 2R
    plus the largest move of that step (twice, for two robots closing in).
    """
    if len(xy) < 2:
        return 0
    hop = np.linalg.norm(np.diff(xy, axis=0), axis=-1)
    reach = 2.0 * np.nanmax(np.where(np.isnan(hop), 0.0, hop), axis=1)
    near = np.minimum(sep[:-1], sep[1:]) < min_sep_m + reach
    count = 0
    prev: set[tuple[int, int]] = set()
    prev_t = -2
    for t in np.nonzero(near)[0].tolist():
        sw = swept_pair_distance(xy[t], xy[t + 1])
        a, b = np.nonzero(np.triu(sw < min_sep_m - 1e-6, 1))
        if len(a) == 0:
            continue
        pairs = {(int(ids[i]), int(ids[j])) for i, j in zip(a, b, strict=True)}
        if t != prev_t + 1:
            prev = set()
        count += len(pairs - prev)
        prev, prev_t = pairs, t
    return count


def _pattern_rows(ph: _PhaseLog, steps: IntArray) -> IntArray:
    """Index into ph.patterns of the pattern in force at each step."""
    starts = np.asarray([p.step for p in ph.patterns], np.int64)
    out: IntArray = np.maximum(np.searchsorted(starts, steps, side="right") - 1, 0)
    return out


def _phase_report(data: LogData, ph: _PhaseLog, end_step: int, complete: bool,
                  timing: dict[str, float]) -> tuple[PhaseReport, StepSeries]:
    fr, w = data.frames, data.world
    lo = int(np.searchsorted(fr.steps, ph.start_step))
    hi = int(np.searchsorted(fr.steps, end_step, side="right"))
    rows = np.arange(lo, hi)
    steps = fr.steps[rows]
    pat_idx = _pattern_rows(ph, steps)
    err = np.full(len(rows), np.nan)
    far = np.full(len(rows), np.nan)
    # runs of rows with the same robots present and the same pattern: one batch each
    pres = fr.present[rows]
    k = 0
    while k < len(rows):
        j = k + 1
        while j < len(rows) and pat_idx[j] == pat_idx[k] and np.array_equal(pres[j], pres[k]):
            j += 1
        C = ph.patterns[int(pat_idx[k])].points
        cols = np.nonzero(pres[k])[0]
        if len(cols) == len(C) and len(C) >= 1:
            e, f = _formation(fr.xy[rows[k:j]][:, cols], C)
            err[k:j], far[k:j] = e, f
        k = j
    tol = np.asarray([ph.patterns[int(i)].formed_tol_m for i in pat_idx])
    formed_rows = np.nonzero(far <= tol)[0]
    formed = len(formed_rows) > 0
    last = int(formed_rows[0]) if formed else len(rows) - 1
    end = int(steps[last]) if len(rows) else ph.start_step
    n_steps = end - ph.start_step
    span = slice(0, last + 1)
    xy = fr.xy[rows[span]]
    # travel: consecutive recorded steps where the robot is present at both
    if len(xy) > 1:
        hop = np.linalg.norm(np.diff(xy, axis=0), axis=-1)
        per = np.nansum(hop, axis=0)
        seen = fr.present[rows[span]].any(axis=0)
        travel = {int(fr.ids[c]): round(float(per[c]), 6) for c in np.nonzero(seen)[0]}
    else:
        travel = {int(fr.ids[c]): 0.0 for c in np.nonzero(fr.present[rows[span]].any(0))[0]} \
            if len(xy) else {}
    # collisions, counted when a pair starts overlapping (as the world counts them)
    all_seps = _min_sep_rows(fr.xy[rows])
    collisions = _collisions(xy, fr.ids, all_seps[: last + 1], w.min_separation_m)
    seps = all_seps[1 : last + 1]
    min_sep = float(seps.min()) if len(seps) and np.isfinite(seps.min()) else None
    # lower bounds from the poses at the phase's first step
    lb_steps: int | None = None
    lb_travel: float | None = None
    n0 = 0
    if len(rows) and steps[0] == ph.start_step:
        cols = np.nonzero(fr.present[rows[0]])[0]
        n0 = len(cols)
        C0 = ph.patterns[0].points
        if n0 == len(C0) and n0 >= 2:
            t_lb = time.perf_counter()
            lbt, lbs = lower_bounds(fr.xy[rows[0]][cols], C0, w.v_max_mps, w.dt_s)
            timing["lower_bounds_s"] = timing.get("lower_bounds_s", 0.0) + (
                time.perf_counter() - t_lb)
            lb_steps, lb_travel = int(lbs), round(float(lbt), 6)
    elif len(ph.patterns[0].points):
        n0 = len(ph.patterns[0].points)
    # commands in [start, end): brains, interventions, missing ones
    cm = data.commands
    sel = (cm.step >= ph.start_step) & (cm.step < end)
    brains = Counter(cm.brain[i] for i in np.nonzero(sel)[0].tolist())
    interventions = int(cm.safety_changed[sel].sum())
    got = cm.step[sel] * (1 << 24) + cm.robot_id[sel]
    decided = rows[:last]  # the steps [start, end) whose poses the robots answered
    rr, cc = np.nonzero(fr.present[decided])
    want = fr.steps[decided][rr] * (1 << 24) + fr.ids[cc]
    missing = int((~np.isin(want, got)).sum())
    # the world's view, for comparison
    mism: list[str] = []
    we = ph.world_end
    if we is not None:
        checks: list[tuple[str, Any, Any, float]] = [
            ("formed", formed, we.get("formed"), 0.0),
            ("steps", n_steps, we.get("steps"), 0.0),
            ("lower_bound_steps", lb_steps, we.get("lower_bound_steps"), 0.0),
            ("lower_bound_travel_m", lb_travel, we.get("lower_bound_travel_m"), 1e-5),
            ("travel_m", round(sum(travel.values()), 6), we.get("travel_m"), 1e-4),
            ("collisions", collisions, we.get("collisions"), 0.0),
            ("min_separation_m", min_sep if min_sep is not None else -1.0,
             we.get("min_separation_m"), 1e-5),
            ("deadline_misses", ph.deadline_misses, we.get("deadline_misses"), 0.0),
        ]
        for name, mine, theirs, tol_rel in checks:
            if theirs is None:
                continue
            if isinstance(theirs, float) or tol_rel:
                if mine is None or abs(float(mine) - float(theirs)) > tol_rel * max(
                        1.0, abs(float(theirs))):
                    mism.append(name)
            elif mine != theirs:
                mism.append(name)
    series = StepSeries(ph.index, steps[: last + 1], steps[: last + 1].astype(np.float64) * w.dt_s,
                        err[: last + 1],
                        np.where(np.isfinite(all_seps), all_seps, np.nan)[: last + 1])
    accepted = [s for s in ph.swaps if s.get("accepted") and (
        "old_brain_id" not in s or s.get("old_brain_id") != s.get("brain_id"))]
    unchanged = sum(1 for s in ph.swaps if s.get("accepted")) - len(accepted)
    return PhaseReport(
        index=ph.index, pattern=ph.name, n_robots=n0, start_step=ph.start_step, end_step=end,
        complete=complete or formed, formed=formed, steps=n_steps, lower_bound_steps=lb_steps,
        lower_bound_travel_m=lb_travel, travel_m=round(sum(travel.values()), 6),
        travel_per_robot_m=travel, collisions=collisions,
        min_separation_m=_r(min_sep), final_error_m=_r(float(err[last])) if len(rows) else None,
        deadline_misses=ph.deadline_misses, commands_missing=missing,
        safety_interventions=interventions, brains=dict(brains),
        swaps_accepted=len(accepted), swaps_refused=len(ph.swaps) - len(accepted) - unchanged,
        swaps_unchanged=unchanged,
        swapped_to=sorted({str(s.get("brain", "")) for s in accepted}),
        joined=ph.joined, lost=ph.lost,
        world=dict(we) if we is not None else None, mismatches=mism,
    ), series


def analyse(data: LogData) -> RunReport:
    """The report of a decoded log (see the module docstring for every figure)."""
    fr = data.frames
    phases = _phases_from_events(data.events, data.world) if data.events else []
    if not phases:
        phases = _phases_from_wire(data)
    run_end = data.events_of("run_end")
    last_step = int(fr.steps[-1]) if len(fr.steps) else None
    S = len(fr.steps)
    reports = []
    series = []
    timing: dict[str, float] = {"lower_bounds_s": 0.0}
    t0 = time.perf_counter()
    for k, ph in enumerate(phases):
        if ph.end_step is not None:
            end, complete = ph.end_step, True
        elif k + 1 < len(phases):
            end, complete = phases[k + 1].start_step, True
        else:
            end = int(run_end[0].get("steps", last_step or 0)) if run_end else (last_step or 0)
            complete = bool(run_end)
        rep, ser = _phase_report(data, ph, max(end, ph.start_step), complete, timing)
        reports.append(rep)
        series.append(ser)
    start = data.events_of("run_start")
    mode = str(start[0].get("mode", "?")) if start else "?"
    if run_end:
        outcome = str(run_end[0].get("outcome", "?"))
    else:
        outcome = "cut short" if not data.recovery.finished else "no run_end"
    world_malformed = int(run_end[0].get("malformed", 0)) if run_end else len(
        data.events_of("malformed"))
    return RunReport(
        path=data.path, recovery=data.recovery, finished=data.recovery.finished,
        messages=data.recovery.messages, steps_recorded=S,
        first_step=int(fr.steps[0]) if S else None, last_step=last_step,
        wall_s=(data.last_log_ns - data.first_log_ns) / 1e9, robots=[int(i) for i in fr.ids],
        mode=mode, outcome=outcome, malformed=data.malformed + world_malformed,
        topics=data.topics, phases=reports,
        series=series, world=data.world, phase_patterns=[ph.patterns for ph in phases],
        timing={**timing, "phases_s": time.perf_counter() - t0},
    )


def report_log(path: str | Path) -> RunReport:
    """Read and analyse one log."""
    return analyse(read_log(path))


# ============================================================================ tables


def _f(x: float | None, nd: int = 2) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def _ids(xs: list[int]) -> str:
    return ",".join(map(str, xs)) if xs else "-"


def _short_brain(b: str) -> str:
    return b if b.startswith("rule:") or len(b) <= 12 else b[:8]


def _table(header: list[str], rows: list[list[str]], right: set[int]) -> list[str]:
    width = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
             for i, h in enumerate(header)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(width[i]) if i in right else c.ljust(width[i])
                         for i, c in enumerate(cells)).rstrip()

    return [line(header), line(["-" * x for x in width]), *(line(r) for r in rows)]


def recovery_line(r: RunReport) -> str:
    rec = r.recovery
    steps = (f"steps {r.first_step}-{r.last_step}" if r.first_step is not None else "no steps")
    if rec.finished:
        return f"log finished: {rec.messages} messages, {r.steps_recorded} steps ({steps})"
    return (f"log NOT finished (writer killed?): recovered {rec.messages} messages in "
            f"{rec.chunks} chunks, {r.steps_recorded} steps ({steps}), "
            f"{rec.bytes_read} of {rec.file_bytes} bytes; {rec.error}")


def format_report(r: RunReport) -> str:
    """The terminal report: run facts, one row per phase, travel per robot."""
    out = [f"{r.path}: {r.mode}, {len(r.robots)} robots, {len(r.phases)} phases, "
           f"outcome {r.outcome}, {r.wall_s:.1f} s of wall time",
           recovery_line(r)]
    if r.malformed:
        out.append(f"malformed messages: {r.malformed}")
    if not r.phases:
        out.append("no pattern phase in the log")
        return "\n".join(out)
    header = ["#", "pattern", "n", "formed", "steps", "lb", "x lb", "travel m", "lb m", "x lb",
              "coll", "min sep m", "final err m", "misses", "swaps", "joined", "lost", "brains"]
    rows = []
    for ph in r.phases:
        formed = "yes" if ph.formed else ("no" if ph.complete else "cut")
        rows.append([
            str(ph.index), ph.pattern, str(ph.n_robots), formed, str(ph.steps),
            "-" if ph.lower_bound_steps is None else str(ph.lower_bound_steps),
            _f(ph.steps_ratio), _f(ph.travel_m), _f(ph.lower_bound_travel_m), _f(ph.travel_ratio),
            str(ph.collisions), _f(ph.min_separation_m, 3), _f(ph.final_error_m, 4),
            str(ph.deadline_misses),
            f"{ph.swaps_accepted}" + (f" ({ph.swaps_refused} refused)" if ph.swaps_refused else ""),
            _ids(ph.joined), _ids(ph.lost),
            ",".join(_short_brain(b) for b in sorted(ph.brains)) or "-",
        ])
    out += ["", *_table(header, rows, {0, 2, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13})]
    ids = sorted({rid for ph in r.phases for rid in ph.travel_per_robot_m})
    if ids:
        header = ["robot", *[f"{ph.index}:{ph.pattern}" for ph in r.phases], "total m"]
        rows = []
        for rid in ids:
            per = [ph.travel_per_robot_m.get(rid) for ph in r.phases]
            rows.append([str(rid), *[_f(v) for v in per], _f(sum(v for v in per if v))])
        out += ["", "travel per robot (m)",
                *_table(header, rows, set(range(len(header))))]
    notes = [f"phase {ph.index}: differs from the world's phase_end in {', '.join(ph.mismatches)}"
             for ph in r.phases if ph.mismatches]
    checked = [ph for ph in r.phases if ph.world is not None]
    if checked and not notes:
        notes.append(f"recomputed figures agree with the world's phase_end ({len(checked)} "
                     f"phase{'s' if len(checked) > 1 else ''})")
    return "\n".join([*out, "", *notes]) if notes else "\n".join(out)


def format_compare(a: RunReport, b: RunReport) -> str:
    """Two runs side by side, phase by phase."""
    out = [f"a: {a.path} ({a.outcome}, {'finished' if a.finished else 'cut short'})",
           f"b: {b.path} ({b.outcome}, {'finished' if b.finished else 'cut short'})", ""]
    header = ["#", "pattern", "formed a|b", "steps a", "steps b", "x lb a", "x lb b",
              "travel a", "travel b", "x lb a", "x lb b", "coll a|b", "min sep a", "min sep b",
              "misses a|b"]
    rows = []
    for k in range(max(len(a.phases), len(b.phases))):
        pa = a.phases[k] if k < len(a.phases) else None
        pb = b.phases[k] if k < len(b.phases) else None
        name = pa.pattern if pa else pb.pattern if pb else "?"
        if pa and pb and pa.pattern != pb.pattern:
            name = f"{pa.pattern}|{pb.pattern}"

        def g(p: PhaseReport | None, attr: str, nd: int = 2) -> str:
            if p is None:
                return "-"
            v = getattr(p, attr)
            return str(v) if isinstance(v, int) and not isinstance(v, bool) else _f(v, nd)

        def fm(p: PhaseReport | None) -> str:
            return "-" if p is None else "yes" if p.formed else "no"

        rows.append([str(k), name, f"{fm(pa)}|{fm(pb)}", g(pa, "steps"), g(pb, "steps"),
                     g(pa, "steps_ratio"), g(pb, "steps_ratio"), g(pa, "travel_m"),
                     g(pb, "travel_m"), g(pa, "travel_ratio"), g(pb, "travel_ratio"),
                     f"{g(pa, 'collisions')}|{g(pb, 'collisions')}",
                     g(pa, "min_separation_m", 3), g(pb, "min_separation_m", 3),
                     f"{g(pa, 'deadline_misses')}|{g(pb, 'deadline_misses')}"])
    out += _table(header, rows, {0, *range(3, 15)})

    def tot(r: RunReport) -> tuple[int, float]:
        return sum(p.steps for p in r.phases), sum(p.travel_m for p in r.phases)

    (sa, ta), (sb, tb) = tot(a), tot(b)
    out += ["", f"total: steps {sa} vs {sb} (b/a {_f(sb / sa if sa else None)}), "
                f"travel {ta:.2f} m vs {tb:.2f} m (b/a {_f(tb / ta if ta else None)})"]
    return "\n".join(out)


# ============================================================================ counterfactual


@dataclass
class Deviation:
    """Deviation of another brain's commands from the recorded ones (m/s)."""

    steps: int = 0
    mean_mps: float = 0.0
    max_mps: float = 0.0
    errors: int = 0
    """Decisions where the other brain could not act (held still)."""
    safety_interventions: int = 0


@dataclass
class CounterfactualReport:
    brain: str
    safety: bool
    realtime: bool
    per_phase: list[tuple[int, str, Deviation]]
    per_robot: dict[tuple[int, int], Deviation]
    """(phase index, robot id) -> deviation"""
    overall: Deviation

    def to_dict(self) -> dict[str, Any]:
        return {
            "brain": self.brain, "safety": self.safety, "realtime": self.realtime,
            "overall": asdict(self.overall),
            "phases": [{"index": i, "pattern": name, **asdict(d),
                        "robots": {str(rid): asdict(dv) for (pi, rid), dv in
                                   sorted(self.per_robot.items()) if pi == i}}
                       for i, name, d in self.per_phase],
        }


def _fit_pattern(msg: PatternMsg, n: int, world: WorldConfig) -> Array | None:
    """The pattern a robot uses for a team of n (:func:`runtime.team_pattern.fit_pattern`)."""
    from runtime.patterns import PatternError
    from runtime.team_pattern import fit_pattern

    try:
        return fit_pattern(msg.name, np.asarray(msg.points, dtype=np.float64), n, world)
    except PatternError:
        return None


def _summarise(dev: list[float], errors: int, interventions: int) -> Deviation:
    if not dev:
        return Deviation(0, 0.0, 0.0, errors, interventions)
    a = np.asarray(dev)
    return Deviation(len(a), round(float(a.mean()), 9), round(float(a.max()), 9), errors,
                     interventions)


def counterfactual(data: LogData, brain_ref: str, safety: bool = True) -> CounterfactualReport:
    """Run ``brain_ref`` on every recorded step as each robot would; compare with the log.

    Raises :class:`runtime.brain.BrainError` for a brain that cannot be loaded.
    """
    from runtime.brain import load_brain
    from runtime.controller import Controller
    from runtime.patterns import PatternError, make_pattern
    from runtime.safety import OrcaParams

    w = data.world
    brain = load_brain(brain_ref, w)
    params = OrcaParams() if safety else None
    fixed: Array | None = None
    m = brain.manifest
    if m is not None and brain.spec.name == "paper" and m.pattern:
        try:
            fixed = make_pattern(m.pattern, m.n_robots or brain.spec.n_robots, w)
        except PatternError:
            fixed = None
    fr, cm = data.frames, data.commands
    recorded: dict[tuple[int, int], tuple[float, float]] = {}
    for rid, step, (vx, vy) in zip(cm.robot_id.tolist(), cm.step.tolist(), cm.v.tolist(),
                                   strict=True):
        recorded.setdefault((step, rid), (vx, vy))
    version_phase: dict[int, int] = {}
    phase_logs = _phases_from_events(data.events, w) if data.events else _phases_from_wire(data)
    for pl in phase_logs:
        for p in pl.patterns:
            version_phase[p.version] = pl.index
    marks = data.patterns
    mark_at = np.asarray([mk.msg_index for mk in marks], np.int64)
    ctrl: dict[int, Controller] = {}
    team: dict[int, list[int]] = {}
    fitted: dict[tuple[int, int], Array | None] = {}
    dev: dict[tuple[int, int], list[float]] = defaultdict(list)
    errs: Counter[tuple[int, int]] = Counter()
    inter: Counter[tuple[int, int]] = Counter()
    for row in range(len(fr.steps)):
        step = int(fr.steps[row])
        k = int(np.searchsorted(mark_at, fr.first_msg[row], side="right")) - 1
        if k < 0:
            continue  # no pattern yet: robots hold still, nothing to compare
        msg = marks[k].msg
        phase = version_phase.get(msg.version, -1)
        cols = np.nonzero(fr.present[row])[0]
        ids = [int(fr.ids[c]) for c in cols]
        pos = fr.xy[row][cols]
        n = len(ids)
        if fixed is not None:
            pattern = fixed if len(fixed) == n else None
        else:
            key = (msg.version, n)
            if key not in fitted:
                fitted[key] = _fit_pattern(msg, n, w)
            pattern = fitted[key]
        for i, rid in enumerate(ids):
            c = ctrl.get(rid)
            if c is None:
                c = ctrl[rid] = Controller(brain, w, params)
            if team.get(rid) != ids:
                c.reset()
                team[rid] = ids
            if pattern is None:
                vx = vy = 0.0
                errs[(phase, rid)] += 1
            else:
                d = c.decide(i, pos, pattern, step)
                vx, vy = d.velocity
                if d.error:
                    errs[(phase, rid)] += 1
                if d.safety_changed:
                    inter[(phase, rid)] += 1
            rv = recorded.get((step, rid))
            if rv is not None:
                dev[(phase, rid)].append(math.hypot(vx - rv[0], vy - rv[1]))
    names = {pl.index: pl.name for pl in phase_logs}
    per_robot = {key: _summarise(v, errs[key], inter[key]) for key, v in dev.items()}
    per_phase = []
    for pi in sorted({key[0] for key in dev}):
        allv = [x for key, v in dev.items() if key[0] == pi for x in v]
        per_phase.append((pi, names.get(pi, "(none)"), _summarise(
            allv, sum(e for key, e in errs.items() if key[0] == pi),
            sum(e for key, e in inter.items() if key[0] == pi))))
    overall = _summarise([x for v in dev.values() for x in v], sum(errs.values()),
                         sum(inter.values()))
    realtime = any(e.get("mode") == "realtime" for e in data.events_of("run_start"))
    return CounterfactualReport(brain.brain_id if brain_ref.startswith("rule:") else
                                f"{Path(brain_ref).name} ({brain.brain_id[:8]})", safety,
                                realtime, per_phase, per_robot, overall)


def format_counterfactual(cf: CounterfactualReport) -> str:
    out = [f"counterfactual: {cf.brain}, safety filter {'on' if cf.safety else 'off'}: "
           f"deviation from the recorded commands over {cf.overall.steps} decisions: "
           f"mean {cf.overall.mean_mps:.4f} m/s, max {cf.overall.max_mps:.4f} m/s"]
    if cf.realtime:
        out.append("(realtime log: the robots decided at their own pace; deviations include it)")
    header = ["#", "pattern", "robot", "decisions", "mean m/s", "max m/s", "held", "filtered"]
    rows = []
    for pi, name, d in cf.per_phase:
        rows.append([str(pi) if pi >= 0 else "-", name, "all", str(d.steps),
                     f"{d.mean_mps:.4f}", f"{d.max_mps:.4f}", str(d.errors),
                     str(d.safety_interventions)])
        for (ppi, rid), dv in sorted(cf.per_robot.items()):
            if ppi == pi:
                rows.append(["", "", str(rid), str(dv.steps), f"{dv.mean_mps:.4f}",
                             f"{dv.max_mps:.4f}", str(dv.errors), str(dv.safety_interventions)])
    return "\n".join([*out, "", *_table(header, rows, {0, 2, 3, 4, 5, 6, 7})])


# ============================================================================ repair


def repair(src: str | Path, dst: str | Path, chunk_size: int = 1 << 20) -> Recovery:
    """Copy every recoverable message of ``src`` into a finished, indexed MCAP at ``dst``."""
    from mcap.writer import CompressionType, Writer

    rec = Recovery()
    src_p, dst_p = Path(src), Path(dst)
    if src_p.resolve() == dst_p.resolve():
        raise LogError(f"{dst_p}: the repaired copy must not overwrite its source")
    check_log_file(src_p)
    dst_p.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst_p.with_name(dst_p.name + ".part")
    with open(tmp, "wb") as f:
        writer = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        started = False
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        for ch, lt, pt, seq, payload in iter_messages(src_p, rec):
            if not started:
                writer.start(profile=rec.profile,
                             library=(rec.library + "; repaired by patternrl replay").lstrip("; "))
                started = True
            cid = channel_ids.get(ch.id)
            if cid is None:
                sid = 0
                if ch.schema_id != 0:
                    sid = schema_ids.get(ch.schema_id, 0)
                    if not sid:
                        sid = schema_ids[ch.schema_id] = writer.register_schema(
                            ch.schema_name, ch.schema_encoding, ch.schema_data)
                cid = channel_ids[ch.id] = writer.register_channel(
                    ch.topic, ch.message_encoding, sid, ch.metadata)
            writer.add_message(cid, lt, payload, pt, seq)
        if not started:
            writer.start(profile=rec.profile, library="patternrl replay (repaired, empty)")
        writer.finish()  # type: ignore[no-untyped-call]
    tmp.replace(dst_p)
    return rec
