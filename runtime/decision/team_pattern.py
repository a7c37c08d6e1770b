"""Which target a team of n robots forms: the one policy every robot (and replay) follows.

A pattern message carries a name and points for the team size the operator had
in mind; robots join and leave, so each robot fits it to the team it sees now:

- as many points as robots: the points themselves;
- a built-in name (circle, cross, line, heart, triangle): rebuilt for n robots;
- any other polyline: resampled by arc length to n points (open curve);
- anything else: refused (:class:`~runtime.decision.patterns.PatternError`).

A fitted pattern whose points come closer than 2R is refused: robots would
have to touch to form it.

Which pattern a robot fits (:class:`TeamPattern`): a paper brain trained for
one pattern forms that pattern whatever the swarm's key says (it knows no
other); any other brain forms the newest pattern message of the swarm, else
the robot's ``--pattern`` default.

Which pattern message is the newest (the version rule): the world numbers its
patterns 1, 2, 3, ... (one per phase and per resize). A robot takes

- its first message if its version is at most :data:`MAX_PATTERN_VERSION` (2^32 - 1);
- later, only a version greater than the one it holds by at most
  :data:`MAX_VERSION_STEP`; the same version again is the world's republish and
  changes nothing; an older one is refused;
- after the world restarted (its own pose's step went back), any version up to
  :data:`MAX_PATTERN_VERSION` again.

So a message cannot jump to the end of the version range and lock the target
for the rest of a run (the robots would ignore every later pattern of the
world). A message is also refused when no team could form it: fewer than 2
points, two points closer than 2R, or points that cannot be fitted to the team
the robot sees now. Every refusal is a :class:`PatternError` the robot counts
as a dropped message. What the version rule cannot stop is a peer that sends
the next version first: only authenticated transport (who may publish on the
pattern key) stops that.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Final

import numpy as np

from runtime.decision.patterns import (
    BUILTIN_PATTERNS,
    PatternError,
    make_pattern,
    min_spacing,
    pattern_label,
    resample_polyline,
)
from runtime.log import Log, one_line
from runtime.types import Array
from runtime.wire.messages import PatternMsg
from runtime.world_config import DEFAULT_WORLD, WorldConfig

if TYPE_CHECKING:
    from runtime.brain.brain import Brain

__all__ = ["MAX_PATTERN_VERSION", "MAX_VERSION_STEP", "TeamPattern", "fit_pattern"]

MAX_PATTERN_VERSION: Final = (1 << 32) - 1
"""The highest pattern version a robot takes: 4 billion phases and resizes."""
MAX_VERSION_STEP: Final = 1000
"""How far a new pattern version may be ahead of the one a robot holds."""


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
    if n >= 2 and not min_spacing(out) >= world.min_separation_m:  # NaN too
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
        self._team_n = 0  # the team of the last for_team: a new message must fit it
        self._restarted = False

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
        """A pattern message from the swarm: taken by the version rule (module docstring).

        Raises :class:`PatternError` with the reason for a message refused: a
        version out of bounds, fewer than 2 points, points closer than 2R, or
        points that cannot be fitted to the team seen now.
        """
        with self._lock:
            held = self._msg
            fresh = held is None or self._restarted
        v = msg.version
        if v > MAX_PATTERN_VERSION:
            raise PatternError(f"pattern version {v} beyond {MAX_PATTERN_VERSION}")
        if not fresh and held is not None:
            if v == held.version:
                return  # the world's republish
            if v < held.version:
                raise PatternError(f"pattern version {v} is older than the held {held.version}")
            if v > held.version + MAX_VERSION_STEP:
                raise PatternError(
                    f"pattern version {v} jumps more than {MAX_VERSION_STEP} past {held.version}"
                )
        if len(msg.points) < 2 or not min_spacing(msg.points) >= self.world.min_separation_m:
            raise PatternError(f"'{msg.name}' has fewer than 2 points or points closer than 2R")
        n = self._team_n
        if n >= 2:  # a pattern the team cannot form would hold every robot still
            fit_pattern(msg.name, np.asarray(msg.points, np.float64), n, self.world)
        with self._lock:
            if self._msg is held:
                self._msg = msg
                self._restarted = False

    def world_restarted(self) -> None:
        """The world started again: its pattern versions count from 1 again."""
        with self._lock:
            self._restarted = True

    def for_team(self, n: int) -> tuple[Array | None, str]:
        """The (n, 2) target in metres for a team of ``n``, or (None, why there is none)."""
        self._team_n = n
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
