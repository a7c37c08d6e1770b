"""Landing on a slot the robot sees only through noise: damp the last steps, then stay.

A brain or rule moves its robot to where its view says the slot is. When the view is
noisy, that place jitters from step to step by the noise the estimator leaves, and a
robot that follows it exactly never stops: the team passes through the formation and
does not hold it (with 5 cm noise `rule:frame-balanced` + the tracker formed 100 % and
held 0 % of 8 episodes). :class:`Settle` is what a robot does about it, after the
brain and before the safety filter, a **damped landing**: a step shorter than
``radius_m`` is cut to ``gain`` of itself, so the robot averages the jittering target
over about ``(2 - gain) / gain`` steps instead of chasing each one. Measured on
``benchmarks/conditions.py``'s circle and heart (n = 10, 8 episodes, 5 cm noise,
`rule:frame-balanced` + the tracker): held 0 % -> 100 %, steps 1.12x -> 1.20x the lower
bound. Tried and left out: parking (a robot whose step is under 1 cm stays until asked
for more than 2.5 cm: steps 1.70x, no better hold) and a long average of peers that keep
still (the damped landing's short steps read as still, and the team's consensus lagged:
formed 75 %, held 0 %).

**Landing frame.** A synchronised plan (the frame rules, the plan brains) places the
pattern in a frame that blends the centre of the smallest circle enclosing the team's
displacements with their centroid. The enclosing circle rests on two or three robots, so
its centre carries their noise whole, where the centroid averages every robot's: a landed
team chasing it does not hold. With ``centroid_steps`` (2) steps or fewer left, a robot
under noise lands in the centroid frame (travel weight 1). Measured (n = 10, 4 episodes of
each of ``benchmarks/conditions.py``'s shapes, `rule:frame-balanced` + the tracker): the
realistic preset held 65 % -> 95 % of episodes, 10 cm noise 0 % -> 35 %, at the same steps
(1.50x -> 1.52x the lower bound); switching at 3 or 5 steps left did no better.
Without noise a plan lands as planned, to the last bit.

:func:`settle_for` sizes it from the noise the robot knows (none without noise: the
perfect world lands as before, to the last bit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from runtime.conditions import Conditions
from runtime.decision.estimator import steady_sigma
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["CENTROID_FRAME", "Lander", "Settle", "damp_landing", "landing_gain",
           "settle_for"]


@dataclass(frozen=True)
class Settle:
    """The landing's tuning (see the module docstring). Units in the names."""

    radius_m: float
    gain: float = 0.3
    centroid_steps: float = 2.0
    """A synchronised plan with this many steps left or fewer lands in the team's centroid
    frame (see the module docstring, "Landing frame")."""

    def lands_in_centroid(self, steps_left: Any) -> Any:
        """Whether a plan with ``steps_left`` (a number or an array) lands in the centroid
        frame (travel weight :data:`CENTROID_FRAME`) rather than its own."""
        return np.asarray(steps_left) <= self.centroid_steps


CENTROID_FRAME = 1.0
"""The travel weight of the team's centroid frame, where a plan lands under noise."""


def settle_for(conditions: Conditions, estimator: bool = False,
               world: WorldConfig = DEFAULT_WORLD) -> Settle | None:
    """The landing for a robot sensing under ``conditions`` (None: land as planned)."""
    if conditions.noise_m <= 0.0:
        return None
    sigma = steady_sigma(conditions.noise_m) if estimator else conditions.noise_m
    return Settle(radius_m=min(SETTLE_SIGMAS * sigma, 0.5 * world.max_step_m),
                  gain=SETTLE_GAIN)


SETTLE_SIGMAS = 2.5
"""Steps shorter than this many sigmas of the estimate's noise are damped."""
SETTLE_GAIN = 0.3


class Lander:
    """One robot's landing (stateless today; the controller resets it with its history)."""

    def __init__(self, settle: Settle, dt_s: float) -> None:
        self.settle = settle
        self.dt_s = dt_s

    def reset(self) -> None:
        """Nothing to forget yet."""

    def apply(self, vx: float, vy: float) -> tuple[float, float]:
        """The brain's velocity (m/s) as the landing lets it through."""
        g = float(landing_gain(math.hypot(vx, vy), self.settle, self.dt_s))
        return vx * g, vy * g


def landing_gain(speed_mps: Any, settle: Settle, dt_s: float) -> Any:
    """The landing's factor on a velocity of ``speed_mps`` (a number or an array): ``gain``
    for a step shorter than ``radius_m``, else 1."""
    return np.where(np.asarray(speed_mps) * dt_s < settle.radius_m, settle.gain, 1.0)


def damp_landing(velocity: Array, settle: Settle, dt_s: float) -> Array:
    """Velocities (..., 2) m/s as the landing lets them through (the training world's robots,
    as :class:`Lander` a robot's)."""
    v = np.asarray(velocity, dtype=np.float64)
    out: Array = v * landing_gain(np.hypot(v[..., 0], v[..., 1]), settle, dt_s)[..., None]
    return out
