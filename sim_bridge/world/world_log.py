"""What the world tells: events, per-step metrics and scenes on the MCAP log; lines for the user.

Events carry the world's step and simulated time (step x dt). Each step writes one
``/world/metrics`` row and one Foxglove ``SceneUpdate`` (robots, the pattern's
targets placed on the team's centroid, robots removed since the last scene, and the
peers as each robot under imperfect sensing perceived them, when a new view of it came).
Without a recorder only the user's lines remain.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from runtime.decision.formation import centred
from runtime.types import Array
from runtime.wire.messages import View
from runtime.world_config import WorldConfig
from sim_bridge.live.scene import scene_json
from sim_bridge.log.recorder import Recorder
from sim_bridge.world.phase_tally import StepMeasures

Say = Callable[[str, bool], None]
"""say(message, detail): detail lines (joins at the start, swaps) matter less."""


class WorldLog:
    """The world's log and its lines to the user."""

    def __init__(self, recorder: Recorder | None, world: WorldConfig, arena_m: float, say: Say,
                 clock: Callable[[], int]) -> None:
        self.rec = recorder
        self.w = world
        self.arena_m = arena_m
        """Side of the square arena drawn in scenes (metres)."""
        self._say = say
        self._clock = clock
        """The world's current step."""
        self._removed_since_scene: list[int] = []
        self._drawn_view: dict[int, int] = {}  # robot -> step of its view in the scene
        self._perceived_removed: list[int] = []

    def say(self, msg: str, detail: bool = False) -> None:
        self._say(msg, detail)

    def event(self, kind: str, **fields: Any) -> None:
        if self.rec is not None:
            step = self._clock()
            self.rec.event(kind, step, step * self.w.dt_s, **fields)

    def robot_removed(self, rid: int) -> None:
        """The next scene deletes this robot's entity."""
        self._removed_since_scene.append(rid)
        if self._drawn_view.pop(rid, None) is not None:
            self._perceived_removed.append(rid)

    def step_measures(self, m: StepMeasures) -> None:
        """The step's events: new collisions, new contacts, robots that missed it."""
        if m.new_collisions:
            self.event("collision", pairs=[list(p) for p in m.new_collisions])
        if m.new_contacts:
            self.event("contact", pairs=[list(p) for p in m.new_contacts])
        if m.missed:  # the step those robots did not answer in time
            self.event("deadline_miss", robots=m.missed, for_step=self._clock() - 1)
        if m.stale:  # of those, the ones that moved on an older command, and its age
            self.event("stale_command", robots=[r for r, _ in m.stale],
                       ages=[k for _, k in m.stale], for_step=self._clock() - 1)
        if m.scaled:
            self.event("stale_guard", robots=m.scaled, for_step=self._clock() - 1)

    def record_step(self, phase: int, pattern: str, version: int, phase_step: int,
                    ids: list[int], pos: Array, C: Array, m: StepMeasures,
                    t_step: float, rate_hz: float | None = None,
                    views: Mapping[int, View] | None = None) -> None:
        """The step's metrics row and scene; ``pos`` (n, 2) in ``ids`` order, ``C`` (n, 2);
        ``rate_hz`` the realtime world's rate at the step; ``views`` each robot's latest view
        (drawn in the scene when new)."""
        if self.rec is None:
            return
        step = self._clock()
        now_ns = self.rec.log_time(step)
        self.rec.metrics({
            "step": step, "time_s": round(step * self.w.dt_s, 6), "phase": phase,
            "pattern": pattern, "pattern_version": version,
            "phase_step": phase_step, "n_live": len(ids),
            "formation_error_m": round(m.error_m, 6), "max_slot_distance_m": round(m.far_m, 6),
            "min_separation_m": round(m.separation_m, 6) if math.isfinite(m.separation_m)
            else -1.0,
            "collisions": m.colliding, "contacts": len(m.new_contacts),
            "deadline_misses": len(m.missed),
            "stale_commands": len(m.stale),
            "command_age_max": max((k for _, k in m.stale), default=0),
            "held_still": len(m.held),
            "guard_scaled": len(m.scaled),
            "wall_ms": round((time.monotonic() - t_step) * 1000.0, 3),
            **({} if rate_hz is None else {"rate_hz": round(rate_hz, 3)}),
        }, now_ns)
        targets = centred(C) + pos.mean(axis=0)
        robots = [(rid, float(x), float(y)) for rid, (x, y) in zip(ids, pos, strict=True)]
        perceived = []
        for rid, v in sorted((views or {}).items()):
            if self._drawn_view.get(rid) != v.step:
                self._drawn_view[rid] = v.step
                perceived.append((rid, v.xy[v.ids != rid]))
        self.rec.scene(scene_json(now_ns, robots, targets, self._removed_since_scene,
                                  self.arena_m, self.w, perceived=perceived,
                                  perceived_removed=self._perceived_removed), now_ns)
        self.rec.end_step()
        self._removed_since_scene = []
        self._perceived_removed = []
