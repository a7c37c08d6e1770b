"""The MCAP log of a run: everything the world saw and did, time-stamped.

Channel layout (``log_time`` = wall clock, ns since the Unix epoch;
``K`` = ``patternrl/<swarm>``):

=========================  ===================  ===========================  ==============
topic                      message encoding     schema (schema encoding)     what
=========================  ===================  ===========================  ==============
``K/robot/<id>/pose``      ``patternrl-wire``   ``patternrl.Pose``           world -> robot
``K/robot/<id>/cmd``       ``patternrl-wire``   ``patternrl.Command``        robot -> world
``K/robot/<id>/status``    ``patternrl-wire``   ``patternrl.Status``         robot health
``K/pattern``              ``patternrl-wire``   ``patternrl.Pattern``        target pattern
``K/brain``                ``patternrl-wire``   ``patternrl.Brain``          brain swaps
other keys under ``K``     ``patternrl-wire``   none (schema id 0)           raw bytes
``/world/events``          ``json``             ``patternrl.Event``          see below
``/world/metrics``         ``json``             ``patternrl.StepMetrics``    one per step
``/world/scene``           ``json``             ``foxglove.SceneUpdate``     one per step
=========================  ===================  ===========================  ==============

Wire schemas have schema encoding ``patternrl-wire``; the JSON ones ``jsonschema``.
Wire channels hold the Zenoh payloads byte for byte, as :mod:`runtime.messages`
encodes them (``patternrl-wire``: a tag byte, a version byte, little-endian
``struct`` fields; the schema record's data is that module's layout description).
One channel per key, so a robot's poses are one topic.

``/world/events`` (one JSON object each, ``kind`` plus ``step`` and ``time_s``):
``run_start`` (configuration), ``pattern`` (a pattern published: version, name,
points, reason ``phase`` or ``resize``), ``phase_start``, ``phase_end`` (the
phase's results: formed, steps, lower bounds, travel, collisions, min separation,
deadline misses, brain), ``brain_swap`` (per robot: accepted, reason), ``join``,
``leave``, ``collision`` (robot pairs that overlapped during the step),
``contact`` (pairs the physics saw start touching, walls included),
``deadline_miss`` (robots that had not answered step ``for_step`` in time), ``malformed``
(a payload that did not decode), ``run_end`` (outcome).

``/world/scene``: one ``foxglove.SceneUpdate`` per step, frame ``world``: an
entity per robot (entity id = the robot id, a cylinder of diameter 2R at its
position), an entity ``targets`` (a small sphere at each target slot, placed on
the team's centroid) and ``arena`` (the walls as a line loop). A robot that left
is deleted by id. The log opens in Foxglove's 3D panel without custom panels.

Durability: chunks are small (``chunk_size`` bytes) and the writer is flushed at
least every ``flush_period_s``, so a writer killed with SIGKILL leaves a file
that :func:`iter_log` (mcap's non-seeking reader) reads up to its last complete
chunk. A finished log also has the summary section and reads with any reader.
"""

from __future__ import annotations

import json
import struct
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from mcap.writer import CompressionType, Writer

from runtime import messages as wire
from runtime.world_config import DEFAULT_WORLD, WorldConfig

WIRE_ENCODING: Final = "patternrl-wire"
EVENTS_TOPIC: Final = "/world/events"
METRICS_TOPIC: Final = "/world/metrics"
SCENE_TOPIC: Final = "/world/scene"
SCENE_FRAME: Final = "world"

# key suffix -> schema name of the wire message on that key
_WIRE_SCHEMAS: Final = {
    "pose": "patternrl.Pose",
    "cmd": "patternrl.Command",
    "status": "patternrl.Status",
    "pattern": "patternrl.Pattern",
    "brain": "patternrl.Brain",
}

EVENT_SCHEMA: Final[dict[str, Any]] = {
    "title": "patternrl.Event",
    "description": "Something the world did or saw; fields beyond these depend on kind.",
    "type": "object",
    "properties": {
        "kind": {"type": "string", "description": "run_start, pattern, phase_start, phase_end, "
                 "brain_swap, join, leave, collision, contact, deadline_miss, malformed, run_end"},
        "step": {"type": "integer", "description": "world step when it happened"},
        "time_s": {"type": "number", "description": "simulated time, step * dt (s)"},
    },
    "required": ["kind", "step", "time_s"],
}

