"""A log's pattern phases, sliced once: what its records say about each phase.

A phase starts at a ``pattern`` event with reason ``phase`` (logs without
pattern events fall back on the wire pattern messages: a new pattern name is a
new phase, a new size of the same pattern is a resize). A phase's patterns are
its first one and its resizes; at step ``s`` the pattern in force is the
phase's last one published at a step <= s.

From the events, each phase also gets the world's own ``phase_start`` and
``phase_end`` (kept to be compared with the recomputation), the robots that
joined and left, its brain swaps (a swap logged between two phases belongs to
the next one, as the world swaps before it publishes a pattern), its deadline
misses, the age of each stale command applied and the guard's interventions.
Nothing here is recomputed from the poses: that is :mod:`sim_bridge.log.report`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from runtime.types import Array, IntArray
from runtime.world_config import WorldConfig
from sim_bridge.log.reader import LogData, as_int


@dataclass
class PhasePattern:
    """A pattern in force from ``step`` on (the phase's first, or a resize)."""

    step: int
    points: Array
    """(n, 2) metres"""
    formed_tol_m: float
    version: int


@dataclass
class PhaseLog:
    """What the log's records say about one phase (before any recomputation)."""

    index: int
    name: str
    start_step: int
    patterns: list[PhasePattern]
    end_step: int | None = None
    """The world's ``phase_end`` step; None when the log has no ``phase_end`` for it."""
    world_start: dict[str, Any] | None = None
    world_end: dict[str, Any] | None = None
    joined: list[int] = field(default_factory=list)
    lost: list[int] = field(default_factory=list)
    swaps: list[dict[str, Any]] = field(default_factory=list)
    deadline_misses: int = 0
    stale_ages: list[int] = field(default_factory=list)
    """Age (steps) of every stale command applied (``stale_command`` events; none in logs
    written before the world applied them)."""
    guard_scaled: int = 0

    def pattern_rows(self, steps: IntArray) -> IntArray:
        """Index into :attr:`patterns` of the pattern in force at each of ``steps``."""
        starts = np.asarray([p.step for p in self.patterns], np.int64)
        out: IntArray = np.maximum(np.searchsorted(starts, steps, side="right") - 1, 0)
        return out


def _from_events(events: list[dict[str, Any]], world: WorldConfig) -> list[PhaseLog]:
    phases: list[PhaseLog] = []
    cur: PhaseLog | None = None
    pending_swaps: list[dict[str, Any]] = []
    for e in events:
        kind = e.get("kind")
        step = as_int(e.get("step"))
        if kind == "pattern":
            try:
                pts = np.asarray(e.get("points", []), dtype=np.float64).reshape(-1, 2)
                tol = float(e.get("formed_tol_m", world.formed_tol_m))
            except (TypeError, ValueError):  # another writer's event: not a pattern we can use
                continue
            pat = PhasePattern(step, pts, tol, as_int(e.get("version")))
            if e.get("reason", "phase") == "phase" or cur is None:
                cur = PhaseLog(len(phases), str(e.get("name", "?")), step, [pat])
                cur.swaps, pending_swaps = pending_swaps, []
                phases.append(cur)
            else:
                cur.patterns.append(pat)
        elif kind == "phase_start" and cur is not None:
            cur.world_start = e
        elif kind == "phase_end" and cur is not None:
            cur.world_end = e
            cur.end_step = as_int(e.get("end_step"), step)
            cur = None
        elif kind == "brain_swap":
            (cur.swaps if cur is not None else pending_swaps).append(e)
        elif cur is not None and kind in ("join", "leave"):
            (cur.joined if kind == "join" else cur.lost).append(as_int(e.get("robot"), -1))
        elif cur is not None and kind == "deadline_miss":
            robots = e.get("robots", [])
            cur.deadline_misses += len(robots) if isinstance(robots, list) else 0
        elif cur is not None and kind == "stale_command":
            ages = e.get("ages", [])
            cur.stale_ages += [as_int(a) for a in ages] if isinstance(ages, list) else []
        elif cur is not None and kind == "stale_guard":
            robots = e.get("robots", [])
            cur.guard_scaled += len(robots) if isinstance(robots, list) else 0
    return phases


def _from_wire(data: LogData) -> list[PhaseLog]:
    """Phases from the pattern messages alone (a log without pattern events)."""
    fr = data.frames
    phases: list[PhaseLog] = []
    for mark in data.patterns:
        k = int(np.searchsorted(fr.first_msg, mark.msg_index))  # the first step published after
        if k >= len(fr.steps):
            continue
        step = int(fr.steps[k])
        pat = PhasePattern(step, np.asarray(mark.msg.points), mark.msg.formed_tol_m,
                           mark.msg.version)
        if phases and phases[-1].name == mark.msg.name:
            phases[-1].patterns.append(pat)
        else:
            phases.append(PhaseLog(len(phases), mark.msg.name, step, [pat]))
    return phases


def phases_of(data: LogData) -> list[PhaseLog]:
    """The log's phases: from its ``pattern`` events, else from its wire pattern messages."""
    return _from_events(data.events, data.world) or _from_wire(data)
