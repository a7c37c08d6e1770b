"""E teams of robots, each robot deciding on its own view: the robot's path, E x n times.

Under imperfect sensing (:class:`runtime.conditions.Conditions`) no two robots see the
same team, so the batch path (one view per team, :func:`runtime.decision.pipeline.decide_batch`)
no longer says what a swarm does. :class:`LocalDecisions` runs, for every robot of every
team, what its robot process runs: its :class:`runtime.decision.sensing.Sensor` view,
optionally its :class:`runtime.decision.estimator.PeerTracker`, and its own
:class:`runtime.decision.controller.Controller` (its own assignment, hysteresis and plan),
with the safety filter's margin widened by the uncertainty it knows it has
(:func:`runtime.decision.safety.uncertainty_params`, the filter on the tracker's estimates).
``patternrl eval --conditions`` and
``benchmarks/conditions.py`` use it; ground truth is the world's.
"""

from __future__ import annotations

import numpy as np

from runtime.brain.brain import Brain
from runtime.conditions import Conditions
from runtime.decision.controller import Controller
from runtime.decision.estimator import PeerTracker
from runtime.decision.safety import OrcaParams, uncertainty_params
from runtime.decision.sensing import Sensor
from runtime.decision.settle import settle_for
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["LocalDecisions", "Perception"]


class Perception:
    """What B robots perceive of their teams: the :class:`Sensor` under ``conditions``,
    and each robot's :class:`PeerTracker`.

    :meth:`perceive` returns, per robot, the team as its brain plans from it (the raw views,
    or with ``estimator`` the tracker's positions as sensed), the team as its safety filter
    takes it now and the velocities. The filter always works from the tracker when sensing
    is imperfect, whatever the brain reads: frame differences of views with 5 cm of noise
    are velocities off by 0.7 m/s, and reciprocal avoidance on them collided 0.4 times per
    episode (``benchmarks/conditions.py``, `rule:frame-balanced`, n = 10). Under perfect
    sensing without ``estimator`` there is no tracker: (views, None, None), and the
    controller takes the views and their frame differences, exactly as before."""

    def __init__(self, conditions: Conditions, observer: IntArray,
                 seeds: list[np.random.SeedSequence], estimator: bool = False,
                 world: WorldConfig = DEFAULT_WORLD, naive: bool = False) -> None:
        self.conditions = conditions
        self.sensor = Sensor(conditions, observer, seeds)
        self.estimator = estimator
        tracked = estimator or not (conditions.sensing_perfect or naive)
        self.tracker = PeerTracker(observer, conditions.noise_m, conditions.latency_steps,
                                   world=world) if tracked else None
        self.last_age: IntArray | None = None
        """(B, n) the age in steps of each position of the last views sensed."""

    def perceive(self, truth: Array) -> tuple[Array, Array | None, Array | None]:
        """(plan view (B, n, 2), filter view (B, n, 2) or None, velocities (B, n, 2) or None)
        from each robot's team as it truly is now, ``truth`` (B, n, 2)."""
        view, age = self.sensor.sense(truth)
        self.last_age = age
        if self.tracker is None:
            return view, None, None
        now, vel, _ = self.tracker.update(view, age)
        plan = self.tracker.sensed if self.estimator else view  # smoothed, as sensed
        return plan, now, vel


class LocalDecisions:
    """Every robot of ``n_envs`` teams of ``n_robots`` deciding on its own view.

    ``seed``: robot i of env e senses with generator ``SeedSequence((seed, e, i))``.
    ``safety`` None: the speed clamp only; else its margin is widened for ``conditions``.
    ``naive``: a robot that ignores what it knows of its sensing (no tracker for its filter,
    no widened margin, no damped landing): the pipeline as it ran before any of these, for
    comparison (``benchmarks/conditions.py``'s ``+naive`` brains).
    """

    def __init__(self, brain: Brain, n_envs: int, n_robots: int, conditions: Conditions,
                 *, estimator: bool = False, safety: OrcaParams | None = OrcaParams(),  # noqa: B008
                 seed: int = 0, world: WorldConfig = DEFAULT_WORLD,
                 naive: bool = False) -> None:
        E, n = n_envs, n_robots
        self.n_envs, self.n_robots = E, n
        self.conditions = conditions
        observer = np.tile(np.arange(n), E)
        seeds = [np.random.SeedSequence((seed, e, i)) for e in range(E) for i in range(n)]
        self.perception = Perception(conditions, observer, seeds, estimator, world, naive)
        self.safety = safety if safety is None or naive else uncertainty_params(
            safety, conditions, world)
        settle = None if naive else settle_for(conditions, estimator, world)
        self.controllers = [Controller(brain, world, self.safety, settle)
                            for _ in range(E * n)]
        self.step = 0
        self.last_view: Array | None = None
        """The last step's perceived team per robot, (E, n, n, 2) m (estimates when on)."""

    def decide(self, truth: Array, pattern: Array, live: BoolArray | None = None
               ) -> tuple[Array, IntArray, BoolArray]:
        """Every robot's command (E, n, 2) m/s, its slot (E, n) (-1 held) and whether the
        filter changed it (E, n), from the true positions ``truth`` (E, n, 2) and each
        team's ``pattern`` (E, n, 2). Teams not ``live`` get zeros (their robots still
        sense, so their views stay current)."""
        E, n = self.n_envs, self.n_robots
        P = np.asarray(truth, dtype=np.float64)
        view, now, vel_est = self.perception.perceive(np.repeat(P, n, axis=0))
        self.last_view = view.reshape(E, n, n, 2)
        out = np.zeros((E, n, 2))
        slots = np.full((E, n), -1, dtype=np.int64)
        changed = np.zeros((E, n), dtype=bool)
        for e in range(E):
            if live is not None and not live[e]:
                continue
            C = pattern[e]
            for i in range(n):
                b = e * n + i
                d = self.controllers[b].decide(
                    i, view[b], C, self.step, None if vel_est is None else vel_est[b],
                    None if now is None else now[b])
                out[e, i] = d.velocity
                slots[e, i] = d.slot
                changed[e, i] = d.safety_changed
        self.step += 1
        return out, slots, changed
