"""A minimal client of Foxglove's WebSocket protocol (``foxglove.websocket.v1``), stdlib only.

Enough to check a live server from a script or a test without Foxglove or the
``websockets`` package: connect, read the advertised channels, subscribe, receive
messages. Server -> client frames are never masked; client -> server frames are.
Binary ``MessageData`` (opcode 1): uint32 subscription id, uint64 log time (ns),
then the message as its channel encodes it.

Example::

    with FoxgloveClient("127.0.0.1", 8765) as c:
        chans = c.wait_channels(["/world/scene"], timeout_s=10)
        c.subscribe([chans["/world/scene"]["id"]])
        topic, log_time_ns, data = c.next_message(timeout_s=10)
"""

from __future__ import annotations

import base64
import json
import os
import socket
import struct
import time
from typing import Any, Final

SUBPROTOCOLS: Final = ("foxglove.sdk.v1", "foxglove.websocket.v1")
"""Offered in this order: foxglove-sdk 0.30 answers only the first, the same
protocol under its new name; older servers (and Foxglove bridges) the second."""
_OP_TEXT, _OP_BINARY, _OP_CLOSE, _OP_PING, _OP_PONG = 1, 2, 8, 9, 10


class FoxgloveClient:
    """One connection to a Foxglove WebSocket server."""

    def __init__(self, host: str, port: int, timeout_s: float = 10.0) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout_s)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((
            f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            f"Sec-WebSocket-Version: 13\r\n"
            f"Sec-WebSocket-Protocol: {', '.join(SUBPROTOCOLS)}\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("the server closed during the handshake")
            head += chunk
        head, _, self._buf = head.partition(b"\r\n\r\n")
        status = head.split(b"\r\n", 1)[0]
        if b" 101 " not in status + b" ":
            raise ConnectionError(f"handshake refused: {status.decode(errors='replace')}")
        self.protocol = ""
        for line in head.split(b"\r\n")[1:]:
            name, _, value = line.decode(errors="replace").partition(":")
            if name.strip().lower() == "sec-websocket-protocol":
                self.protocol = value.strip()
        self.channels: dict[int, dict[str, Any]] = {}
        """channel id -> the server's advertisement (topic, encoding, schemaName, schema, ...)"""
        self.server_info: dict[str, Any] = {}
        self.statuses: list[str] = []
        """The server's status messages so far (a subscription it refused, ...)."""
        self._subs: dict[int, int] = {}  # subscription id -> channel id
        self._messages: list[tuple[str, int, bytes]] = []
        self._pos = 0
        self._complete = False

    # ------------------------------------------------------------------ frames

    def _read(self, n: int) -> bytes:
        """The next ``n`` bytes of the frame being read (kept until it is whole, so a
        timeout in the middle of a frame loses nothing)."""
        while len(self._buf) - self._pos < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("the server closed the connection")
            self._buf += chunk
        out = self._buf[self._pos : self._pos + n]
        self._pos += n
        return out

    def _frame(self) -> tuple[int, bytes]:
        """One whole message (continuation frames joined): (opcode, payload)."""
        self._pos = 0
        try:
            return self._frame_at()
        finally:
            if self._complete:
                self._buf = self._buf[self._pos :]
            self._complete = False

    def _frame_at(self) -> tuple[int, bytes]:
        opcode, parts = -1, []
        while True:
            b0, b1 = self._read(2)
            n = b1 & 0x7F
            if n == 126:
                (n,) = struct.unpack(">H", self._read(2))
            elif n == 127:
                (n,) = struct.unpack(">Q", self._read(8))
            mask = self._read(4) if b1 & 0x80 else b""
            data = self._read(n)
            if mask:
                data = bytes(c ^ mask[i % 4] for i, c in enumerate(data))
            op = b0 & 0x0F
            if op == _OP_PING:  # answered; the frame is consumed
                self._send(_OP_PONG, data)
                self._buf, self._pos = self._buf[self._pos :], 0
                continue
            if op != 0:
                opcode = op
            parts.append(data)
            if b0 & 0x80:
                self._complete = True
                return opcode, b"".join(parts)

    def _send(self, opcode: int, data: bytes) -> None:
        mask = os.urandom(4)
        n = len(data)
        head = bytes((0x80 | opcode,))
        if n < 126:
            head += bytes((0x80 | n,))
        elif n < 1 << 16:
            head += bytes((0x80 | 126,)) + struct.pack(">H", n)
        else:
            head += bytes((0x80 | 127,)) + struct.pack(">Q", n)
        self.sock.sendall(head + mask + bytes(c ^ mask[i % 4] for i, c in enumerate(data)))

    def send_json(self, obj: dict[str, Any]) -> None:
        self._send(_OP_TEXT, json.dumps(obj).encode())

    # ------------------------------------------------------------------ protocol

    def poll(self, timeout_s: float) -> bool:
        """Read one message from the server, if one comes within ``timeout_s``."""
        self.sock.settimeout(timeout_s)
        try:
            op, data = self._frame()
        except TimeoutError:
            return False
        if op == _OP_TEXT:
            msg = json.loads(data)
            if msg.get("op") == "advertise":
                for ch in msg.get("channels", []):
                    self.channels[int(ch["id"])] = ch
            elif msg.get("op") == "unadvertise":
                for cid in msg.get("channelIds", []):
                    self.channels.pop(int(cid), None)
            elif msg.get("op") == "serverInfo":
                self.server_info = msg
            elif msg.get("op") == "status":  # the server's warnings and errors, kept
                self.statuses.append(str(msg.get("message", "")))
        elif op == _OP_BINARY and data and data[0] == 1:
            sub, t = struct.unpack_from("<IQ", data, 1)
            cid = self._subs.get(sub)
            if cid is not None and cid in self.channels:
                self._messages.append((self.channels[cid]["topic"], t, data[13:]))
        elif op == _OP_CLOSE:  # status code, then the reason (RFC 6455 5.5.1)
            reason = data[2:].decode(errors="replace") if len(data) >= 2 else ""
            code = struct.unpack(">H", data[:2])[0] if len(data) >= 2 else None
            raise ConnectionError(f"the server closed the connection (code {code}"
                                  + (f": {reason})" if reason else ")"))
        return True

    def by_topic(self) -> dict[str, dict[str, Any]]:
        return {ch["topic"]: ch for ch in self.channels.values()}

    def wait_channels(self, topics: list[str], timeout_s: float) -> dict[str, dict[str, Any]]:
        """The advertisements of ``topics`` once all are advertised; TimeoutError otherwise."""
        deadline = time.monotonic() + timeout_s
        while not set(topics) <= self.by_topic().keys():
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"not advertised within {timeout_s} s: "
                                   f"{sorted(set(topics) - self.by_topic().keys())}")
            self.poll(min(left, 0.5))
        return self.by_topic()

    def subscribe(self, channel_ids: list[int]) -> None:
        subs = []
        for cid in channel_ids:
            sid = len(self._subs) + 1
            self._subs[sid] = cid
            subs.append({"id": sid, "channelId": cid})
        self.send_json({"op": "subscribe", "subscriptions": subs})

    def next_message(self, timeout_s: float) -> tuple[str, int, bytes]:
        """(topic, log time ns, data) of the next message of a subscribed channel."""
        deadline = time.monotonic() + timeout_s
        while not self._messages:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no message within {timeout_s} s")
            self.poll(min(left, 0.5))
        return self._messages.pop(0)

    def close(self) -> None:
        try:
            self._send(_OP_CLOSE, b"")
        except OSError:
            pass
        self.sock.close()

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
