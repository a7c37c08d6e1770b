"""The world's constants, in one place.

Every figure here is a default that callers may override by building their own
:class:`WorldConfig`. Units: metres, seconds, metres per second.

| constant          | default | why                                                       |
|-------------------|---------|-----------------------------------------------------------|
| radius_m (R)      | 0.1     | robot radius                                              |
| v_max_mps, dt_s   | 1.0, 0.1| one step moves at most one radius: nothing jumps a robot  |
| arena_m           | 10      | starts are drawn uniformly in a square of this side       |
| start_separation  | 2.5 R   | robots never start in contact                             |
| pattern_spacing   | 4 R     | parked robots keep a diameter of gap                      |
| formed_tol        | 0.25 R  | every robot within a quarter step of its slot             |
| step_limit        | 400     | about 5x the slowest lower bound in this arena            |
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class WorldConfig:
    """Physical constants of the pattern-formation world."""

    radius_m: float = 0.1
    v_max_mps: float = 1.0
    dt_s: float = 0.1
    arena_m: float = 10.0
    start_separation_m: float = 0.25  # 2.5 R
    pattern_spacing_m: float = 0.4  # 4 R
    formed_tol_m: float = 0.025  # 0.25 R
    step_limit: int = 400

    @property
    def min_separation_m(self) -> float:
        """Closest two robot centres may come: 2R."""
        return 2.0 * self.radius_m

    @property
    def max_step_m(self) -> float:
        """Longest move in one step: v_max * dt."""
        return self.v_max_mps * self.dt_s

    def with_(self, **changes: float | int) -> WorldConfig:
        """A copy with some constants changed."""
        return replace(self, **changes)  # type: ignore[arg-type]


DEFAULT_WORLD = WorldConfig()

HOLD_SHARE = 0.9
"""A formation holds when it is formed on this share of the steps watched after it first
formed, or more: ``patternrl eval --hold-steps`` and the world's ``--hold-steps`` judge alike."""


def holds(formed: bool, held_steps: int, hold_steps: int) -> bool:
    """A formation holds when it formed and was still formed after at least
    :data:`HOLD_SHARE` of the ``hold_steps`` watched after its first passage (with none
    watched, when it formed)."""
    return formed and held_steps >= HOLD_SHARE * hold_steps

MAX_PATTERN_COORD_M = 1e4
"""A pattern point farther than this from the origin (metres, either axis) is refused:
the arena is tens of metres wide, and coordinates near the float range overflow
distances into inf and NaN."""
