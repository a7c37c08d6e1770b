"""The one reader of a run's log: :func:`read_log` -> :class:`LogData`.

Replay, the report, plots, play-back and the benchmarks all read logs through
here (play-back needs only the raw messages: :func:`sim_bridge.log_file.iter_messages`).
One pass over the records (:func:`sim_bridge.log_file.blocks`, so a log cut
short is read up to its last complete chunk): pose and command payloads are only
collected there and decoded column-wise afterwards (:mod:`sim_bridge.log_columns`);
pattern messages are decoded as they come (a new version is a :class:`PatternMark`);
JSON is parsed for events and metrics only; every other message is just counted.
Channels are told apart by :mod:`sim_bridge.log_layout`.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Final

from runtime import keys
from runtime.messages import MessageError, PatternMsg, decode_pattern
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from sim_bridge.log_columns import Commands, Frames, decode_commands, decode_poses, frames_of
from sim_bridge.log_file import MESSAGE, OP_MESSAGE, RECORD, Records, Recovery, blocks
from sim_bridge.log_layout import EVENTS_TOPIC, METRICS_TOPIC, wire_kind


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


_OTHER, _POSE, _CMD, _PATTERN, _EVENT, _METRIC = range(6)
_WIRE_KINDS: Final = {keys.POSE: _POSE, keys.CMD: _CMD, keys.PATTERN: _PATTERN}
_JSON_TOPICS: Final = {EVENTS_TOPIC: _EVENT, METRICS_TOPIC: _METRIC}


def _kind(topic: str, message_encoding: str) -> tuple[int, int]:
    """(what the reader does with a channel's messages, robot id on its key or -1)."""
    kind, rid = wire_kind(topic, message_encoding)
    if kind:
        return _WIRE_KINDS.get(kind, _OTHER), rid
    return _JSON_TOPICS.get(topic, _OTHER), -1


def read_log(path: str | Path) -> LogData:
    """Read and decode a log (finished or cut short); :class:`LogError` if it is no log."""
    recovery = Recovery()
    state = Records()
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
                            kind[cid], key_rid[cid] = _kind(ch.topic, ch.message_encoding)
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
    prec, pidx, bad_p = decode_poses(pose_raw, pose_idx, pose_rid)
    cmds, bad_c = decode_commands(cmd_raw, cmd_rid)
    topics = {state.channels[cid].topic: c for cid, c in counts.items() if c}
    return LogData(
        path=str(path), recovery=recovery, events=events, metrics=metrics,
        frames=frames_of(prec, pidx), commands=cmds, patterns=patterns, topics=topics,
        malformed=malformed + bad_p + bad_c, first_log_ns=max(first_ns, 0),
        last_log_ns=max(last_ns, 0), world=_world_from(events),
    )
