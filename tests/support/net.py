"""Ports, waiting, child processes, and a Zenoh observer of a swarm's keys."""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any


def _ephemeral_low() -> int:
    """The lowest port the kernel hands out to outgoing connections (32768 where unknown)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


_PORTS = random.Random(os.getpid() ^ time.monotonic_ns())


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now, below the kernel's ephemeral range: a port the
    kernel gives out itself (port 0) can be taken by any outgoing connection (a Zenoh session
    dialling a peer) before the test's process binds it ("Address already in use")."""
    hi = _ephemeral_low()
    for _ in range(200):
        port = _PORTS.randrange(max(1024, hi - 12000), hi)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:  # all taken: any free one
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(cond: Callable[[], Any], timeout: float, what: str, poll: float = 0.01) -> Any:
    """Poll ``cond`` until truthy (returned) or fail the test after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)


def wait_notified(cond: threading.Condition, pred: Callable[[], Any], timeout: float,
                  what: str) -> Any:
    """Wait on ``cond`` (notified when something arrives) until ``pred`` is truthy (returned),
    or fail the test after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    with cond:
        while True:
            v = pred()
            if v:
                return v
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            cond.wait(left)


def stop_processes(procs: list[subprocess.Popen[Any]], timeout: float = 5.0) -> None:
    """SIGTERM every process still running, then wait for each (SIGKILL after ``timeout`` s)."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=timeout)


class Seen:
    """Everything a Zenoh session receives on a swarm's keys, and the liveliness tokens it sees."""

    def __init__(self, s: Any, swarm: str) -> None:
        from runtime.wire import keys

        self.lock = threading.Lock()
        self.samples: list[tuple[str, bytes]] = []
        self.alive: set[str] = set()
        self._decls = [
            s.declare_subscriber(keys.swarm_root(swarm), self._on),
            s.liveliness().declare_subscriber(keys.all_alive(swarm), self._on_alive,
                                              history=True),
        ]

    def _on(self, s: Any) -> None:
        with self.lock:
            self.samples.append((str(s.key_expr), s.payload.to_bytes()))

    def _on_alive(self, s: Any) -> None:
        import zenoh

        with self.lock:
            if s.kind == zenoh.SampleKind.PUT:
                self.alive.add(str(s.key_expr).rsplit("/", 1)[1])

    def keys(self) -> set[str]:
        with self.lock:
            return {k for k, _ in self.samples}

    def has(self, key: str, payload: bytes) -> bool:
        with self.lock:
            return (key, payload) in self.samples

    def close(self) -> None:
        for d in self._decls:
            d.undeclare()
