"""Helpers shared by the integration and end-to-end tests' conftest modules."""

from __future__ import annotations

import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
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


def assert_same_episodes(brain: Any, rule: Any, safety: Any) -> float:
    """``brain`` and ``rule`` on the same seeded circle episodes: the same steps, travel (to
    float32 rounding) and success. Returns the success rate."""
    import numpy as np

    from trainer.evaluate import evaluate_brain

    kw = {"seed": 77, "safety": safety, "progress": False}
    a = evaluate_brain(brain, "circle", 8, 4, **kw)
    b = evaluate_brain(rule, "circle", 8, 4, **kw)
    assert a.episode_stats["steps"] == b.episode_stats["steps"]
    np.testing.assert_allclose(a.episode_stats["travel_m"], b.episode_stats["travel_m"],
                               rtol=1e-5)
    assert a.success_rate == b.success_rate
    return float(a.success_rate)


def forged_command(robot_id: int, step: int, brain: str = "forged") -> bytes:
    """A well-formed command payload of robot ``robot_id`` (the attacks' forgeries and fences)."""
    from runtime.wire.messages import Command, encode_command

    return encode_command(Command(robot_id, step, 1.0, 0.0, brain, False, 0.0, 0.0))


def forged_keys(swarm: str) -> tuple[str, ...]:
    """What robot 1 has no right to publish: robot 2's keys, the brain and the pattern."""
    from runtime.wire import keys

    return (keys.cmd_key(swarm, 2), keys.status_key(swarm, 2), keys.pose_key(swarm, 2),
            keys.brain_key(swarm), keys.pattern_key(swarm))


def forge_and_fence(attacker: Any, seen: Seen, swarm: str, token_ids: tuple[int, ...]
                    ) -> list[object]:
    """Robot 1 forges everything it has no right to (:func:`forged_keys`, three steps each,
    liveliness tokens of ``token_ids``), then publishes its own command and token.

    Messages of one link arrive in order, so once ``seen`` has the fence it has had every
    forgery that was ever going to arrive. Returns the tokens (keep them alive).
    """
    from runtime.wire import keys

    for step in range(3):
        for key in forged_keys(swarm):
            attacker.put(key, forged_command(2, step))
    tokens = [attacker.liveliness().declare_token(keys.alive_key(swarm, i))
              for i in (*token_ids, 1)]
    fence = forged_command(1, 999, "fence")
    attacker.put(keys.cmd_key(swarm, 1), fence)
    wait_for(lambda: seen.has(keys.cmd_key(swarm, 1), fence), 20, "robot 1's own command")
    wait_for(lambda: "1" in seen.alive, 20, "robot 1's own liveliness token")
    return tokens
