"""A brain that wants collisions: each robot drives at full speed at its nearest peer.

The safety filter is the last word between any brain and the motors, so it must keep a
team apart whatever the brain asks; this brain asks for the worst. ``eval`` and
``benchmarks/conditions.py`` run it by the name :data:`ADVERSARY` (never a robot: it is
not one of the rules a robot loads).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.brain.manifest import BrainManifest
from runtime.decision.observation import ObservationSpec
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["ADVERSARY", "ChargeBrain"]

ADVERSARY = "adversary:charge"


class ChargeBrain:
    """Full speed at the nearest peer seen (the general observation's first neighbour);
    alone, full speed along +x."""

    def __init__(self, world: WorldConfig = DEFAULT_WORLD, k_neighbours: int = 6) -> None:
        self.brain_id = ADVERSARY
        self.spec = ObservationSpec("general", k_neighbours=k_neighbours)
        self.manifest: BrainManifest | None = None
        self._v_max = world.v_max_mps

    def act(self, obs: NDArray[Any]) -> Array:
        o = np.asarray(obs, dtype=np.float64)
        rel = o[:, 6:8]  # the nearest peer's relative position
        seen = o[:, 10] > 0.5
        d = np.hypot(rel[:, 0], rel[:, 1])
        out = np.zeros((o.shape[0], 2))
        out[:, 0] = self._v_max
        ok = seen & (d > 1e-12)
        out[ok] = rel[ok] / d[ok, None] * self._v_max
        return out
