"""The one reader of a run's log: :func:`read_log` -> :class:`LogData`.

Replay, the report, plots, play-back and the benchmarks all read logs through
here (play-back needs only the raw messages: :func:`sim_bridge.log.file.iter_messages`).
One pass over the records (:func:`sim_bridge.log.file.blocks`, so a log cut
short is read up to its last complete chunk): pose and command payloads are only
collected there and decoded column-wise afterwards (:mod:`sim_bridge.log.columns`);
pattern messages are decoded as they come (a new version is a :class:`PatternMark`);
JSON is parsed for events and metrics only; every other message is just counted.
Channels are told apart by :func:`sim_bridge.log.layout.channel_kind`, so a log in
today's layout (protobuf) and an old one (``patternrl-wire``) read alike.

Views (what robots under imperfect sensing perceived, ``K/robot/<id>/view``) are collected
too and decoded afterwards (:mod:`sim_bridge.log.views`); a log without them has none.

What cannot be part of the run is skipped and said (:attr:`LogData.skipped`): a pose,
command or view whose step lies outside the run (0 .. the last step the world noted,
or :data:`MAX_LOG_STEP` for a log without the world's notes), a robot id above
:data:`MAX_ROBOT_ID`, a command of a robot the world never placed (no pose of it
on the log), an event or metrics row whose ``step`` is not an integer; a view whose robot
id is above :data:`MAX_ROBOT_ID`.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Final

import numpy as np

from runtime.wire import keys
from runtime.wire.messages import MessageError, PatternMsg, decode_pattern
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from sim_bridge.log import schemas as pb
from sim_bridge.log.columns import (
    Commands,
    Frames,
    decode_commands,
    decode_commands_pb,
    decode_poses,
    decode_poses_pb,
    frames_of,
)
from sim_bridge.log.file import (
    MESSAGE,
    OP_MESSAGE,
    RECORD,
    LogError,
    Records,
    Recovery,
    blocks,
)
from sim_bridge.log.layout import (
    EVENTS_TOPIC,
    METRICS_TOPIC,
    OTHER_TOPIC,
    SCENE_TOPIC,
    channel_kind,
)
from sim_bridge.log.views import Views, decode_views, select

MAX_LOG_STEP: Final = 10_000_000
"""The last step of a log without the world's notes (11 days at 10 Hz)."""
MAX_ROBOT_ID: Final = 65_535


def as_int(v: Any, default: int = 0) -> int:
    """``v`` if it is an integer (not a bool), else ``default`` (logs other writers made)."""
    return v if isinstance(v, int) and not isinstance(v, bool) else default


@dataclass
class PatternMark:
    """A new pattern version on the wire, and where in the log it arrived."""

    msg: PatternMsg
    msg_index: int
    log_time_ns: int


@dataclass
class LogData:
    """One log, decoded: everything replay, reports, plots and benchmarks read."""

    path: str
    recovery: Recovery
    events: list[dict[str, Any]]
    """``/world/events``, in file order"""
    metrics: list[dict[str, Any]]
    """``/world/metrics``, in file order"""
    frames: Frames
    commands: Commands
    patterns: list[PatternMark]
    topics: dict[str, int]
    """topic -> messages recorded on it (topics with at least one)"""
    malformed: int
    """payloads that did not decode (poses, commands, patterns, events, metrics)"""
    first_log_ns: int
    last_log_ns: int
    world: WorldConfig
    """The world of the ``run_start`` event (the default world without one)."""
    skipped: dict[str, int]
    """what was skipped as no part of the run -> how many (see the module)"""
    wire_layout: bool = False
    """an old log (Zenoh payloads as ``patternrl-wire`` bytes)"""
    views: Views = field(default_factory=Views.empty)
    """what robots under imperfect sensing perceived (none in a log without views)"""

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        """Events of one kind, in order."""
        return [e for e in self.events if e.get("kind") == kind]


def _world_from(events: list[dict[str, Any]]) -> WorldConfig:
    for e in events:
        if e.get("kind") == "run_start" and isinstance(e.get("world"), dict):
            names = {f.name for f in fields(WorldConfig)}
            try:
                return WorldConfig(**{k: v for k, v in e["world"].items() if k in names})
            except (TypeError, ValueError):
                break
    return DEFAULT_WORLD


_OTHER, _POSE, _CMD, _PATTERN, _EVENT, _METRIC, _RAW, _VIEW = range(8)
_WIRE_KINDS: Final = {keys.POSE: _POSE, keys.CMD: _CMD, keys.PATTERN: _PATTERN,
                      keys.VIEW: _VIEW}
_JSON_TOPICS: Final = {EVENTS_TOPIC: _EVENT, METRICS_TOPIC: _METRIC}


