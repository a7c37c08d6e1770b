"""Which target a team of n robots forms: the one policy every robot (and replay) follows.

A pattern message carries a name and points for the team size the operator had
in mind; robots join and leave, so each robot fits it to the team it sees now:

- as many points as robots: the points themselves;
- a built-in name (circle, cross, line, heart, triangle): rebuilt for n robots;
- any other polyline: resampled by arc length to n points (open curve);
- anything else: refused (:class:`~runtime.patterns.PatternError`).

A fitted pattern whose points come closer than 2R is refused: robots would
have to touch to form it.
"""

from __future__ import annotations

import numpy as np

from runtime.patterns import (
    BUILTIN_PATTERNS,
    PatternError,
    make_pattern,
    min_spacing,
    resample_polyline,
)
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig


def fit_pattern(
    name: str, points: Array, n: int, world: WorldConfig = DEFAULT_WORLD
) -> Array:
    """The pattern a team of ``n`` forms for a message ``(name, points)``, (n, 2) metres.

    Raises :class:`PatternError` with a one-line reason when it cannot be fitted.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == n:
        out: Array = pts.copy()
    elif name in BUILTIN_PATTERNS:
        return make_pattern(name, n, world)
    elif len(pts) >= 2 and n >= 2:
        out = resample_polyline(pts, n, closed=False)
    else:
        raise PatternError(f"pattern '{name}' has {len(pts)} points, the team has {n}")
    if n >= 2 and min_spacing(out) < world.min_separation_m:
        raise PatternError(f"pattern '{name}' for {n} robots puts two points closer than 2R")
    return out
