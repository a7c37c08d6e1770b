"""A process's heap: settled before its loop (:func:`settle`), its collections timed
(:class:`Pauses`)."""

from __future__ import annotations

import gc
import time
from typing import Any

__all__ = ["Pauses", "settle"]


def settle() -> None:
    """Collect once, then freeze what is left: the objects of the imports and of the set-up
    are never scanned by the collector again, only what the loop makes. A full collection
    scanned them all: 6-9 ms in a robot process (numpy, onnxruntime, Zenoh loaded), 15-20 ms
    in the world's, each a pause of every thread (the world's stalled the whole swarm's
    commands at once) -- longer still with a hundred processes sharing two cores."""
    gc.collect()
    gc.freeze()


class Pauses:
    """The garbage collector's pauses while installed: how many, their total and the
    longest (seconds), per generation. A context manager; not reentrant."""

    def __init__(self) -> None:
        self.count = [0, 0, 0]
        self.total_s = [0.0, 0.0, 0.0]
        self.max_s = [0.0, 0.0, 0.0]
        self._t0 = 0.0

    def _callback(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        g = int(info.get("generation", 2))
        dt = time.perf_counter() - self._t0
        self.count[g] += 1
        self.total_s[g] += dt
        self.max_s[g] = max(self.max_s[g], dt)

    def __enter__(self) -> Pauses:
        gc.callbacks.append(self._callback)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._callback in gc.callbacks:
            gc.callbacks.remove(self._callback)

    def figures(self) -> dict[str, Any]:
        """``{"count": [g0, g1, g2], "total_ms": [...], "max_ms": [...]}``."""
        return {"count": list(self.count),
                "total_ms": [round(t * 1000.0, 2) for t in self.total_s],
                "max_ms": [round(t * 1000.0, 2) for t in self.max_s]}
