"""E teams of robots, each robot deciding on its own view: the robot's path, E x n times.

Under imperfect sensing (:class:`runtime.conditions.Conditions`) no two robots see the
same team, so the batch path (one view per team, :func:`runtime.decision.pipeline.decide_batch`)
no longer says what a swarm does. :class:`LocalDecisions` runs, for every robot of every
team, what its robot process runs: its :class:`runtime.decision.sensing.Sensor` view,
optionally its :class:`runtime.decision.estimator.PeerTracker`, and its own
:class:`runtime.decision.controller.Controller` (its own assignment, hysteresis and plan),
with the safety filter's margin widened by the uncertainty it knows it has
(:func:`runtime.decision.safety.uncertainty_params`). ``patternrl eval --conditions`` and
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
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["LocalDecisions"]


class LocalDecisions:
    """Every robot of ``n_envs`` teams of ``n_robots`` deciding on its own view.

    ``seed``: robot i of env e senses with generator ``SeedSequence((seed, e, i))``.
    ``safety`` None: the speed clamp only; else its margin is widened for ``conditions``
    (and the estimator, when on).
    """

    def __init__(self, brain: Brain, n_envs: int, n_robots: int, conditions: Conditions,
                 *, estimator: bool = False, safety: OrcaParams | None = OrcaParams(),  # noqa: B008
                 seed: int = 0, world: WorldConfig = DEFAULT_WORLD) -> None:
        E, n = n_envs, n_robots
        self.n_envs, self.n_robots = E, n
        self.conditions = conditions
        observer = np.tile(np.arange(n), E)
        seeds = [np.random.SeedSequence((seed, e, i)) for e in range(E) for i in range(n)]
        self.sensor = Sensor(conditions, observer, seeds)
        self.tracker = PeerTracker(observer, conditions.noise_m, conditions.latency_steps,
                                   world=world) if estimator else None
        self.safety = None if safety is None else uncertainty_params(safety, conditions,
                                                                     estimator, world)
        self.controllers = [Controller(brain, world, self.safety) for _ in range(E * n)]
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
        view, age = self.sensor.sense(np.repeat(P, n, axis=0))
        vel_est = now = None
        if self.tracker is not None:  # plan from the smoothed views, filter from now
            now, vel_est, _ = self.tracker.update(view, age)
            view = self.tracker.sensed
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
