"""Writes the MCAP log of a run: everything the world saw and did, time-stamped.

The channels, encodings and schemas are :mod:`sim_bridge.log.layout`'s; this
module writes them (:class:`Recorder`); the Foxglove scene of a step is
:mod:`sim_bridge.live.scene`'s. Each Zenoh payload is decoded and written as its protobuf
message (:mod:`sim_bridge.log.schemas`); one over :data:`MAX_PAYLOAD_BYTES`
(brains: :data:`MAX_BRAIN_PAYLOAD_BYTES`) is not written, an event says so. The
same messages can go to a live sink too (:class:`sim_bridge.live.foxglove_live.FoxgloveLive`),
with or without a file. Durability: chunks are small (``chunk_size`` bytes) and
the writer is flushed at least every ``flush_period_s``, so a writer killed with
SIGKILL leaves a file that :mod:`sim_bridge.log.reader` reads up to its last
complete chunk. A finished log also has the summary section and reads with any
reader.

Off the caller's path: with ``threaded`` the recorder hands every message to a writer
thread through a bounded queue (:data:`QUEUE_ITEMS`), so the world's step and Zenoh's
receive callbacks only stamp and queue it; decoding, encoding, compressing, writing and
the live view happen on the writer. A full queue drops the message and counts it
(:attr:`Recorder.dropped`; a ``log_dropped`` event at the end says how many): the log
is never silently short. :meth:`Recorder.flush` and :meth:`Recorder.close` wait for the
writer to have written everything queued before them.
"""

from __future__ import annotations

import json
import queue
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final, Protocol

from mcap.writer import CompressionType, Writer

from runtime.errors import InputError
from runtime.wire import keys
from runtime.wire.messages import (
    MessageError,
    Pose,
    decode_brain,
    decode_command,
    decode_pattern,
    decode_pose,
    decode_poses,
    decode_slots,
    decode_status,
    decode_view,
    encode_pose,
)
from sim_bridge.log import schemas as pb
from sim_bridge.log.layout import (
    EVENTS_TOPIC,
    JSON_ENCODING,
    JSON_SCHEMA_ENCODING,
    JSON_TOPICS,
    MAX_BRAIN_PAYLOAD_BYTES,
    MAX_PAYLOAD_BYTES,
    METRICS_TOPIC,
    OTHER_TOPIC,
    PB_SCHEMAS,
    PROTOBUF_ENCODING,
    SCENE_FRAME,
    SCENE_TOPIC,
    TF_TOPIC,
    WIRE_ENCODING,
    WIRE_SCHEMA_DATA,
    robot_frame,
    robot_pose_topic,
    wire_schema,
)

MALFORMED_BYTES_KEPT: Final = 256
"""Of a payload that did not decode, the first bytes kept on ``/log/other``."""
REFUSED_EVENTS: Final = 100
"""Refused payloads logged one by one as events; the count goes on."""
QUEUE_ITEMS: Final = 200_000
"""``threaded``: messages waiting for the writer at most (about 900 steps of 100 robots)."""

@dataclass(frozen=True)
class SimTime:
    """Simulated time for ``log_time``: ``start_ns + step * dt_ns`` (lockstep)."""

    start_ns: int
    """wall clock at step 0 (ns since the Unix epoch)"""
    dt_ns: int
    current_step: Callable[[], int]
    """the world's current step"""

    def at(self, step: int | None) -> int:
        """The log time of ``step``; the current step's for None or a step that cannot be
        one of the run (negative, or ahead of the world: a forged message)."""
        cur = self.current_step()
        if step is None or not 0 <= step <= cur + 2:
            step = cur
        return self.start_ns + step * self.dt_ns


class LiveSink(Protocol):
    """Where the recorder's messages also go while the run goes on (never blocks)."""

    def add_channel(self, channel_id: int, topic: str, message_encoding: str,
                    schema_name: str, schema_encoding: str, schema_data: bytes) -> None: ...

    def offer(self, channel_id: int, data: bytes, log_time_ns: int) -> None: ...


