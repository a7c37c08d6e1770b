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

Which pattern message is the newest (the version rule). Two sources send patterns,
on two keys: the world on ``pattern`` (its phases, 1, 2, 3, ...: one per phase and
per resize) and an operator on ``operator/pattern`` (a pattern of its own choice,
between the world's). A robot keeps ``W``, the version of the last *world* pattern it
took, and ``H``, the version of the pattern it holds (the world's or an operator's):

- a world pattern ``v`` is taken when ``W < v <= W + S`` (the world's republish of
  ``W`` changes nothing; the first one, and the first after the world restarted --
  its own pose's step went back -- any ``v`` up to :data:`MAX_PATTERN_VERSION`);
- an operator pattern ``v`` is taken when ``H < v <= W + S``: newer than what the
  robot holds, and at most ``S`` past the world's last;

with ``S`` = :data:`MAX_VERSION_STEP`. The world numbers its next pattern
``max(own, O) + 1``, ``O`` the highest operator version it has seen below
``own + S`` (none: ``own``), so its next is at most ``own + S``, and an operator
pattern sent before the world's next phase is older than it when it arrives late.

**No pattern locks out the world's next phase.** Whether a robot takes the world's
next pattern depends on ``W`` only, and only a world pattern moves ``W`` (operator
patterns move ``H``, never ``W``). The world's versions are ``w_1 < w_2 < ...``
with ``w_{k+1} - w_k <= S``, so a robot holding ``W = w_k`` takes ``w_{k+1}``
whatever operator patterns it took or refused, in whatever order they came. Nor
can the world reach the end of the range: ``w_k <= k S``, and
:data:`MAX_PATTERN_VERSION` is ``2^53 - 1``, 9 x 10^12 phases at ``S`` = 1000. This
rests on who may publish on which key: with the swarm's identities, only the world
may put on ``pattern`` and the operator on ``operator/pattern``
(:mod:`runtime.net.identity`); without them, anyone who speaks on the world's key
speaks as the world.

A message is also refused when no team could form it: fewer than 2 points, two
points closer than 2R, or points that cannot be fitted to the team the robot sees
now. Every refusal is a :class:`PatternError` the robot counts as a dropped message.
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
from runtime.decision.safety import guard_note
from runtime.log import Log, one_line
from runtime.types import Array
from runtime.wire.messages import PatternMsg
from runtime.world_config import DEFAULT_WORLD, WorldConfig

if TYPE_CHECKING:
    from runtime.brain.brain import Brain

__all__ = ["MAX_PATTERN_VERSION", "MAX_VERSION_STEP", "TeamPattern", "fit_pattern"]

MAX_PATTERN_VERSION: Final = (1 << 53) - 1
"""The highest pattern version a robot takes (exact as a JSON number in the log)."""
MAX_VERSION_STEP: Final = 1000
"""How far a pattern version may be ahead of the world's last one a robot took."""


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
        self._world_v: int | None = None  # the version of the world's last pattern taken
        self.guard_m = 0.0
        """The safety guard's distance (:func:`runtime.decision.safety.guard_distance`): a
        pattern whose closest pair lies inside it is taken with a warning."""

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

    def offer(self, msg: PatternMsg, operator: bool = False) -> None:
        """A pattern message of the world (or, ``operator``, of an operator): taken by
        the version rule (module docstring).

        Raises :class:`PatternError` with the reason for a message refused: a
        version out of bounds, fewer than 2 points, points closer than 2R, or
        points that cannot be fitted to the team seen now.
        """
        with self._lock:
            held, world_v, fresh = self._msg, self._world_v, self._restarted
        v = msg.version
        if v > MAX_PATTERN_VERSION:
            raise PatternError(f"pattern version {v} beyond {MAX_PATTERN_VERSION}")
        base = 0 if fresh or world_v is None else world_v  # the world's last taken
        if operator:
            h = 0 if fresh or held is None else held.version
            if v <= h:
                raise PatternError(f"operator pattern version {v} is not newer than the "
                                   f"held {h}")
            if v > base + MAX_VERSION_STEP:
                raise PatternError(f"operator pattern version {v} is more than "
                                   f"{MAX_VERSION_STEP} past the world's {base}")
        elif not fresh and world_v is not None:
            if v == world_v:
                return  # the world's republish
            if v < world_v:
                raise PatternError(f"pattern version {v} is older than the world's {world_v}")
            if v > world_v + MAX_VERSION_STEP:
                raise PatternError(
                    f"pattern version {v} jumps more than {MAX_VERSION_STEP} past {world_v}"
                )
        if len(msg.points) < 2 or not min_spacing(msg.points) >= self.world.min_separation_m:
            raise PatternError(f"'{msg.name}' has fewer than 2 points or points closer than 2R")
        n = self._team_n
        if n >= 2:  # a pattern the team cannot form would hold every robot still
            fit_pattern(msg.name, np.asarray(msg.points, np.float64), n, self.world)
        with self._lock:
            if self._msg is held and self._world_v == world_v:
                self._msg = msg
                if not operator:
                    self._world_v = v
                    self._restarted = False

    def world_restarted(self) -> None:
        """The world started again: its pattern versions count from 1 again."""
        with self._lock:
            self._restarted = True
            self._world_v = None

    @property
    def version(self) -> int:
        """The version of the pattern of the last :meth:`for_team` (0: not from a message:
        the brain's own pattern or ``--pattern``)."""
        c = self._cache
        return c[0].version if c is not None and isinstance(c[0], PatternMsg) else 0

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
        if pts is not None and n >= 2:
            note = guard_note(self.guard_m, min_spacing(pts))
            if note is not None:
                self._say("warning", note)
        self._cache = (src, n, pts, why)
        return pts, why
