"""Observation rows built the plain way, robot by robot: the reference the row builders are
checked against."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from runtime.world_config import DEFAULT_WORLD, WorldConfig

W = DEFAULT_WORLD


def reference_rows(pos: Any, prev: Any, slots: Any, k: int, world: WorldConfig = W,
                   steps_left: float | None = None) -> Any:
    """One team's general (``steps_left`` None) or plan rows, (n, 6 + 5k) float64, by the
    layout of runtime/core/general_row.py's docstring."""
    n = len(pos)
    vel = (pos - prev) / world.dt_s
    rows = np.zeros((n, 6 + 5 * k))
    for i in range(n):
        sv = slots[i] - pos[i]
        rows[i, 0:2] = sv
        if steps_left is None:  # the straight-line step, at most unit length
            rows[i, 2:4] = sv / max(math.hypot(*sv), world.v_max_mps * world.dt_s)
        else:  # the plan's step in units of v_max
            rows[i, 2:4] = sv / (steps_left * world.v_max_mps * world.dt_s)
        rows[i, 4:6] = vel[i]
        others = []
        for j in range(n):
            if j != i:
                dx, dy = (pos[j] - pos[i]).tolist()
                others.append((dx * dx + dy * dy, j))
        for c, (_, j) in enumerate(sorted(others)[:k]):
            rows[i, 6 + 5 * c : 11 + 5 * c] = [*(pos[j] - pos[i]), *(vel[j] - vel[i]), 1.0]
    return rows
