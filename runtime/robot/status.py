"""A robot's health figures and the status message that carries them.

Counted from several threads (Zenoh callbacks drop messages, the swap worker
counts its errors, the loop its decisions) under one lock. Decision latencies
and decision times are kept for one status period: p50/p99 of the latency,
and loop jitter = p99 - p50 of the interval between consecutive decisions.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import threading
import time

from runtime.log import one_line
from runtime.robot.swap_worker import SwapReply
from runtime.wire.messages import Status

__all__ = ["RobotStats", "percentile"]


def percentile(sorted_vals: list[float], q: float) -> float:
    """The ``q`` quantile (0..1) of ascending values, nearest rank; 0.0 when empty."""
    if not sorted_vals:
        return 0.0
    idx = min(len(sorted_vals) - 1, max(0, math.ceil(q * len(sorted_vals)) - 1))
    return float(sorted_vals[idx])


class RobotStats:
    """Counters of one robot (since start) and its decision timings (this period)."""

    def __init__(self) -> None:
        self.t_start = time.monotonic()
        self._lock = threading.Lock()
        self.dropped = 0
        self.errors = 0
        self.interventions = 0
        self.steps = 0
        self.nonfinite_fallbacks = 0
        self.last_error = ""
        self.last_step = 0
        self._latency_us: list[float] = []
        self._decided_at: list[float] = []  # monotonic s

    def drop(self) -> None:
        """A malformed message was dropped."""
        with self._lock:
            self.dropped += 1

    def error(self, text: str, count: bool = True) -> None:
        """An error: ``text`` becomes the last error; ``count`` False only notes it."""
        with self._lock:
            if count:
                self.errors += 1
            self.last_error = text

    def nonfinite(self) -> None:
        """The brain's output was not finite; the fallback decided this step."""
        with self._lock:
            self.nonfinite_fallbacks += 1

    def decided(self, step: int, latency_us: float, safety_changed: bool) -> float:
        """One decision was sent; returns its time (monotonic s)."""
        t = time.monotonic()
        with self._lock:
            self.steps += 1
            self.last_step = step
            if safety_changed:
                self.interventions += 1
            self._latency_us.append(latency_us)
            self._decided_at.append(t)
        return t

    def new_period(self) -> None:
        """Start a status period: forget the timings (keep the last decision time)."""
        with self._lock:
            self._latency_us.clear()
            self._decided_at = self._decided_at[-1:]

    def status(self, robot_id: int, brain_id: str, reply: SwapReply | None = None) -> Status:
        """The status message now; with ``reply``, the answer to a swap request."""
        with self._lock:
            lat = sorted(self._latency_us)
            gaps = sorted(b - a for a, b in itertools.pairwise(self._decided_at))
            dropped, errors, interventions = self.dropped, self.errors, self.interventions
            last_error, step = self.last_error, self.last_step
            nonfinite = self.nonfinite_fallbacks
        jitter_ms = (percentile(gaps, 0.99) - percentile(gaps, 0.5)) * 1000.0 if gaps else 0.0
        st = Status(
            robot_id=robot_id,
            step=max(step, 0),
            brain_id=brain_id[:64],
            decision_latency_us_p50=percentile(lat, 0.5),
            decision_latency_us_p99=percentile(lat, 0.99),
            loop_jitter_ms=max(jitter_ms, 0.0),
            messages_dropped=dropped,
            errors=errors,
            safety_interventions=interventions,
            last_error=one_line(last_error),
            uptime_s=time.monotonic() - self.t_start,
            nonfinite_fallbacks=nonfinite,
        )
        if reply is None:
            return st
        return dataclasses.replace(
            st,
            brain_id=reply.new_brain[:64],
            swap_request_id=one_line(reply.request, 256),
            swap_accepted=reply.accepted,
            swap_reason=reply.reason,
            old_brain_id=reply.old_brain[:64],
        )