def _kind(topic: str, message_encoding: str, schema_name: str) -> tuple[int, int, bool]:
    """(what the reader does with a channel's messages, robot id on its key or -1, old wire)."""
    kind, rid, wire = channel_kind(topic, message_encoding, schema_name)
    if kind:
        return _WIRE_KINDS.get(kind, _OTHER), rid, wire
    if topic == OTHER_TOPIC and schema_name == pb.RAW_SAMPLE:
        return _RAW, -1, False
    return _JSON_TOPICS.get(topic, _OTHER), -1, False


def _pattern(raw: bytes, wire: bool) -> PatternMsg:
    if wire:
        return decode_pattern(raw)
    try:
        m = pb.parse(pb.PATTERN, raw)
        pts = np.stack([np.asarray(m.x, float), np.asarray(m.y, float)], axis=1)
        return PatternMsg(int(m.version), str(m.name), pts.reshape(-1, 2), float(m.formed_tol_m))
    except ValueError as e:
        raise MessageError(str(e)) from None


def _is_malformed_sample(raw: bytes) -> bool:
    try:
        return bool(pb.parse(pb.RAW_SAMPLE, raw).reason)
    except ValueError:
        return True


PROJECT_LIBRARY_PREFIX: Final = "patternrl"
"""How the MCAP header's ``library`` of every log the project writes begins."""


def _is_project_log(recovery: Recovery, channels: dict[int, Any],
                    kind: dict[int, tuple[int, int, bool]]) -> bool:
    """Whether a readable MCAP file is a Pattern-RL log: written by the project (its
    header says so) or carrying at least one channel of the project's layout."""
    if recovery.library.startswith(PROJECT_LIBRARY_PREFIX):
        return True
    return any(k[0] != _OTHER or channels[cid].topic == SCENE_TOPIC for cid, k in kind.items())


def read_log(path: str | Path) -> LogData:
    """Read and decode a log (finished or cut short); :class:`LogError` if it is no log,
    including a valid MCAP file another tool wrote, with none of the project's channels."""
    recovery = Recovery()
    state = Records()
    kind: dict[int, tuple[int, int, bool]] = {}
    counts: dict[int, int] = {}
    # (payloads, message indices, robot id on the key) of each layout: [old wire, protobuf]
    pose_raw: tuple[list[bytes], list[bytes]] = ([], [])
    pose_idx: tuple[list[int], list[int]] = ([], [])
    pose_rid: tuple[list[int], list[int]] = ([], [])
    cmd_raw: tuple[list[bytes], list[bytes]] = ([], [])
    cmd_idx: tuple[list[int], list[int]] = ([], [])
    cmd_rid: tuple[list[int], list[int]] = ([], [])
    json_msgs: list[tuple[int, bytes]] = []
    view_raw: list[bytes] = []
    view_wire: list[bool] = []
    view_rid: list[int] = []
    patterns: list[PatternMark] = []
    malformed = 0
    wire_seen = False
    first_ns = last_ns = -1
    i = 0  # messages so far
    unpack_rec, unpack_msg = RECORD.unpack_from, MESSAGE.unpack_from
    for buf in blocks(path, recovery):
        p, n = 0, len(buf)
        try:
            while p < n:
                op, length = unpack_rec(buf, p)
                s = p + 9
                p = s + length
                if p > n:
                    raise ValueError("record runs past its chunk")
                if op != OP_MESSAGE:
                    state.other(op, memoryview(buf)[s:p])
                    for cid, ch in state.channels.items():
                        if cid not in kind:
                            kind[cid] = _kind(ch.topic, ch.message_encoding, ch.schema_name)
                            counts[cid] = 0
                    continue
                cid, _seq, lt, _pt = unpack_msg(buf, s)
                k, rid, wire = kind[cid]
                counts[cid] += 1
                if first_ns < 0:
                    first_ns = lt
                last_ns = lt
                if k == _POSE:
                    w = 0 if wire else 1
                    pose_raw[w].append(buf[s + 22 : p])
                    pose_idx[w].append(i)
                    pose_rid[w].append(rid)
                elif k == _CMD:
                    w = 0 if wire else 1
                    cmd_raw[w].append(buf[s + 22 : p])
                    cmd_idx[w].append(i)
                    cmd_rid[w].append(rid)
                elif k == _VIEW:
                    view_raw.append(buf[s + 22 : p])
                    view_wire.append(wire)
                    view_rid.append(rid)
                elif k == _EVENT or k == _METRIC:
                    json_msgs.append((k, buf[s + 22 : p]))
                elif k == _PATTERN:
                    try:
                        pm = _pattern(buf[s + 22 : p], wire)
                    except MessageError:
                        malformed += 1
                    else:
                        if not patterns or patterns[-1].msg.version != pm.version:
                            patterns.append(PatternMark(pm, i, lt))
                elif k == _RAW and _is_malformed_sample(buf[s + 22 : p]):
                    malformed += 1
                wire_seen = wire_seen or wire
                i += 1
        except (ValueError, KeyError, struct.error, UnicodeDecodeError) as e:
            recovery.error = f"unreadable record inside a chunk: {e}"[:200]
            recovery.corrupted = True
            break
    recovery.messages = i
    if not _is_project_log(recovery, state.channels, kind):
        by = f" (written by '{recovery.library}')" if recovery.library else ""
        raise LogError(f"{path}: not a Pattern-RL log{by}: an MCAP file with none of its "
                       f"channels ({EVENTS_TOPIC}, robot poses, ...)")
    skipped: dict[str, int] = {}
    events: list[dict[str, Any]] = []
    metrics: list[dict[str, Any]] = []
    for k, raw in json_msgs:
        try:
            obj = json.loads(raw)
        except (ValueError, UnicodeDecodeError, RecursionError):
            obj = None
        if not isinstance(obj, dict):
            malformed += 1
        elif as_int(obj.get("step"), -1) < 0:
            name = "events" if k == _EVENT else "metrics rows"
            skipped[f"{name} whose step is not an integer >= 0"] = skipped.get(
                f"{name} whose step is not an integer >= 0", 0) + 1
        else:
            (events if k == _EVENT else metrics).append(obj)
    prec, pidx, bad_p = decode_poses(pose_raw[0], pose_idx[0], pose_rid[0])
    prec2, pidx2, bad_p2 = decode_poses_pb(pose_raw[1], pose_idx[1], pose_rid[1])
    if len(prec2):
        prec, pidx = np.concatenate([prec, prec2]), np.concatenate([pidx, pidx2])
    cmds, bad_c = decode_commands(cmd_raw[0], cmd_rid[0], cmd_idx[0])
    cmds2, bad_c2 = decode_commands_pb(cmd_raw[1], cmd_rid[1], cmd_idx[1])
    cmds = cmds.concat(cmds2)
    last = _last_step(events, metrics)
    prec, pidx = _valid_poses(prec, pidx, last, skipped)
    frames = frames_of(prec, pidx)
    cmds = _valid_commands(cmds, frames.ids, last, skipped)
    views, bad_v = decode_views(view_raw, view_wire, view_rid)
    views = _valid_views(views, last, skipped)
    topics = {state.channels[cid].topic: c for cid, c in counts.items() if c}
    return LogData(
        path=str(path), recovery=recovery, events=events, metrics=metrics,
        frames=frames, commands=cmds, patterns=patterns, topics=topics,
        malformed=malformed + bad_p + bad_p2 + bad_c + bad_c2 + bad_v,
        first_log_ns=max(first_ns, 0), last_log_ns=max(last_ns, 0), world=_world_from(events),
        skipped=skipped, wire_layout=wire_seen, views=views,
    )


