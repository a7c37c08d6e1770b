"""How the formation is measured in the world, step by step and over a phase.

Every measure comes from :mod:`runtime.decision.formation`, the one home of the geometry:
the formation error is the RMS slot distance under the centred optimal
assignment (:func:`~runtime.decision.formation.assign_slots`, no hysteresis), and a
pattern is *formed* when the farthest robot is within ``world.formed_tol_m`` of
its slot; collisions are robot pairs whose discs overlap at any time during the
step (swept, :func:`~runtime.decision.formation.collision_pairs`), counted once per
encounter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from runtime.decision.formation import (
    assign_slots,
    collision_pairs,
    min_separation,
    slot_distances,
)
from runtime.types import Array, IntArray
from runtime.world_config import WorldConfig

Pair = tuple[int, int]


def formation_measure(pos: Array, C: Array) -> tuple[float, float]:
    """(formation error, farthest robot from its slot) in metres; pos and C (n, 2).

    The error is the RMS of the slot distances, which is what
    :func:`~runtime.decision.formation.formation_error_batch` returns for the same slots;
    taken from the distances here so that a step solves and measures once.
    """
    d = slot_distances(pos, C, assign_slots(pos, C))
    return float(np.sqrt(np.mean(d * d))), float(d.max())


class StepMeasures(NamedTuple):
    """What one step measured (after it)."""

    error_m: float
    far_m: float
    """Distance of the farthest robot from its slot."""
    separation_m: float
    """Smallest centre-to-centre distance (inf with one robot)."""
    colliding: int
    """Pairs overlapping during the step."""
    new_collisions: list[Pair]
    """Of those, the pairs that did not overlap during the step before (robot ids)."""
    new_contacts: list[tuple[int | str, int | str]]
    """Physics contacts that started this step (robot ids or "wall")."""
    missed: list[int]
    """Robots that gave no command for the step before its deadline."""
    stale: list[tuple[int, int]]
    """Of those, (robot, age in steps) of the ones that moved on an older command."""
    held: list[int]
    """Of those, the robots that held still (no command within the age bound)."""
    scaled: list[int]
    """Robots whose command the world's guard slowed down or stopped."""


@dataclass
class PhaseTally:
    """What one phase measured so far."""

    travel_m: float = 0.0
    collisions: int = 0
    contacts: int = 0
    deadline_misses: int = 0
    stale_commands: int = 0
    held_still: int = 0
    command_age_max: int = 0
    guard_scaled: int = 0
    joins: int = 0
    leaves: int = 0
    min_separation_m: float = math.inf
    error_m: float = math.inf
    far_m: float = math.inf
    _colliding: set[Pair] = field(default_factory=set)

    def formed(self, world: WorldConfig) -> bool:
        return self.far_m <= world.formed_tol_m

    def start(self, pos: Array, C: Array) -> None:
        """The formation before the phase's first step."""
        self.error_m, self.far_m = formation_measure(pos, C)

    def step(self, ids: list[int], pos: Array, new_pos: Array, C: Array,
             new_contacts: list[tuple[int | str, int | str]], missed: list[int],
             world: WorldConfig, age: IntArray | None = None,
             scaled: list[int] | None = None) -> StepMeasures:
        """Fold in a step from ``pos`` to ``new_pos`` ((n, 2) metres in ``ids`` order);
        ``age`` (n,) of the commands applied (0 fresh, k stale, -1 none; None: all of the
        missed held still), ``scaled`` the robots the guard slowed."""
        self.travel_m += float(np.linalg.norm(new_pos - pos, axis=1).sum())
        pairs = {(ids[a], ids[b]) for a, b in collision_pairs(pos, new_pos, world)}
        new_pairs = sorted(pairs - self._colliding)
        self._colliding = pairs
        self.collisions += len(new_pairs)
        self.contacts += len(new_contacts)
        self.deadline_misses += len(missed)
        stale: list[tuple[int, int]] = []
        held = list(missed)
        if age is not None and missed:
            a = age.tolist()
            stale = [(r, k) for r, k in zip(ids, a, strict=True) if k > 0]
            held = [r for r, k in zip(ids, a, strict=True) if k < 0]
        self.stale_commands += len(stale)
        self.held_still += len(held)
        self.command_age_max = max([self.command_age_max, *(k for _, k in stale)])
        self.guard_scaled += len(scaled or [])
        sep = float(min_separation(new_pos)) if len(ids) > 1 else math.inf
        self.min_separation_m = min(self.min_separation_m, sep)
        self.error_m, self.far_m = formation_measure(new_pos, C)
        return StepMeasures(self.error_m, self.far_m, sep, len(pairs), new_pairs,
                            new_contacts, missed, stale, held, list(scaled or []))
