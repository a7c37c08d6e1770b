"""The conditions a swarm runs under: how robots sense each other and how their wheels obey.

The perfect world (every robot sees every other exactly, at once, and moves exactly at its
command) is one point of a space real fleets never sit at. :class:`Conditions` names that
space in one frozen record, read by every world: the training world (``BatchWorld``),
``patternrl eval --conditions``, the pymunk world and its robots (``sim``, ``launch``,
``robot``) and ``benchmarks/conditions.py``. A brain's manifest records the conditions it
was trained under.

======================= ======= ==============================================================
field                   unit    meaning
======================= ======= ==============================================================
noise_m                 m       sigma of the Gaussian error on each sensed peer position
range_m                 m       a peer farther than this is not seen (inf: no limit)
k_nearest               -       only the k nearest peers are seen (0: all)
latency_steps           steps   a peer's sensed position is this many steps old
own_latency_steps       steps   the robot's own pose age (odometry: 0, fresh)
loss                    -       chance that a peer's update of a step is lost
gain_noise              -       each robot's wheels run at a gain drawn in [1 - g, 1 + g]
act_noise_mps           m/s     sigma of the Gaussian error added to each executed velocity
kinematics              -       "holonomic", or "diff" (differential drive)
turn_rate_rps           rad/s   a differential-drive base's turn-rate limit
======================= ======= ==============================================================

A peer that is not seen, or whose update is lost, keeps its last sensed position (its age
grows); at the start every robot knows where the team stands (the start-up roll call).
Randomness is seeded by the caller (a world seed, the robot's id): the same seed gives the
same noise, losses and gains.

Presets (:data:`PRESETS`): ``perfect``; ``realistic`` (5 cm noise, peers 1 step late,
10 % of updates lost, 10 % wheel gain spread, 2 cm/s actuation noise); ``harsh`` (10 cm,
2 steps, 30 % lost, the same actuation noise, differential drive at 2 rad/s). A spec
string is a preset and overrides, ``"realistic,latency_steps=2,kinematics=diff"``
(:func:`parse_conditions`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from runtime.errors import InputError

__all__ = ["PERFECT", "PRESETS", "Conditions", "parse_conditions"]

KINEMATICS = ("holonomic", "diff")
MAX_LATENCY_STEPS = 20
"""A view older than this (2 s at 10 Hz) is refused: the robot would be driving blind."""


@dataclass(frozen=True)
class Conditions:
    """How robots sense each other and move (see the module docstring's table)."""

    noise_m: float = 0.0
    range_m: float = math.inf
    k_nearest: int = 0
    latency_steps: int = 0
    own_latency_steps: int = 0
    loss: float = 0.0
    gain_noise: float = 0.0
    act_noise_mps: float = 0.0
    kinematics: str = "holonomic"
    turn_rate_rps: float = 2.0

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> InputError:
            return InputError(f"conditions: {name} {why}, got {getattr(self, name)!r}")

        for name in ("noise_m", "gain_noise", "act_noise_mps"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise bad(name, "must be a finite number >= 0")
        if not (isinstance(self.range_m, int | float) and self.range_m > 0
                and not math.isnan(self.range_m)):
            raise bad("range_m", "must be > 0 (inf: no limit)")
        for name, hi in (("k_nearest", 10_000), ("latency_steps", MAX_LATENCY_STEPS),
                         ("own_latency_steps", MAX_LATENCY_STEPS)):
            v = getattr(self, name)
            if not (isinstance(v, int) and 0 <= v <= hi):
                raise bad(name, f"must be an integer in 0..{hi}")
        if not (isinstance(self.loss, int | float) and 0.0 <= self.loss < 1.0):
            raise bad("loss", "must be in [0, 1)")
        if self.gain_noise >= 1.0:
            raise bad("gain_noise", "must be < 1")
        if self.kinematics not in KINEMATICS:
            raise bad("kinematics", f"must be one of {', '.join(KINEMATICS)}")
        if not (math.isfinite(self.turn_rate_rps) and self.turn_rate_rps > 0):
            raise bad("turn_rate_rps", "must be > 0")

    # ---------------------------------------------------------------- views

    @property
    def diff_turn_rps(self) -> float | None:
        """The base's turn-rate limit (rad/s) when it is a differential drive, else None."""
        return self.turn_rate_rps if self.kinematics == "diff" else None

    @property
    def sensing_perfect(self) -> bool:
        """Every robot sees every other exactly and at once."""
        return (self.noise_m == 0 and self.range_m == math.inf and self.k_nearest == 0
                and self.latency_steps == 0 and self.own_latency_steps == 0 and self.loss == 0)

    @property
    def acting_perfect(self) -> bool:
        """Every robot moves exactly at its command."""
        return (self.gain_noise == 0 and self.act_noise_mps == 0
                and self.kinematics == "holonomic")

    @property
    def perfect(self) -> bool:
        return self.sensing_perfect and self.acting_perfect

    @property
    def history_steps(self) -> int:
        """How many past steps of the truth a sensor keeps."""
        return max(self.latency_steps, self.own_latency_steps)

    def name(self) -> str:
        """The preset's name when these are a preset, else the spec string that makes them."""
        for key, preset in PRESETS.items():
            if preset == self:
                return key
        base = PERFECT
        changes = [f"{f.name}={_fmt(getattr(self, f.name))}" for f in fields(self)
                   if getattr(self, f.name) != getattr(base, f.name)]
        return "perfect," + ",".join(changes)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (inf as the string "inf")."""
        return {k: ("inf" if isinstance(v, float) and math.isinf(v) else v)
                for k, v in asdict(self).items()}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> Conditions:
        """The inverse of :meth:`to_dict`; unknown or mistyped keys are an :class:`InputError`."""
        known = {f.name: f for f in fields(Conditions)}
        kw: dict[str, Any] = {}
        for k, v in d.items():
            if k not in known:
                raise InputError(f"conditions: unknown field '{k}' (known: {', '.join(known)})")
            kw[k] = _coerce(k, v)
        return Conditions(**kw)


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return "inf" if math.isinf(v) else f"{v:g}"
    return str(v)


def _coerce(name: str, value: object) -> Any:
    """A field's value from JSON or a spec string, as the field's type."""
    default = getattr(PERFECT, name)
    try:
        if isinstance(default, str):
            return str(value)
        if isinstance(default, int) and not isinstance(default, bool):
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(str(value)) if isinstance(value, str) else int(value)  # type: ignore[call-overload]
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"conditions: {name} must be a {type(default).__name__}, "
                         f"got {value!r}") from None


PERFECT = Conditions()

PRESETS: dict[str, Conditions] = {
    "perfect": PERFECT,
    "realistic": Conditions(noise_m=0.05, latency_steps=1, loss=0.1, gain_noise=0.1,
                            act_noise_mps=0.02),
    "harsh": Conditions(noise_m=0.1, latency_steps=2, loss=0.3, gain_noise=0.1,
                        act_noise_mps=0.02, kinematics="diff", turn_rate_rps=2.0),
}


def parse_conditions(spec: str | None) -> Conditions:
    """A preset with ``field=value`` overrides, comma-separated: ``"realistic,noise_m=0.1"``;
    a spec without a preset starts from ``perfect``. Raises :class:`InputError` (one line)."""
    if spec is None or not spec.strip():
        return PERFECT
    parts = [p.strip() for p in spec.split(",") if p.strip()]
    base = PERFECT
    if "=" not in parts[0]:
        name = parts.pop(0)
        if name not in PRESETS:
            raise InputError(f"conditions: unknown preset '{name}' "
                             f"(presets: {', '.join(PRESETS)})")
        base = PRESETS[name]
    changes: dict[str, Any] = {}
    known = {f.name for f in fields(Conditions)}
    for p in parts:
        key, sep, value = p.partition("=")
        key = key.strip()
        if not sep or key not in known:
            raise InputError(f"conditions: '{p}' is not field=value with a known field "
                             f"({', '.join(sorted(known))})")
        changes[key] = _coerce(key, value.strip())
    return replace(base, **changes)
