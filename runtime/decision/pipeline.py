"""The decision pipeline: its steps, each one function, for a batch of teams or one robot.

A decision is a list of named steps; each is written once, batched over (teams x
robots), and a robot runs it on its own team (a batch of one) and its own row:

1. **assign** -- the shared slot assignment with hysteresis
   (:mod:`runtime.core.assignment`; :func:`runtime.decision.formation.assign_slots_batch`).
2. **target** -- :func:`targets`: each robot's slot in the world, and for a brain
   on the plan the plan's steps left (:mod:`runtime.core.plan_frame`).
3. **observe** -- the rows the brain's spec names (:mod:`runtime.core.general_row`
   for the general and plan specs; the paper's from :mod:`runtime.decision.observation`).
4. **act** -- the brain's velocity per row (m/s). A *team rule* (a brain with
   ``team_plan``, e.g. ``rule:frame``, :mod:`runtime.decision.rules`) plans from what every
   robot sees anyway -- all positions, the pattern and the shared assignment -- in
   place of steps 2-4.
5. **command** -- :func:`commands`: clamp to v_max and the ORCA safety filter on
   the robot's view of its neighbours (:mod:`runtime.core.orca`, its neighbour
   choice inside it), the horizon shortened to the plan's landing
   (:func:`runtime.decision.safety.landing`). A non-finite brain velocity holds the robot
   still.

Two callers run these steps:

:func:`decide_batch`
    The evaluation path (the trainer's ``eval``, benchmarks): E teams at once.

:class:`runtime.decision.controller.Controller`
    The robot's path: one robot, one team, once per step, holding the state the
    steps keep between calls (the frames, the assignment's potentials, the plan's
    support, the scratch of the row builder and the filter).

Frames. ``frames[0]`` is the newest (t), ``frames[1]`` is t-1 and ``frames[2]``
is t-2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.brain.brain import Brain
from runtime.decision.formation import assign_slots_batch, slot_positions
from runtime.decision.observation import observe
from runtime.decision.rules import plan_targets
from runtime.decision.safety import OrcaParams, landing, make_filter
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "Decision",
    "commands",
    "decide_batch",
    "preferred_velocities",
    "targets",
]

ERR_NONFINITE = "brain output non-finite: holding still"
ERR_TEAM = "brain cannot drive this team size: holding still"
ERR_BRAIN = "brain failed: holding still"


@dataclass(slots=True)
class Decision:
    """One robot's decision for one step."""

    velocity: tuple[float, float]
    """The command (m/s): after the safety filter, norm <= v_max."""
    brain_velocity: tuple[float, float]
    """What the brain asked for (m/s), before clamping and the filter."""
    safety_changed: bool
    """Whether the safety filter changed the (clamped) brain velocity."""
    safety_change_mps: float
    """By how much (norm of the difference, m/s)."""
    decision_us: float
    """Wall time of the whole decision (assignment, observation, brain, filter)."""
    error: str = ""
    """Empty when all went well; else why the robot holds still this step."""
    slot: int = -1
    """The pattern index this robot was assigned (-1 without an assignment)."""


# --------------------------------------------------------------------- steps


def targets(brain: Brain, pos: Array, pattern: Array, slots: IntArray,
            world: WorldConfig = DEFAULT_WORLD) -> tuple[Array | None, Array | None]:
    """Step 2 for E teams: (each robot's slot in the world (E, n, 2) m, the plan's steps
    left (E,)), for the brain's spec; (None, None) for the paper's (no slots), steps left
    None for the general spec (no plan)."""
    spec = brain.spec
    if spec.name == "plan":
        return plan_targets(pos, pattern, slots, spec.travel_weight, world)
    if spec.needs_slots:
        return slot_positions(pos, pattern, slots), None
    return None, None