def check_output(path: str | Path, force: bool) -> Path:
    """``path`` as a place to write a new log; :class:`InputError` (one line) if it is a
    directory, or a file that exists and ``force`` is not set."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{p}: is a directory; give a file name such as {p / 'run.mcap'}")
    if p.exists() and not force:
        raise InputError(f"{p}: exists; pass --force to overwrite it")
    if p.parent.exists() and not p.parent.is_dir():
        raise InputError(f"{p.parent}: not a directory")
    return p


class _NoFile:
    """The writer of a recorder without a file (a live view alone): ids, nothing written."""

    def __init__(self) -> None:
        self._n = 0

    def _next(self, *_a: Any, **_k: Any) -> int:
        self._n += 1
        return self._n

    register_schema = register_channel = _next

    def add_message(self, *_a: Any, **_k: Any) -> None:
        pass

    def flush(self) -> None:
        pass

    def finish(self) -> None:
        pass


class Recorder:
    """Writes one run's MCAP log; safe to call from Zenoh callback threads.

    ``path`` None writes no file (the messages go to ``live`` only). ``overwrite``
    False refuses an existing file (:class:`InputError`). ``sim_time`` (settable
    later: :attr:`sim_time`) makes ``log_time`` simulated time. ``wire_layout``
    writes the layout of old logs (payloads as ``patternrl-wire`` bytes): kept so
    the reader's support of old logs stays tested. Use as a context manager or call
    :meth:`close`; closing twice is harmless.
    """

    def __init__(
        self,
        path: str | Path | None,
        chunk_size: int = 64 * 1024,
        flush_period_s: float = 0.5,
        compression: str = "zstd",
        live: LiveSink | None = None,
        overwrite: bool = True,
        sim_time: SimTime | None = None,
        wire_layout: bool = False,
        threaded: bool = False,
        queue_items: int = QUEUE_ITEMS,
    ) -> None:
        self.path = Path(path) if path is not None else None
        self._file: IO[bytes] | None = None
        self._writer: Any
        if self.path is None:
            self._writer = _NoFile()
        else:
            check_output(self.path, overwrite)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            try:
                self._file = open(self.path, "wb" if overwrite else "xb")  # closed in close()
            except FileExistsError:
                raise InputError(f"{self.path}: exists; pass --force to overwrite it") from None
            except OSError as e:
                raise InputError(f"{self.path}: cannot write: {e.strerror or e}") from None
            comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                    "none": CompressionType.NONE}[compression]
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp)
            self._writer.start(profile="", library="patternrl sim_bridge")
        self.live = live
        self.sim_time = sim_time
        self._wire_layout = wire_layout
        self._lock = threading.Lock()
        self._flush_period_ns = int(flush_period_s * 1e9)
        self._last_flush_ns = time.monotonic_ns()
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._closed = False
        self.messages_written = 0
        self.refused = 0
        """payloads not written for their size"""
        self.malformed = 0
        """payloads on the project's keys that did not decode (kept on ``/log/other``)"""
        self._tf_step = -1
        self._tf_time = 0
        self._tf: dict[int, tuple[str, float, float]] = {}
        if self._file is not None:
            self._file.flush()  # the header is on disk before anything else happens
        for topic, schema in JSON_TOPICS:
            self._json_channel(topic, schema)
        self.dropped = 0
        """``threaded``: messages not written because the writer's queue was full"""
        self.writer_errors = 0
        """``threaded``: messages whose writing raised (the writer goes on)"""
        self.writer_cpu_s = 0.0
        """``threaded``: CPU seconds the writer thread has spent so far"""
        self._clock_ns: int | None = None  # the writer's item: when it was queued
        self._queue: queue.Queue[tuple[Callable[..., None], tuple[Any, ...], int] | None] | None
        self._queue = None
        self._thread: threading.Thread | None = None
        self._drop_lock = threading.Lock()
        if threaded:
            self._queue = queue.Queue(maxsize=queue_items)
            self._thread = threading.Thread(target=self._write_queued, name="recorder-writer",
                                            daemon=True)
            self._thread.start()

    # ------------------------------------------------------------------ the writer thread

    def _queue_call(self, fn: Callable[..., None], *args: Any) -> None:
        assert self._queue is not None
        try:
            self._queue.put_nowait((fn, args, time.time_ns()))
        except queue.Full:
            with self._drop_lock:
                self.dropped += 1

    def _write_queued(self) -> None:
        assert self._queue is not None
        cpu0 = time.thread_time()
        while True:
            item = self._queue.get()
            self.writer_cpu_s = time.thread_time() - cpu0
            if item is None:
                return
            fn, args, self._clock_ns = item
            try:
                fn(*args)
            except Exception:  # one message lost, counted; the writer goes on
                self.writer_errors += 1
            finally:
                self._clock_ns = None
            time.sleep(0)  # hand the interpreter to the step and the receive callbacks

    def _wait_writer(self) -> None:
        """Return once the writer has written everything queued before this call."""
        done = threading.Event()
        assert self._queue is not None
        self._queue.put((lambda: done.set(), (), time.time_ns()))
        done.wait(timeout=60.0)

    # ------------------------------------------------------------------ channels

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            sid = self._writer.register_schema(name=name, encoding=encoding, data=data)
            self._schemas[name] = sid
        return sid

    def _channel(self, topic: str, encoding: str, schema: str, schema_encoding: str,
                 schema_data: bytes, metadata: dict[str, str] | None = None) -> int:
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        sid = self._schema(schema, schema_encoding, schema_data)
        cid = self._writer.register_channel(topic=topic, message_encoding=encoding,
                                            schema_id=sid, metadata=metadata or {})
        self._channels[topic] = cid
        if self.live is not None:
            self.live.add_channel(cid, topic, encoding, schema, schema_encoding, schema_data)
        return cid

    def _json_channel(self, topic: str, schema: dict[str, Any]) -> int:
        return self._channel(topic, JSON_ENCODING, schema["title"], JSON_SCHEMA_ENCODING,
                             json.dumps(schema).encode())

    def _pb_channel(self, topic: str, schema: str) -> int:
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        return self._channel(topic, PROTOBUF_ENCODING, schema, PROTOBUF_ENCODING,
                             pb.schema_data(schema))

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

    def log_time(self, step: int | None = None) -> int:
        """``log_time`` of a message of ``step`` (None: now): simulated with
        :attr:`sim_time`, else the wall clock (ns)."""
        st = self.sim_time
        return (self._clock_ns or time.time_ns()) if st is None else st.at(step)

    def _add(self, channel_id: int, data: bytes, log_time_ns: int | None) -> None:
        wall = self._clock_ns or time.time_ns()
        t = (wall if self.sim_time is None else self.sim_time.at(None)) if log_time_ns is None \
            else log_time_ns
        self._writer.add_message(channel_id=channel_id, log_time=t, data=data, publish_time=wall)
        self.messages_written += 1
        if self.live is not None:
            self.live.offer(channel_id, data, t)
        now = time.monotonic_ns()
        if now - self._last_flush_ns >= self._flush_period_ns:
            self._writer.flush()
            self._last_flush_ns = now

    def write_wire(self, key: str, payload: bytes, log_time_ns: int | None = None) -> None:
        """Record a Zenoh payload on ``key`` as its protobuf message (see the module)."""
        if self._queue is None:
            self._write_wire(key, payload, log_time_ns)
            return
        if log_time_ns is None and self.sim_time is None:  # stamped on arrival, not on writing
            log_time_ns = time.time_ns()
        self._queue_call(self._write_wire, key, bytes(payload), log_time_ns)

    def _write_wire(self, key: str, payload: bytes, log_time_ns: int | None = None) -> None:
        payload = bytes(payload)
        k = keys.parse_key(key)
        kind = "" if k is None else k.kind
        limit = MAX_BRAIN_PAYLOAD_BYTES if kind == keys.BRAIN else MAX_PAYLOAD_BYTES
        if len(payload) > limit:
            self._refuse(key, len(payload), limit)
            return
        if kind == keys.POSES and k is not None and self._expand_poses(k.swarm, payload,
                                                                       log_time_ns):
            return
        if self._wire_layout:
            with self._lock:
                if not self._closed:
                    self._add(self._wire_channel(key), payload, log_time_ns)
            return
        try:
            data, step = self._to_pb(kind, payload)
        except MessageError as e:
            with self._lock:
                self.malformed += 1
                if not self._closed:
                    self._add(self._pb_channel(OTHER_TOPIC, pb.RAW_SAMPLE), pb.raw_sample_pb(
                        key, len(payload), str(e)[:200], payload[:MALFORMED_BYTES_KEPT]),
                        log_time_ns)
            return
        with self._lock:
            if self._closed:
                return
            t = self.log_time(step) if log_time_ns is None else log_time_ns
            if data is None:  # not one of the project's messages: kept whole
                self._add(self._pb_channel(OTHER_TOPIC, pb.RAW_SAMPLE),
                          pb.raw_sample_pb(key, len(payload), "", payload), t)
                return
            self._add(self._pb_channel(key, PB_SCHEMAS[kind]), data, t)
            if kind == keys.POSE and k is not None and k.robot_id is not None:
                self._pose_views(k.robot_id, payload, step, t)

    def _expand_poses(self, swarm: str, payload: bytes, log_time_ns: int | None) -> bool:
        """A :class:`~runtime.wire.messages.PoseBatch` is logged as the per-robot poses it holds
        (the channels every reader, replay and Foxglove panel knows); False if malformed."""
        try:
            b = decode_poses(payload)
        except MessageError:
            return False  # kept as a malformed raw sample by the caller
        n = len(b.robot_ids)
        for rid, (x, y), (vx, vy) in zip(b.robot_ids.tolist(), b.xy.tolist(), b.v.tolist(),
                                         strict=True):
            self._write_wire(keys.pose_key(swarm, rid),
                            encode_pose(Pose(rid, b.step, b.time_s, x, y, vx, vy, n)),
                            log_time_ns)
        return True

    @staticmethod
    def _to_pb(kind: str, payload: bytes) -> tuple[bytes | None, int | None]:
        """(the protobuf message of a payload on a key of ``kind``, its step); (None, None)
        for a key that has no message; :class:`MessageError` if it does not decode."""
        if kind == keys.POSE:
            p = decode_pose(payload)
            return pb.encode_pose_pb(p), p.step
        if kind == keys.CMD:
            c = decode_command(payload)
            return pb.encode_command_pb(c), c.step
        if kind == keys.STATUS:
            s = decode_status(payload)
            return pb.status_pb(s), s.step
        if kind in (keys.PATTERN, keys.OPERATOR_PATTERN):
            return pb.pattern_pb(decode_pattern(payload)), None
        if kind == keys.BRAIN:
            return pb.brain_pb(decode_brain(payload)), None
        if kind == keys.VIEW:
            v = decode_view(payload)
            return pb.view_pb(v), v.step
        if kind == keys.SLOTS:
            sl = decode_slots(payload)
            return pb.slots_pb(sl), sl.step
        if kind == keys.POSES:  # only a malformed one comes here (see _expand_poses)
            decode_poses(payload)
        return None, None

    def _pose_views(self, rid: int, payload: bytes, step: int | None, t: int) -> None:
        """The pose as Foxglove sees robots: a ``PoseInFrame`` now, a transform in the step's
        ``/tf`` message (written at :meth:`end_step`, the next step's first pose, or a flush)."""
        x, y = _xy(payload)
        self._add(self._pb_channel(robot_pose_topic(rid), pb.POSE_IN_FRAME),
                  pb.pose_in_frame_pb(t, SCENE_FRAME, x, y), t)
        s = -1 if step is None else step
        if s != self._tf_step:
            self._write_tf()
            self._tf_step, self._tf_time = s, t
        self._tf[rid] = (robot_frame(rid), x, y)

    def end_step(self) -> None:
        """The step is complete: write its ``/tf`` now rather than at the next step's first pose."""
        if self._queue is not None:
            self._queue_call(self._end_step)
        else:
            self._end_step()

    def _end_step(self) -> None:
        with self._lock:
            if not self._closed:
                self._write_tf()

    def _write_tf(self) -> None:
        """The pending step's ``/tf`` (caller holds the lock)."""
        if self._tf:
            children = [self._tf[r] for r in sorted(self._tf)]
            self._add(self._pb_channel(TF_TOPIC, pb.FRAME_TRANSFORMS),
                      pb.frame_transforms_pb(self._tf_time, SCENE_FRAME, children), self._tf_time)
            self._tf = {}

    def _refuse(self, key: str, size: int, limit: int) -> None:
        with self._lock:
            self.refused += 1
            n = self.refused
        if n <= REFUSED_EVENTS:
            st = self.sim_time
            step = 0 if st is None else st.current_step()
            self.event("payload_refused", step, 0.0 if st is None else step * st.dt_ns / 1e9,
                       key=key[:200], bytes=size, limit_bytes=limit, refused=n)

    def write_json(self, topic: str, obj: dict[str, Any], log_time_ns: int | None = None) -> None:
        """Record one JSON object on one of the ``/world/*`` topics."""
        if self._queue is None:
            self._write_json(topic, obj, log_time_ns)
        else:
            self._queue_call(self._write_json, topic, obj,
                             self.log_time() if log_time_ns is None else log_time_ns)

    def _write_json(self, topic: str, obj: dict[str, Any], log_time_ns: int | None) -> None:
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

    def scene(self, update: dict[str, Any] | bytes, log_time_ns: int | None = None) -> None:
        """Record one ``foxglove.SceneUpdate`` on ``/world/scene``: the object, or its JSON
        already encoded (:func:`sim_bridge.live.scene.scene_json`)."""
        if isinstance(update, dict):
            self.write_json(SCENE_TOPIC, update, log_time_ns)
        elif self._queue is not None:
            self._queue_call(self._scene, update,
                             self.log_time() if log_time_ns is None else log_time_ns)
        else:
            self._scene(update, log_time_ns)

    def _scene(self, update: bytes, log_time_ns: int | None) -> None:
        with self._lock:
            if not self._closed:
                self._add(self._channels[SCENE_TOPIC], update, log_time_ns)

    def flush(self) -> None:
        """Finish the chunk in progress and push everything to the file."""
        if self._queue is not None and self._thread is not None and self._thread.is_alive():
            self._wait_writer()
        with self._lock:
            if not self._closed:
                self._write_tf()
                self._writer.flush()
                self._last_flush_ns = time.monotonic_ns()

    def close(self) -> None:
        """Write what is queued, the summary section, and close the file."""
        thread, self._thread = self._thread, None
        if thread is not None and self._queue is not None:
            self._queue.put(None)  # after everything queued before
            thread.join()
        self._queue = None
        if self.dropped or self.writer_errors:  # never silently short
            st = self.sim_time
            step = 0 if st is None else st.current_step()
            self.event("log_dropped", step, 0.0 if st is None else step * st.dt_ns / 1e9,
                       dropped=self.dropped, writer_errors=self.writer_errors)
        with self._lock:
            if self._closed:
                return
            self._write_tf()
            self._closed = True
            try:
                self._writer.finish()
            finally:
                if self._file is not None:
                    self._file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_POSE_XY: Final = struct.Struct("<dd")


def _xy(pose_payload: bytes) -> tuple[float, float]:
    """x, y of a wire pose payload (decoded already: offsets of :mod:`runtime.wire.messages`)."""
    return _POSE_XY.unpack_from(pose_payload, 22)
