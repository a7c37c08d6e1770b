"""Writes the MCAP log of a run: everything the world saw and did, time-stamped.

The channels, encodings and schemas are :mod:`sim_bridge.log_layout`'s; this
module writes them (:class:`Recorder`) and builds the Foxglove scene of a step
(:func:`scene_update`). Durability: chunks are small (``chunk_size`` bytes) and
the writer is flushed at least every ``flush_period_s``, so a writer killed with
SIGKILL leaves a file that :mod:`sim_bridge.log_reader` reads up to its last
complete chunk. A finished log also has the summary section and reads with any
reader.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
from mcap.writer import CompressionType, Writer

from runtime.world_config import DEFAULT_WORLD, WorldConfig
from sim_bridge.log_layout import (
    EVENTS_TOPIC,
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    JSON_TOPICS,
    METRICS_TOPIC,
    SCENE_FRAME,
    SCENE_TOPIC,
    WIRE_ENCODING,
    WIRE_SCHEMA_DATA,
    wire_schema,
)

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
        for topic, schema in JSON_TOPICS:
            self._json_channel(topic, schema)

    # ------------------------------------------------------------------ channels

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(name=name, encoding=encoding, data=data)
            self._schemas[name] = sid
        return sid

    def _json_channel(self, topic: str, schema: dict[str, Any]) -> int:
        sid = self._schema(schema["title"], JSON_SCHEMA_ENCODING, json.dumps(schema).encode())
        cid = self._writer.register_channel(topic=topic, message_encoding=JSON_ENCODING,
                                            schema_id=sid)
        self._channels[topic] = cid
        return cid

    def _wire_channel(self, key: str) -> int:
        cid = self._channels.get(key)
        if cid is not None:
            return cid
        schema_name = wire_schema(key)
        sid = 0
        if schema_name is not None:
            sid = self._schema(schema_name, WIRE_ENCODING, WIRE_SCHEMA_DATA)
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
