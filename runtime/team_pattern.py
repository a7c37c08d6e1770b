"""Which target a team of n robots forms: the one policy every robot (and replay) follows.

A pattern message carries a name and points for the team size the operator had
in mind; robots join and leave, so each robot fits it to the team it sees now:

- as many points as robots: the points themselves;
- a built-in name (circle, cross, line, heart, triangle): rebuilt for n robots;
- any other polyline: resampled by arc length to n points (open curve);
- anything else: refused (:class:`~runtime.patterns.PatternError`).

A fitted pattern whose points come closer than 2R is refused: robots would
have to touch to form it.

Which pattern a robot fits (:class:`TeamPattern`): a paper brain trained for
one pattern forms that pattern whatever the swarm's key says (it knows no
other); any other brain forms the newest pattern message of the swarm, else
the robot's ``--pattern`` default.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np

from runtime.log import Log, one_line
from runtime.messages import PatternMsg
from runtime.patterns import (
    BUILTIN_PATTERNS,
    PatternError,
    make_pattern,
    min_spacing,
    pattern_label,
    resample_polyline,
)
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

if TYPE_CHECKING:
    from runtime.brain import Brain

__all__ = ["TeamPattern", "fit_pattern"]


def fit_pattern(name: str, points: Array, n: int, world: WorldConfig = DEFAULT_WORLD) -> Array:
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


class TeamPattern:
    """The target of one robot's team, by the policy above, cached per team size.

    :meth:`offer` may be called from any thread (Zenoh callbacks);
    :meth:`use_brain` and :meth:`for_team` from the robot's loop only.
    """

    def __init__(
        self, default: str | None, world: WorldConfig = DEFAULT_WORLD, log: Log | None = None
    ) -> None:
        """``default``: a built-in pattern name or file, used until a message arrives."""
        self.world = world
        self._log = log
        self._default = default
        self._fixed: Array | None = None
        self._msg: PatternMsg | None = None
        self._lock = threading.Lock()
        self._cache: tuple[object, int, Array | None, str] | None = None

    def _say(self, level: str, msg: str) -> None:
        if self._log is not None:
            self._log(level, "pattern", msg)

    def use_brain(self, brain: Brain) -> None:
        """Follow a new brain: a paper brain trained for one pattern fixes the target."""
        m = brain.manifest
        self._fixed = None
        if m is not None and brain.spec.name == "paper" and m.pattern:
            n = m.n_robots or brain.spec.n_robots
            try:
                self._fixed = make_pattern(m.pattern, n, self.world)
            except PatternError as e:
                self._say("warning", f"brain's own pattern unusable: {e}")

    def offer(self, msg: PatternMsg) -> None:
        """A pattern message from the swarm: kept unless a newer version is held.

        Raises :class:`PatternError` for a message no team could form (fewer
        than 2 points, or points closer than 2R).
        """
        if len(msg.points) < 2 or min_spacing(msg.points) < self.world.min_separation_m:
            raise PatternError(f"'{msg.name}' has fewer than 2 points or points closer than 2R")
        with self._lock:
            if self._msg is None or msg.version >= self._msg.version:
                self._msg = msg

    def for_team(self, n: int) -> tuple[Array | None, str]:
        """The (n, 2) target in metres for a team of ``n``, or (None, why there is none)."""
        if self._fixed is not None:
            src: object = self._fixed
        else:
            with self._lock:
                msg = self._msg
            src = msg if msg is not None else self._default
        cache = self._cache
        if cache is not None and cache[0] is src and cache[1] == n:
            return cache[2], cache[3]
        pts: Array | None = None
        why = ""
        try:
            if src is None:
                why = "no pattern yet"
            elif isinstance(src, np.ndarray):
                pts = src if len(src) == n else None
                why = "" if pts is not None else f"brain's pattern has {len(src)} points, team {n}"
            elif isinstance(src, PatternMsg):
                pts = fit_pattern(src.name, np.asarray(src.points, np.float64), n, self.world)
                self._say("info", f"{src.name} v{src.version} for {n} robots")
            else:
                pts = make_pattern(str(src), n, self.world)
                self._say("info", f"{pattern_label(str(src))} for {n} robots")
        except PatternError as e:
            why = one_line(str(e))
            self._say("warning", why)
        self._cache = (src, n, pts, why)
        return pts, why
