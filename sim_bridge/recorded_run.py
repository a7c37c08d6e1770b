"""A log as a per-step dict of decoded poses: the view older callers read.

Built on the one reader (:func:`sim_bridge.log_file.iter_messages`): no MCAP
parsing of its own. New code reads :func:`sim_bridge.log_reader.read_log`, whose
columns (``frames``, ``commands``) hold the same poses and commands; this view
decodes each message into its :mod:`runtime.messages` object instead, which is
convenient for a few steps and slow for a whole run.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from runtime import messages as wire
from sim_bridge.log_file import Recovery, iter_messages
from sim_bridge.log_layout import EVENTS_TOPIC, METRICS_TOPIC, WIRE_SCHEMAS

_POSE, _PATTERN, _COMMAND = (WIRE_SCHEMAS[k] for k in ("pose", "pattern", "cmd"))


@dataclass
class LogMessage:
    """One recorded message."""

    topic: str
    schema: str
    log_time_ns: int
    data: bytes


@dataclass
class LogScan:
    """How far a read got: ``complete`` is False for a log cut short (a killed writer)."""

    messages: int = 0
    complete: bool = True
    error: str = ""


def iter_log(path: str | Path, scan: LogScan | None = None) -> Iterator[LogMessage]:
    """Every message of a log in file order, up to the last complete chunk.

    A log cut short is not an error: iteration stops and ``scan.complete`` turns
    False with the reason in ``scan.error``.
    """
    scan = scan if scan is not None else LogScan()
    rec = Recovery()
    for ch, lt, _pt, _seq, data in iter_messages(path, rec):
        scan.messages += 1
        yield LogMessage(ch.topic, ch.schema_name, lt, bytes(data))
    scan.complete = rec.finished
    scan.error = rec.error


@dataclass
class RecordedRun:
    """A log decoded message by message."""

    events: list[dict[str, Any]] = field(default_factory=list)
    metrics: list[dict[str, Any]] = field(default_factory=list)
    poses: dict[int, dict[int, wire.Pose]] = field(default_factory=dict)
    """step -> robot id -> the pose the world published at that step."""
    patterns: list[wire.PatternMsg] = field(default_factory=list)
    commands: int = 0
    malformed: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    scan: LogScan = field(default_factory=LogScan)

    def events_of(self, kind: str) -> list[dict[str, Any]]:
        """Events of one kind, in order."""
        return [e for e in self.events if e.get("kind") == kind]


def read_run(path: str | Path) -> RecordedRun:
    """Decode a log (complete or cut short) into a :class:`RecordedRun`."""
    run = RecordedRun()
    for m in iter_log(path, run.scan):
        run.topics[m.topic] = run.topics.get(m.topic, 0) + 1
        try:
            if m.topic == EVENTS_TOPIC:
                run.events.append(json.loads(m.data))
            elif m.topic == METRICS_TOPIC:
                run.metrics.append(json.loads(m.data))
            elif m.schema == _POSE:
                p = wire.decode_pose(m.data)
                run.poses.setdefault(p.step, {})[p.robot_id] = p
            elif m.schema == _PATTERN:
                pm = wire.decode_pattern(m.data)
                if not run.patterns or run.patterns[-1].version != pm.version:
                    run.patterns.append(pm)
            elif m.schema == _COMMAND:
                run.commands += 1
        except (wire.MessageError, ValueError):
            run.malformed += 1
    return run
