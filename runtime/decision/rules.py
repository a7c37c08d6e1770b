"""Team rules: rule brains that plan from the whole team, not from one observation row.

``rule:assign`` (:class:`runtime.brain.brain.RuleBrain`) reads one robot's general
observation and drives straight to its slot at up to v_max. Its slots sit on
the team's *current* centroid, and the centroid drifts while the far robots are
clipped to v_max and the near ones are not: it lands in about the fewest steps
(1.02x the lower bound) but travels 1.15x the least travel.

A :class:`FrameRule` fixes that drift without keeping any state. It is the
synchronised straight-line plan of CAPT (Turpin, Michael and Kumar, "Concurrent
assignment and planning of trajectories for multiple robots", 2014): every
robot heads straight for its slot in one shared frame ``t`` (a translation of
the pattern) at the speed that makes *all* robots arrive at the same step::

    s_i = c_sigma(i) + t - p_i                       slot vector (m)
    K   = max(1, ceil(max_j |s_j| / (v_max dt)))     steps left for the farthest robot
    v_i = s_i / (K dt)                               |v_i| <= v_max, exact landing at K = 1

``sigma`` is the pipeline's shared assignment (least summed squares, with
hysteresis), which does not depend on ``t``. The frame is a blend of two
centres of the displacements ``d_i = p_i - c_sigma(i)``::

    t = t_mec + travel_weight * (t_centroid - t_mec)

``t_mec`` is the centre of the smallest circle enclosing the ``d_i`` (the frame
of fewest steps for this assignment: the farthest robot is as near as it can
be), ``t_centroid`` their mean (the team's centroid stays where it is; close
to the frame of least travel). **Why no state is needed:** under the plan every
robot moves along ``p_i -> c_sigma(i) + t`` at a common fraction of its way, so
the displacements shrink homothetically towards ``t``; both centres, and so any
blend of them, are equivariant under that homothety, hence the next step
recomputes the very same ``t`` and ``sigma`` (the squared-distance assignment
of a linear interpolation towards its own optimum stays optimal). The frame is
"fixed once per pattern" by construction, and re-solved from the poses alone
whenever the team, the pattern or the safety filter moves a robot off the
plan: a robot process, ``eval`` and the world compute the same numbers from the
same poses (:func:`runtime.decision.pipeline.decide_batch` and
:class:`runtime.decision.controller.Controller` call :func:`frame_plan` alike).

Observation. A team rule reads what every robot already observes (all the
team's positions), the pattern and the shared assignment, through the decision
pipeline's ``team_plan`` hook instead of ``act(obs)``; its ``act`` on a
general observation row is ``rule:assign``'s (the only thing one row allows).
"""

from __future__ import annotations

from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from runtime.brain.manifest import BrainManifest
from runtime.core.plan_frame import plan_frame, plan_frames
from runtime.decision.observation import ObservationSpec
from runtime.types import Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "FRAME_RULES",
    "FrameRule",
    "PlanFrame",
    "frame_plan",
    "pace_velocity",
    "plan_step",
    "plan_targets",
    "plan_velocity",
    "straight_to_slot",
]

FRAME_RULES: Final[dict[str, float]] = {
    "rule:frame": 0.0,
    "rule:frame-balanced": 0.25,
    "rule:frame-travel": 1.0,
}
"""Each team rule's ``travel_weight``: 0 the frame of fewest steps, 1 the
centroid frame (less travel, a step or a few more). ``rule:frame-balanced``
(0.25) is the base the shipped plan brains learn on: behind the safety filter
the weights 0, 0.25, 0.5 and 0.75 tie on steps + travel (2.260-2.272 on 15
cases, docs/frontier.md); 0.25 cuts rule:frame's travel most for the fewest
steps given up."""


def straight_to_slot(obs: NDArray[Any], world: WorldConfig = DEFAULT_WORLD) -> Array:
    """``rule:assign`` on general observation rows: slot vector / dt, clipped to v_max.

    ``obs`` (m, dim) -> (m, 2) m/s.
    """
    v = np.asarray(obs[:, 0:2], dtype=np.float64) / world.dt_s
    sp = np.hypot(v[:, 0], v[:, 1])
    scale = np.where(sp > world.v_max_mps, world.v_max_mps / np.maximum(sp, 1e-300), 1.0)
    out: Array = v * scale[:, None]
    return out


def plan_targets(
    pos: Array,
    pattern: Array,
    slots: IntArray,
    travel_weight: float,
    world: WorldConfig = DEFAULT_WORLD,
) -> tuple[Array, Array]:
    """Every robot's slot in the blended frame, and the steps the plan has left.

    ``pos`` (E, n, 2) positions (m), ``pattern`` (E, n, 2) the pattern (any
    translation), ``slots`` (E, n) the shared assignment, ``travel_weight`` in
    [0, 1] (see the module docstring). Returns (targets (E, n, 2) m: the slot
    points of the pattern translated by the frame ``t``; steps_left (E,): ``K``,
    the whole steps the farthest robot needs at v_max, at least 1).
    """
    p = np.ascontiguousarray(pos, dtype=np.float64)
    target = np.take_along_axis(np.asarray(pattern, dtype=np.float64), slots[..., None], axis=-2)
    E = p.shape[0]
    t = np.empty((E, 2))
    k = np.empty(E)
    plan_frames(p, target, travel_weight, world.v_max_mps * world.dt_s, t, k)
    target += t[:, None, :]
    return target, k


