"""The live view: the log's channels served to Foxglove over its WebSocket protocol.

``patternrl sim|launch --foxglove [HOST:PORT]`` starts a Foxglove WebSocket server
(``foxglove-sdk``, the optional ``foxglove`` extra, imported only then) in the
world's process, bound to 127.0.0.1:8765 by default (port 0: any free port). It
serves exactly the channels the log has (:mod:`sim_bridge.log.layout`: the scene,
metrics, events, every robot's pose and ``/tf``, commands, statuses, the pattern),
message for message, as the recorder writes them (:class:`FoxgloveLive` is the
recorder's live sink; brains, and anything over :data:`LIVE_MAX_BYTES`, stay off
the wire). Open Foxglove, "Open connection", ``ws://127.0.0.1:8765``.

Never slowing the world: the recorder only appends each message to a bounded
queue (:data:`QUEUE_MESSAGES`; should the server thread fall that far behind,
the oldest are dropped); a thread of its own hands them to the server, whose
per-client queues drop rather than block too. ``benchmarks/foxglove_cost.py``
measures the cost per step.
"""

from __future__ import annotations

import collections
import threading
from typing import Any, Final

from runtime.errors import InputError

DEFAULT_HOST: Final = "127.0.0.1"
DEFAULT_PORT: Final = 8765
DEFAULT_ADDRESS: Final = f"{DEFAULT_HOST}:{DEFAULT_PORT}"
LIVE_MAX_BYTES: Final = 1 << 20
"""Messages larger than this (a brain) are not served live."""
QUEUE_MESSAGES: Final = 50_000
"""Messages waiting for the server thread at most (about 100 steps of 100 robots)."""
DRAIN_PERIOD_S: Final = 0.01


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` -> (host, port); :class:`InputError` otherwise."""
    host, sep, port_s = str(text).rpartition(":")
    if not sep:
        host, port_s = "", text
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_s)
    except ValueError:
        raise InputError(f"--foxglove {text!r}: expected HOST:PORT, e.g. {DEFAULT_ADDRESS}"
                         ) from None
    if not 0 <= port <= 65535:
        raise InputError(f"--foxglove {text!r}: port must be 0..65535 (0: any free port)")
    return host, port


class FoxgloveLive:
    """A Foxglove WebSocket server fed from the recorder
    (:class:`sim_bridge.log.recorder.LiveSink`).

    Raises :class:`InputError` (one line) when ``foxglove-sdk`` is missing or the
    server cannot start (the port is taken). :meth:`close` stops it.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 name: str = "patternrl") -> None:
        try:
            import foxglove
        except ImportError:
            raise InputError("--foxglove needs foxglove-sdk: pip install 'patternrl[foxglove]'"
                             ) from None
        self._fg: Any = foxglove
        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port,
                                                 context=self._ctx)
        except Exception as e:  # the SDK's own error types (address in use, ...)
            raise InputError(f"--foxglove {host}:{port}: cannot start the server: {e}"
                             ) from None
        self.host = host
        self.port = int(self._server.port)
        self._new_channels: collections.deque[tuple[int, str, str, str, str, bytes]] = (
            collections.deque())
        self._queue: collections.deque[tuple[int, bytes, int]] = collections.deque(
            maxlen=QUEUE_MESSAGES)
        self._channels: dict[int, Any] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="foxglove-live", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    # ------------------------------------------------------------------ the sink (any thread)

    def add_channel(self, channel_id: int, topic: str, message_encoding: str,
                    schema_name: str, schema_encoding: str, schema_data: bytes) -> None:
        self._new_channels.append((channel_id, topic, message_encoding, schema_name,
                                   schema_encoding, schema_data))

    def offer(self, channel_id: int, data: bytes, log_time_ns: int) -> None:
        """Queue one message; never blocks (a full queue drops its oldest)."""
        if len(data) <= LIVE_MAX_BYTES:
            self._queue.append((channel_id, data, log_time_ns))

    # ------------------------------------------------------------------ the server's thread

    def _run(self) -> None:
        while not self._stop.wait(DRAIN_PERIOD_S):
            self._drain()
        self._drain()

    def _make_channels(self) -> None:
        fg = self._fg
        while self._new_channels:
            cid, topic, enc, sname, senc, sdata = self._new_channels.popleft()
            self._channels[cid] = fg.Channel(
                topic, message_encoding=enc, context=self._ctx,
                schema=fg.Schema(name=sname, encoding=senc, data=sdata))

    def _drain(self) -> None:
        self._make_channels()
        q = self._queue
        while q:
            cid, data, t = q.popleft()
            ch = self._channels.get(cid)
            if ch is None:  # its channel came in after this drain began
                self._make_channels()
                ch = self._channels.get(cid)
            if ch is not None:
                ch.log(data, log_time=t)

    def close(self) -> None:
        """Serve what is queued, then stop the server; a second call does nothing."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._server.stop()

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