def _last_step(events: list[dict[str, Any]], metrics: list[dict[str, Any]]) -> int:
    """The last step the world noted (its run_end, its metrics), or :data:`MAX_LOG_STEP`."""
    noted = [as_int(e.get("steps"), -1) for e in events if e.get("kind") == "run_end"]
    noted += [as_int(m.get("step"), -1) for m in metrics[-1:]]
    noted = [s for s in noted if 0 <= s <= MAX_LOG_STEP]
    return max(noted) + 1 if noted else MAX_LOG_STEP


def _count(skipped: dict[str, int], what: str, n: int) -> None:
    if n:
        skipped[what] = skipped.get(what, 0) + n


def _valid_poses(rec: Any, idx: Any, last: int, skipped: dict[str, int]) -> tuple[Any, Any]:
    step = rec["step"].astype(np.int64)  # a step >= 2^63 wraps negative: outside too
    rid = rec["robot_id"].astype(np.int64)
    bad_step = (step < 0) | (step > last)
    bad_id = ~bad_step & (rid > MAX_ROBOT_ID)
    _count(skipped, f"poses with a step outside 0..{last}", int(bad_step.sum()))
    _count(skipped, f"poses with a robot id above {MAX_ROBOT_ID}", int(bad_id.sum()))
    ok = ~(bad_step | bad_id)
    return (rec, idx) if ok.all() else (rec[ok], idx[ok])


def _valid_commands(c: Commands, placed: Any, last: int, skipped: dict[str, int]) -> Commands:
    bad_step = (c.step < 0) | (c.step > last)
    bad_id = ~bad_step & ~np.isin(c.robot_id, placed)
    _count(skipped, f"commands with a step outside 0..{last}", int(bad_step.sum()))
    _count(skipped, "commands of robots the world never placed", int(bad_id.sum()))
    ok = ~(bad_step | bad_id)
    return c if ok.all() else c.select(ok)


def _valid_views(v: Views, last: int, skipped: dict[str, int]) -> Views:
    bad_step = (v.step < 0) | (v.step > last)
    bad_id = ~bad_step & (v.robot_id > MAX_ROBOT_ID)
    _count(skipped, f"views with a step outside 0..{last}", int(bad_step.sum()))
    _count(skipped, f"views with a robot id above {MAX_ROBOT_ID}", int(bad_id.sum()))
    return select(v, ~(bad_step | bad_id))
