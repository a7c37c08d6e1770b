"""What each key may cost the world and the log per second: :class:`KeyBudget`.

Whoever may publish on a key (the transport's access rules) can still publish
too much on it: a robot's own status key, with valid 64 KiB statuses, grew a log
by 18 MB a second. So every sample that arrives at the world
(:mod:`sim_bridge.world.world_link`) or at ``patternrl record``
(:mod:`sim_bridge.log.record`) first passes its key's budget: at most so many
messages and so many bytes per second, with a burst of one second's worth (a
token bucket per key). A sample over budget is dropped -- not handled, not
written -- and counted; the first drop on a key is said once (``on_first_drop``:
an ``over_budget`` event in the log); the total is in the world's ``run_end`` event
and in ``record``'s summary.

The defaults (:data:`BUDGETS`, per key of each kind, per second) are far above what a
normal swarm sends, so only a flood meets them:

==================  ========  =========  ==========================================
kind                messages  bytes      a normal swarm (measured or by design)
==================  ========  =========  ==========================================
``cmd``             1000      256 KiB    one a step: <= 213 steps/s in lockstep at
                                         10 robots, 10 in realtime; 66-130 bytes
``pose``            1000      256 KiB    the same rate, 54 bytes
``poses``           1000      8 MiB      one a step, 24 + 36 n bytes (100 robots at
                                         10 Hz: 36 KB/s; 10 at 213 steps/s: 82 KB/s)
``status``          20        256 KiB    about one a second (and one per swap
                                         answer), under 1 KB; four 64 KiB ones fit
``view``            50        512 KiB    one per ``--view-every`` steps (10: <= 22 a
                                         second at 213 steps/s), 18 + 24 n bytes
                                         (2.4 KB at 100 robots); one a step at 10 Hz
                                         fits, four of the largest (4096 robots) too
``slots``           1000      256 KiB    one a step (``--agree``), like ``cmd``; 30
                                         bytes, the leader's 30 + 6 n (630 at 100)
``pattern``,        50        4 MiB      about one a second and one per phase or
``operator_pattern``                     resize; <= 64 KiB (4096 points)
``brain``           10        130 MiB    one per swap; a largest brain (64 MiB
                                         ONNX) fits twice
anything else       100       64 KiB     (nothing of ours)
==================  ========  =========  ==========================================

So a robot that floods its cmd, status, view and slots keys costs the log at most 1.25 MiB
a second.
At most :data:`MAX_KEYS` keys have their own bucket; keys beyond share one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from runtime.wire import keys

__all__ = ["BUDGETS", "MAX_KEYS", "Budget", "KeyBudget"]


@dataclass(frozen=True)
class Budget:
    """At most ``messages`` and ``bytes`` per second on one key (burst: one second's)."""

    messages: float
    bytes: float


_KIB: Final = 1 << 10
_MIB: Final = 1 << 20
BUDGETS: Final[dict[str, Budget]] = {
    keys.CMD: Budget(1000, 256 * _KIB),
    keys.POSE: Budget(1000, 256 * _KIB),
    keys.POSES: Budget(1000, 8 * _MIB),
    keys.STATUS: Budget(20, 256 * _KIB),
    keys.VIEW: Budget(50, 512 * _KIB),
    keys.SLOTS: Budget(1000, 256 * _KIB),
    keys.PATTERN: Budget(50, 4 * _MIB),
    keys.OPERATOR_PATTERN: Budget(50, 4 * _MIB),
    keys.BRAIN: Budget(10, 130 * _MIB),
    "": Budget(100, 64 * _KIB),
}
"""Per key of each kind ("" any other key), per second: see the module docstring."""
MAX_KEYS: Final = 1 << 16
"""Keys with a bucket of their own; beyond, one bucket for the rest (an attacker making up
keys cannot grow the table)."""
_SHARED: Final = "<more keys>"


class _Bucket:
    __slots__ = ("budget", "bytes", "messages", "t")

    def __init__(self, budget: Budget, now: float) -> None:
        self.budget = budget
        self.messages, self.bytes, self.t = budget.messages, budget.bytes, now


class KeyBudget:
    """Per-key budgets of the samples one process takes in; safe from any thread."""

    def __init__(self, on_first_drop: Callable[[str, Budget], None] | None = None,
                 budgets: dict[str, Budget] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._budgets = dict(BUDGETS if budgets is None else budgets)
        self._on_first_drop = on_first_drop
        self._clock = clock
        self._lock = threading.Lock()
        self._buckets: dict[str, _Bucket] = {}
        self.allowed = 0
        """Samples within budget, every key."""
        self.dropped = 0
        """Samples dropped over budget, every key."""
        self.dropped_bytes = 0
        self.dropped_by_key: dict[str, int] = {}

    def _budget(self, key: str) -> Budget:
        k = keys.parse_key(key)
        return self._budgets.get("" if k is None else k.kind, self._budgets[""])

    def allow(self, key: str, nbytes: int) -> bool:
        """Whether a sample of ``nbytes`` on ``key`` fits its budget now (it is spent if so)."""
        now = self._clock()
        first = False
        with self._lock:
            b = self._buckets.get(key)
            if b is None:
                name = key if len(self._buckets) < MAX_KEYS else _SHARED
                b = self._buckets.get(name)
                if b is None:
                    b = self._buckets[name] = _Bucket(self._budget(key), now)
            cap = b.budget
            dt = max(now - b.t, 0.0)
            b.t = now
            b.messages = min(cap.messages, b.messages + dt * cap.messages)
            b.bytes = min(cap.bytes, b.bytes + dt * cap.bytes)
            if b.messages >= 1.0 and b.bytes >= nbytes:
                b.messages -= 1.0
                b.bytes -= nbytes
                self.allowed += 1
                return True
            self.dropped += 1
            self.dropped_bytes += nbytes
            n = self.dropped_by_key.get(key, 0) if len(self.dropped_by_key) < MAX_KEYS else 1
            if n == 0:
                first = True
            if key in self.dropped_by_key or len(self.dropped_by_key) < MAX_KEYS:
                self.dropped_by_key[key] = n + 1
        if first and self._on_first_drop is not None:
            self._on_first_drop(key, cap)
        return False