def preferred_velocities(brain: Brain, frames: Array, pattern: Array, slots: IntArray,
                         world: WorldConfig = DEFAULT_WORLD) -> tuple[Array, Array | None]:
    """Steps 2-4 for E teams: every robot's brain velocity (E, n, 2) m/s and the plan's
    steps left per team (E,) (None for a brain without a plan).

    ``frames`` (E, 3, n, 2), ``pattern`` (E, n, 2), ``slots`` (E, n) from step 1.
    """
    E, _, n, _ = frames.shape
    pos = frames[:, 0]
    team = getattr(brain, "team_plan", None)
    if team is not None:  # a team rule plans from the poses
        out, steps_left = team(pos, pattern, slots)
        return np.asarray(out, dtype=np.float64).reshape(E, n, 2), steps_left
    slot_pos, steps_left = targets(brain, pos, pattern, slots, world)
    obs = observe(brain.spec, frames, slot_pos, None, world, steps_left)
    act = np.asarray(brain.act(obs.reshape(E * n, brain.spec.dim)), dtype=np.float64)
    return act.reshape(E, n, 2), steps_left


def commands(
    act: Array,
    pos: Array,
    prev: Array,
    safety: OrcaParams | None,
    world: WorldConfig = DEFAULT_WORLD,
    steps_left: Array | None = None,
) -> tuple[Array, BoolArray]:
    """Step 5 for E teams: every robot's command from its own view.

    ``act``: the brain's velocities, (E, n, 2) or (E * n, 2) (m/s); ``pos``, ``prev``:
    (E, n, 2) positions at t and t-1 (the velocities the filter assumes are their
    difference / dt). Returns (velocities (E, n, 2) m/s, safety_changed (E, n)).
    ``steps_left`` (E,): each team's plan steps left, for the filter's landing horizon
    (:func:`runtime.decision.safety.landing`); None for brains without a plan. ``safety`` None:
    the speed clamp only. The training world calls it too
    (``TrainConfig.train_safety``), so a brain trains behind the filter the robots run.
    """
    P = np.ascontiguousarray(pos, dtype=np.float64)
    E, n, _ = P.shape
    pref = np.ascontiguousarray(np.asarray(act, dtype=np.float64).reshape(E, n, 2))
    V = np.ascontiguousarray((P - np.asarray(prev, dtype=np.float64)) / world.dt_s)
    params = safety if safety is not None else OrcaParams()
    if steps_left is None:
        horizon = np.full(E, params.time_horizon_s)
    else:
        horizon = np.array([landing(params, float(k), world) for k in np.reshape(steps_left, E)])
    vel = np.empty((E, n, 2))
    changed = np.zeros((E, n), dtype=np.uint8)
    make_filter(safety, world).teams(P, V, pref, horizon, vel, changed)
    return vel, changed.astype(bool)


# ---------------------------------------------------------------- E teams


def decide_batch(
    brain: Brain,
    frames: Array,
    pattern: Array,
    prev_slots: IntArray | None = None,
    safety: OrcaParams | None = OrcaParams(),  # noqa: B008 - frozen, immutable default
    world: WorldConfig = DEFAULT_WORLD,
) -> tuple[Array, IntArray, BoolArray]:
    """Every robot's decision in E teams at once: the evaluation path.

    ``frames``: (E, 3, n, 2) positions at [t, t-1, t-2]. ``pattern``: (n, 2),
    (1, n, 2) or (E, n, 2). ``prev_slots``: (E, n) assignment of the last step
    (hysteresis) or None. Returns (velocities (E, n, 2) m/s, slots (E, n),
    safety_changed (E, n)). The steps :meth:`runtime.decision.controller.Controller.decide`
    runs robot by robot; a non-finite brain output holds that robot still.
    """
    f = np.asarray(frames, dtype=np.float64)
    n = f.shape[2]
    pos, prev = f[:, 0], f[:, 1]
    c = np.asarray(pattern, dtype=np.float64)
    C = np.broadcast_to(c[None] if c.ndim == 2 else c, pos.shape)
    spec = brain.spec
    if not spec.accepts_team(n):
        raise ValueError(f"brain spec '{spec.name}' ({spec.n_robots} robots) cannot drive {n}")
    slots = assign_slots_batch(pos, C, prev_slots)  # 1. assign
    act, steps_left = preferred_velocities(brain, f, C, slots, world)  # 2-4
    vel, changed = commands(act, pos, prev, safety, world, steps_left)  # 5. command
    return vel, slots, changed