METRICS_SCHEMA: Final[dict[str, Any]] = {
    "title": "patternrl.StepMetrics",
    "description": "Per-step figures of the formation, after the step's physics.",
    "type": "object",
    "properties": {
        "step": {"type": "integer"},
        "time_s": {"type": "number"},
        "phase": {"type": "integer", "description": "index of the pattern in the sequence"},
        "pattern": {"type": "string"},
        "pattern_version": {"type": "integer"},
        "phase_step": {"type": "integer", "description": "steps since the phase began"},
        "n_live": {"type": "integer"},
        "formation_error_m": {"type": "number"},
        "max_slot_distance_m": {"type": "number"},
        "min_separation_m": {"type": "number"},
        "collisions": {"type": "integer", "description": "robot pairs overlapping this step"},
        "contacts": {"type": "integer", "description": "contacts the physics saw begin"},
        "deadline_misses": {"type": "integer", "description": "robots that held still"},
        "wall_ms": {"type": "number", "description": "wall time of the step (ms)"},
    },
    "required": ["step", "time_s", "n_live", "formation_error_m", "min_separation_m"],
}


def _obj(title: str, props: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": props, "required": list(props)}


def _scene_schema() -> dict[str, Any]:
    """JSON schema of ``foxglove.SceneUpdate``, the parts this log writes.

    Names and fields follow Foxglove's published schema; the primitive arrays this
    log leaves empty are declared as arrays of objects.
    """
    num = {"type": "number"}
    time_ = _obj("time", {"sec": {"type": "integer", "minimum": 0},
                          "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}})
    dur = _obj("duration", {"sec": {"type": "integer"},
                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}})
    vec3 = _obj("foxglove.Vector3", {"x": num, "y": num, "z": num})
    quat = _obj("foxglove.Quaternion", {"x": num, "y": num, "z": num, "w": num})
    pose = _obj("foxglove.Pose", {"position": vec3, "orientation": quat})
    color = _obj("foxglove.Color", {"r": num, "g": num, "b": num, "a": num})
    point3 = _obj("foxglove.Point3", {"x": num, "y": num, "z": num})
    any_arr = {"type": "array", "items": {"type": "object"}}
    sphere = _obj("foxglove.SpherePrimitive", {"pose": pose, "size": vec3, "color": color})
    cylinder = _obj("foxglove.CylinderPrimitive", {
        "pose": pose, "size": vec3, "bottom_scale": num, "top_scale": num, "color": color})
    line = _obj("foxglove.LinePrimitive", {
        "type": {"title": "foxglove.LineType", "oneOf": [
            {"title": "LINE_STRIP", "const": 0}, {"title": "LINE_LOOP", "const": 1},
            {"title": "LINE_LIST", "const": 2}]},
        "pose": pose, "thickness": num, "scale_invariant": {"type": "boolean"},
        "points": {"type": "array", "items": point3}, "color": color,
        "colors": {"type": "array", "items": color},
        "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}}})
    text = _obj("foxglove.TextPrimitive", {
        "pose": pose, "billboard": {"type": "boolean"}, "font_size": num,
        "scale_invariant": {"type": "boolean"}, "color": color, "text": {"type": "string"}})
    kv = _obj("foxglove.KeyValuePair", {"key": {"type": "string"}, "value": {"type": "string"}})
    entity = _obj("foxglove.SceneEntity", {
        "timestamp": time_, "frame_id": {"type": "string"}, "id": {"type": "string"},
        "lifetime": dur, "frame_locked": {"type": "boolean"},
        "metadata": {"type": "array", "items": kv},
        "arrows": any_arr, "cubes": any_arr,
        "spheres": {"type": "array", "items": sphere},
        "cylinders": {"type": "array", "items": cylinder},
        "lines": {"type": "array", "items": line},
        "triangles": any_arr,
        "texts": {"type": "array", "items": text},
        "models": any_arr,
    })
    deletion = _obj("foxglove.SceneEntityDeletion", {
        "timestamp": time_,
        "type": {"title": "foxglove.SceneEntityDeletionType", "oneOf": [
            {"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}]},
        "id": {"type": "string"}})
    out = _obj("foxglove.SceneUpdate", {
        "deletions": {"type": "array", "items": deletion},
        "entities": {"type": "array", "items": entity}})
    out["description"] = "An update to the entities displayed in a 3D scene"
    return out


SCENE_SCHEMA: Final = _scene_schema()

_IDENTITY: Final = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def _colour(i: int) -> dict[str, float]:
    """A stable, distinct colour per robot id (tab10 cycle)."""
    tab10 = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
             (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
    r, g, b = tab10[i % len(tab10)]
    return {"r": r / 255, "g": g / 255, "b": b / 255, "a": 1.0}


def _entity(stamp: dict[str, int], eid: str, **prims: list[dict[str, Any]]) -> dict[str, Any]:
    ent: dict[str, Any] = {
        "timestamp": stamp, "frame_id": SCENE_FRAME, "id": eid,
        "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
        "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "lines": [],
        "triangles": [], "texts": [], "models": [],
    }
    ent.update(prims)
    return ent


def scene_update(
    log_time_ns: int,
    robots: Sequence[tuple[int, float, float]],
    targets: np.ndarray | None,
    removed: Sequence[int] = (),
    arena_m: float | None = None,
    world: WorldConfig = DEFAULT_WORLD,
) -> dict[str, Any]:
    """One ``foxglove.SceneUpdate``: a disc per robot (id = robot id), targets, walls."""
    stamp = {"sec": log_time_ns // 1_000_000_000, "nsec": log_time_ns % 1_000_000_000}
    d = 2.0 * world.radius_m
    height = 0.5 * world.radius_m
    entities = []
    for rid, x, y in robots:
        cyl = {"pose": {"position": {"x": x, "y": y, "z": height / 2}, "orientation": _IDENTITY},
               "size": {"x": d, "y": d, "z": height}, "bottom_scale": 1.0, "top_scale": 1.0,
               "color": _colour(rid)}
        label = {"pose": {"position": {"x": x, "y": y, "z": height * 2}, "orientation": _IDENTITY},
                 "billboard": True, "font_size": 12.0, "scale_invariant": True,
                 "color": {"r": 1.0, "g": 1.0, "b": 1.0, "a": 1.0}, "text": str(rid)}
        entities.append(_entity(stamp, str(rid), cylinders=[cyl], texts=[label]))
    if targets is not None and len(targets):
        s = 0.5 * world.radius_m
        grey = {"r": 0.5, "g": 0.5, "b": 0.5, "a": 0.6}
        spheres = [{"pose": {"position": {"x": float(x), "y": float(y), "z": 0.0},
                             "orientation": _IDENTITY},
                    "size": {"x": s, "y": s, "z": s}, "color": grey} for x, y in targets]
        entities.append(_entity(stamp, "targets", spheres=spheres))
    if arena_m is not None:
        a = float(arena_m)
        corners = [{"x": 0.0, "y": 0.0, "z": 0.0}, {"x": a, "y": 0.0, "z": 0.0},
                   {"x": a, "y": a, "z": 0.0}, {"x": 0.0, "y": a, "z": 0.0}]
        loop = {"type": 1, "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                                    "orientation": _IDENTITY},
                "thickness": 0.02, "scale_invariant": False, "points": corners,
                "color": {"r": 0.8, "g": 0.8, "b": 0.8, "a": 1.0}, "colors": [], "indices": []}
        entities.append(_entity(stamp, "arena", lines=[loop]))
    deletions = [{"timestamp": stamp, "type": 0, "id": str(r)} for r in removed]
    return {"deletions": deletions, "entities": entities}


class Recorder:
    """Writes one run's MCAP log; safe to call from Zenoh callback threads.

    Use as a context manager or call :meth:`close`; closing twice is harmless.
    """

    def __init__(
        self,
        path: str | Path,
        chunk_size: int = 64 * 1024,
        flush_period_s: float = 0.5,
        compression: str = "zstd",
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = open(self.path, "wb")  # closed in close()
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}[compression]
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp)
        self._writer.start(profile="", library="patternrl sim_bridge")
        self._lock = threading.Lock()
        self._flush_period_ns = int(flush_period_s * 1e9)
        self._last_flush_ns = time.monotonic_ns()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._closed = False
        self.messages_written = 0
        self._file.flush()  # the header is on disk before anything else happens
        self._json_channel(EVENTS_TOPIC, EVENT_SCHEMA)
        self._json_channel(METRICS_TOPIC, METRICS_SCHEMA)
        self._json_channel(SCENE_TOPIC, SCENE_SCHEMA)

    # ------------------------------------------------------------------ channels

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(name=name, encoding=encoding, data=data)
            self._schemas[name] = sid
        return sid

    def _json_channel(self, topic: str, schema: dict[str, Any]) -> int:
        sid = self._schema(schema["title"], "jsonschema", json.dumps(schema).encode())
        cid = self._writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self._channels[topic] = cid
        return cid

    def _wire_channel(self, key: str) -> int:
        cid = self._channels.get(key)
        if cid is not None:
            return cid
        schema_name = _WIRE_SCHEMAS.get(key.rsplit("/", 1)[-1])
        sid = 0
        if schema_name is not None:
            layout = (wire.__doc__ or "").encode()
            sid = self._schema(schema_name, WIRE_ENCODING, layout)
        cid = self._writer.register_channel(
            topic=key, message_encoding=WIRE_ENCODING, schema_id=sid,
            metadata={"source": "zenoh"})
        self._channels[key] = cid
        return cid

    # ------------------------------------------------------------------ writing

    def _add(self, channel_id: int, data: bytes, log_time_ns: int | None) -> None:
        t = time.time_ns() if log_time_ns is None else log_time_ns
        self._writer.add_message(channel_id=channel_id, log_time=t, data=data, publish_time=t)
        self.messages_written += 1
        now = time.monotonic_ns()
        if now - self._last_flush_ns >= self._flush_period_ns:
            self._writer.flush()  # type: ignore[no-untyped-call]
            self._last_flush_ns = now

    def write_wire(self, key: str, payload: bytes, log_time_ns: int | None = None) -> None:
        """Record a Zenoh payload on ``key`` byte for byte."""
        with self._lock:
            if self._closed:
                return
            self._add(self._wire_channel(key), bytes(payload), log_time_ns)

    def write_json(self, topic: str, obj: dict[str, Any], log_time_ns: int | None = None) -> None:
        """Record one JSON object on one of the ``/world/*`` topics."""
        data = json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
        with self._lock:
            if self._closed:
                return
            self._add(self._channels[topic], data, log_time_ns)

    def event(self, kind: str, step: int, time_s: float, **fields: Any) -> dict[str, Any]:
        """Record an event on ``/world/events``; returns the object written."""
        obj = {"kind": kind, "step": int(step), "time_s": round(float(time_s), 6), **fields}
        self.write_json(EVENTS_TOPIC, obj)
        return obj

    def metrics(self, obj: dict[str, Any], log_time_ns: int | None = None) -> None:
        """Record one step's metrics on ``/world/metrics``."""
        self.write_json(METRICS_TOPIC, obj, log_time_ns)

    def scene(self, update: dict[str, Any], log_time_ns: int | None = None) -> None:
        """Record one ``foxglove.SceneUpdate`` on ``/world/scene``."""
        self.write_json(SCENE_TOPIC, update, log_time_ns)

    def flush(self) -> None:
        """Finish the chunk in progress and push everything to the file."""
        with self._lock:
            if not self._closed:
                self._writer.flush()  # type: ignore[no-untyped-call]
                self._last_flush_ns = time.monotonic_ns()

    def close(self) -> None:
        """Write the summary section and close the file."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()  # type: ignore[no-untyped-call]
            finally:
                self._file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------- reading


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
    """Every message of a log in file order, with mcap's non-seeking reader.

    A log whose writer was killed ends in an incomplete chunk or record: iteration
    stops there (after the last complete chunk) and ``scan.complete`` turns False
    with the reason in ``scan.error``; nothing is raised for that.
    """
    scan = scan if scan is not None else LogScan()
    with open(path, "rb") as f:
        reader = NonSeekingReader(f, record_size_limit=256 << 20)
        it = reader.iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, msg = next(it)
            except StopIteration:
                break
            except (McapError, EOFError, ValueError, OSError, struct.error) as e:
                scan.complete = False
                scan.error = f"{type(e).__name__}: {e}"[:200]
                break
            scan.messages += 1
            yield LogMessage(channel.topic, schema.name if schema else "", msg.log_time, msg.data)
    if scan.complete and not _has_footer(Path(path)):
        scan.complete = False
        scan.error = scan.error or "no footer: the writer did not finish"


def _has_footer(path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(0, 2)
        if f.tell() < 8:
            return False
        f.seek(-8, 2)
        return f.read(8) == b"\x89MCAP0\r\n"


@dataclass
class RecordedRun:
    """A log decoded: what analysis, the launcher's table and the figure need."""

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
            elif m.schema == "patternrl.Pose":
                p = wire.decode_pose(m.data)
                run.poses.setdefault(p.step, {})[p.robot_id] = p
            elif m.schema == "patternrl.Pattern":
                pm = wire.decode_pattern(m.data)
                if not run.patterns or run.patterns[-1].version != pm.version:
                    run.patterns.append(pm)
            elif m.schema == "patternrl.Command":
                run.commands += 1
        except (wire.MessageError, ValueError):
            run.malformed += 1
    return run