def frame_plan(
    pos: Array,
    pattern: Array,
    slots: IntArray,
    travel_weight: float,
    world: WorldConfig = DEFAULT_WORLD,
) -> Array:
    """Every robot's velocity under the synchronised plan in the blended frame.

    Arguments as :func:`plan_targets`. Returns (E, n, 2) m/s, each of norm
    <= v_max; all robots of a team land on their slots at the same step.
    """
    return plan_step(pos, pattern, slots, travel_weight, world)[0]


def plan_step(
    pos: Array,
    pattern: Array,
    slots: IntArray,
    travel_weight: float,
    world: WorldConfig = DEFAULT_WORLD,
) -> tuple[Array, Array]:
    """:func:`frame_plan`'s velocities (E, n, 2) m/s and the plan's steps left K (E,)."""
    target, k = plan_targets(pos, pattern, slots, travel_weight, world)
    return plan_velocity(target, pos, k, world), k


def plan_velocity(target: Array, pos: Array, steps_left: Array | float,
                  world: WorldConfig = DEFAULT_WORLD) -> Array:
    """The plan's velocities (..., n, 2) m/s: each robot's way to its ``target`` over the
    ``steps_left`` K of its team (...,), so that all land at the same step."""
    return pace_velocity(target, pos, np.asarray(steps_left, dtype=np.float64)[..., None],
                         world)


def pace_velocity(target: Array, pos: Array, steps: Array | float,
                  world: WorldConfig = DEFAULT_WORLD) -> Array:
    """Velocities (..., n, 2) m/s: each robot's way to its ``target`` over its own ``steps``
    left (..., n), or a number for all (a landing at each robot's own pace,
    :func:`runtime.decision.settle.landing_steps`)."""
    out: Array = (np.asarray(target, dtype=np.float64) - np.asarray(pos, dtype=np.float64)) \
        / (np.asarray(steps, dtype=np.float64)[..., None] * world.dt_s)
    return out


class PlanFrame:
    """:func:`plan_targets` for one team, step after step: the robot's path.

    The solve is :func:`runtime.core.plan_frame.plan_frame`, which keeps the last
    step's support (the displacements on the smallest enclosing circle) and tries
    it first (see there for why that circle stays the smallest under the plan, and
    for the slack that keeps a formed team from re-solving). This object holds the
    support and the scratch between steps.
    """

    def __init__(self) -> None:
        self._sup = np.zeros(4, dtype=np.int64)  # the support: [count, j0, j1, j2]
        self._d = np.zeros((0, 2))  # the displacements (scratch)

    def solve(self, pos: Array, slot_points: Array, travel_weight: float,
              world: WorldConfig = DEFAULT_WORLD) -> tuple[Array, float]:
        """``pos`` (n, 2) positions, ``slot_points`` (n, 2) each robot's pattern point (any
        translation of the pattern). Returns (the frame ``t`` (2,), steps left ``K``):
        robot j's slot is ``slot_points[j] + t``."""
        tx, ty, k = self.solve_floats(pos, slot_points, travel_weight, world)
        return np.array([tx, ty]), k

    def solve_floats(self, pos: Array, slot_points: Array, travel_weight: float,
                     world: WorldConfig = DEFAULT_WORLD) -> tuple[float, float, float]:
        """:meth:`solve` as plain floats (tx, ty, K)."""
        n = len(pos)
        if self._d.shape[0] < n:
            self._d = np.zeros((n, 2))
        return plan_frame(
            np.ascontiguousarray(pos, dtype=np.float64),
            np.ascontiguousarray(slot_points, dtype=np.float64),
            self._d, travel_weight, world.v_max_mps * world.dt_s, self._sup)


class FrameRule:
    """A team rule (``rule:frame``, ``-balanced``, ``-travel``): :func:`frame_plan` in the pipeline.

    ``team_plan(pos, pattern, slots)`` -> ((E, n, 2) m/s, (E,) steps left) is what
    :mod:`runtime.decision.pipeline` calls; ``act`` (a general observation row ->
    ``rule:assign``'s velocity) is only the per-row fallback of the Brain
    interface.
    """

    def __init__(
        self,
        name: str,
        world: WorldConfig = DEFAULT_WORLD,
        k_neighbours: int = 6,
        travel_weight: float | None = None,
    ) -> None:
        """``travel_weight`` (default: the named rule's) places any frame between the two
        ends, e.g. to trace the frontier (``benchmarks/frontier.py``)."""
        if name not in FRAME_RULES:
            raise ValueError(f"unknown team rule '{name}' (known: {', '.join(FRAME_RULES)})")
        self.travel_weight = FRAME_RULES[name] if travel_weight is None else float(travel_weight)
        self.brain_id = name if travel_weight is None else f"{name}@{self.travel_weight:g}"
        self.spec = ObservationSpec("general", k_neighbours=k_neighbours)
        self.manifest: BrainManifest | None = None
        self._world = world

    def act(self, obs: NDArray[Any]) -> Array:
        return straight_to_slot(np.asarray(obs), self._world)

    def team_plan(self, pos: Array, pattern: Array, slots: IntArray,
                  travel_weight: float | None = None) -> tuple[Array, Array]:
        """(E, n, 2) positions, (E, n, 2) pattern, (E, n) slots -> every robot's velocity
        (E, n, 2) m/s and the plan's steps left K per team (E,), which the safety filter's
        landing horizon reads (:func:`runtime.decision.safety.landing`)."""
        w = self.travel_weight if travel_weight is None else travel_weight
        return plan_step(pos, pattern, slots, w, self._world)

