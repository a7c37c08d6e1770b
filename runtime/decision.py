"""The decision pipeline: one robot's decision, and the same decision for a batch of teams.

A decision is a list of named steps, each with one implementation:

1. **assign** -- the shared slot assignment with hysteresis
   (:func:`runtime.formation.assign_centred` for one team,
   :func:`runtime.formation.assign_slots_batch` for E teams: one cost, one
   solver, one hysteresis rule).
2. **observe** -- :func:`runtime.observation.observe`, the builder the
   brain's spec names, for every robot or for the robot's own row.
3. **act** -- :func:`brain_velocities`: the brain's velocity per row (m/s).
   A *team rule* (a brain with ``team_plan``, e.g. ``rule:frame``,
   :mod:`runtime.rules`) skips step 2 and plans from what every robot sees
   anyway -- all positions, the pattern and the shared assignment of step 1 --
   with one function that both paths call on a batch (the robot on a batch of
   one team, then takes its own row), so a robot and ``eval`` agree number for
   number. It keeps no state between steps: its plan re-derives its frame from
   the poses (see :mod:`runtime.rules` for why that frame does not drift).
4. **command** -- :func:`command`: clamp to v_max, the ORCA safety filter
   on the robot's view of its neighbours (:func:`neighbour_rows` over
   :func:`frame_velocities`), clamp again. A non-finite brain velocity holds
   the robot still.

Two entry points run these steps:

:class:`runtime.controller.Controller`
    The robot's path: one robot, one team, once per step, keeping the state
    the steps need between calls (its own module).

:func:`decide_batch`
    The evaluation path (the trainer's ``eval``, benchmarks): E teams at
    once, one ``brain.act`` on (E*n, dim), then :func:`command` per robot.

Frames. ``frames[0]`` is the newest (t), ``frames[1]`` is t-1 and
``frames[2]`` is t-2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from runtime.brain import Brain
from runtime.formation import (
    assign_slots_batch,
    slot_positions,
)
from runtime.observation import (
    frame_velocities,
    observe,
)
from runtime.rules import plan_targets
from runtime.safety import OrcaParams, clamp_speed, landing, nearest_in_range, orca_velocity
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "Command",
    "Decision",
    "brain_velocities",
    "command",
    "commands",
    "decide_batch",
    "frame_velocities",
    "neighbour_rows",
]

ERR_NONFINITE = "brain output non-finite: holding still"
ERR_TEAM = "brain cannot drive this team size: holding still"
ERR_BRAIN = "brain failed: holding still"

Rows = list[list[float]]
Neighbours = tuple[list[float], Rows, Rows]
"""What :func:`neighbour_rows` gives: (own velocity, others' relative positions,
others' velocities), plain floats."""


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


class Command(NamedTuple):
    """Step 4's outcome for one robot."""

    velocity: tuple[float, float]
    """m/s, norm <= v_max."""
    changed: bool
    """Whether the safety filter changed the clamped brain velocity."""
    change_mps: float
    """Norm of that change (m/s)."""


# ------------------------------------------------------------------- helpers


def neighbour_rows(i: int, L: Rows, V: Rows) -> Neighbours:
    """Robot i's view of its neighbours for the safety filter.

    ``L``: positions at t, ``V``: :func:`frame_velocities`, both in robot-id
    order. Returns (own velocity, every other robot's position relative to
    robot i, those robots' absolute velocities), others in id order with i left
    out. ORCA itself keeps the ``max_neighbours`` nearest within
    ``neighbour_dist_m``, with deterministic ties.
    """
    px, py = L[i]
    rel = [[q[0] - px, q[1] - py] for q in L]
    del rel[i]
    return V[i], rel, V[:i] + V[i + 1 :]


# --------------------------------------------------------------------- steps


def brain_velocities(brain: Brain, obs: Array) -> Rows:
    """Step 3: the brain's velocity for every row of ``obs`` (m, dim) -> m rows [vx, vy] (m/s)."""
    out: Rows = np.asarray(brain.act(obs), dtype=np.float64).tolist()
    return out


def command(
    bvx: float,
    bvy: float,
    neighbours: Neighbours | None,
    safety: OrcaParams | None,
    world: WorldConfig,
) -> Command | None:
    """Step 4 for one robot: clamp -> ORCA safety filter -> clamp; None if not finite.

    ``neighbours``: :func:`neighbour_rows` of the robot (None when it has none);
    ``safety`` None skips the filter. None means the brain's velocity was not
    finite: the robot holds still.
    """
    if not (math.isfinite(bvx) and math.isfinite(bvy)):
        return None
    v_max = world.v_max_mps
    vx, vy = clamp_speed(bvx, bvy, v_max)
    if safety is None or neighbours is None:
        return Command((vx, vy), False, 0.0)
    own, rel, nbv = neighbours
    near = nearest_in_range(rel, safety)
    return _filtered(vx, vy, own, near, [nbv[k[3]] for k in near], safety, world)


def _filtered(
    vx: float,
    vy: float,
    own: list[float],
    near: list[tuple[float, float, float, int]],
    nb_vel: Rows,
    safety: OrcaParams,
    world: WorldConfig,
) -> Command:
    """The ORCA part of :func:`command`, neighbours chosen: ``near`` as
    :func:`runtime.safety.nearest_in_range` gives them, ``nb_vel`` their velocities."""
    ox, oy = own
    if not (math.isfinite(ox) and math.isfinite(oy)):
        ox = oy = 0.0  # as orca_filter: an unknown own velocity counts as zero
    rx, ry, changed, change = orca_velocity(vx, vy, ox, oy, near, nb_vel, world, safety)
    # the filter clamps its result to v_max (both ways of taking the norm): the
    # final clamp of step 4 would change nothing
    return Command((rx, ry), changed, change)


def _near_in_order(
    i: int, L: Rows, order: list[int], d2: list[float], params: OrcaParams
) -> list[tuple[float, float, float, int]]:
    """:func:`runtime.safety.nearest_in_range` of robot i's neighbours, read off the
    observation's order (:func:`runtime.observation.neighbour_order`) instead of
    every robot: the same tuples (index = robot id) in the same order.

    The filter sorts by (d^2, dx, dy, index) and keeps ``max_neighbours``; all of
    those lie within the first ``max_neighbours`` of ``order`` (sorted by d^2)
    and the ones tied with the last of them, so only that prefix is looked at.
    """
    keep = params.max_neighbours
    end = min(keep, len(order))
    if end == 0:
        return []
    last = d2[order[end - 1]]
    while end < len(order) and d2[order[end]] == last:
        end += 1
    range_sq = params.neighbour_dist_m * params.neighbour_dist_m
    px, py = L[i]
    near = []
    for j in order[:end]:
        dj = d2[j]
        if dj < range_sq:  # False for NaN and for i itself (inf)
            q = L[j]
            near.append((dj, q[0] - px, q[1] - py, j))
    near.sort()
    del near[keep:]
    return near


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
    safety_changed (E, n)). Same numbers as :meth:`Controller.decide` robot
    by robot; a non-finite brain output holds that robot still.
    """
    f = np.asarray(frames, dtype=np.float64)
    E, _, n, _ = f.shape
    pos, prev = f[:, 0], f[:, 1]
    c = np.asarray(pattern, dtype=np.float64)
    C = np.broadcast_to(c[None] if c.ndim == 2 else c, pos.shape)
    spec = brain.spec
    if not spec.accepts_team(n):
        raise ValueError(f"brain spec '{spec.name}' ({spec.n_robots} robots) cannot drive {n}")
    # 1. assign
    slots = assign_slots_batch(pos, C, prev_slots)
    team = getattr(brain, "team_plan", None)
    steps_left: Array | None = None  # a plan's steps left per team: the landing horizon
    if team is not None:  # a team rule: steps 2-3 from the poses
        out, steps_left = team(pos, C, slots)
        act: Rows = np.asarray(out, dtype=np.float64).reshape(E * n, 2).tolist()
    else:
        # 2. observe (every row)
        target = None
        if spec.name == "plan":
            target, steps_left = plan_targets(pos, C, slots, spec.travel_weight, world)
        elif spec.needs_slots:
            target = slot_positions(pos, C, slots)
        obs = observe(spec, f, target, None, world, steps_left)
        # 3. act
        act = brain_velocities(brain, obs.reshape(E * n, spec.dim))
    # 4. command, robot by robot
    vel, changed = commands(act, pos, prev, safety, world, steps_left)
    return vel, slots, changed


def commands(
    act: Rows | Array,
    pos: Array,
    prev: Array,
    safety: OrcaParams | None,
    world: WorldConfig = DEFAULT_WORLD,
    steps_left: Array | None = None,
) -> tuple[Array, BoolArray]:
    """Step 4 for E teams: every robot's :func:`command` from its own view.

    ``act``: the brain's velocities, (E * n) rows of [vx, vy] or an (E, n, 2)
    array (m/s); ``pos``, ``prev``: (E, n, 2) positions at t and t-1. Returns
    (velocities (E, n, 2) m/s, safety_changed (E, n)). ``steps_left`` (E,): each
    team's plan steps left, for the filter's landing horizon
    (:func:`runtime.safety.landing`); None for brains without a plan. The
    training world calls it too (``TrainConfig.train_safety``), so a brain
    trains behind the filter the robots run.
    """
    E, n, _ = pos.shape
    rows: Rows = act.reshape(E * n, 2).tolist() if isinstance(act, np.ndarray) else act
    vel = np.zeros((E, n, 2))
    changed = np.zeros((E, n), dtype=bool)
    filtering = safety is not None and n >= 2
    for e in range(E):
        L: Rows = pos[e].tolist()
        V = frame_velocities(L, prev[e].tolist(), world.dt_s) if filtering else []
        params = safety if steps_left is None else landing(safety, float(steps_left[e]), world)
        for i in range(n):
            bvx, bvy = rows[e * n + i]
            cmd = command(bvx, bvy, neighbour_rows(i, L, V) if filtering else None, params, world)
            if cmd is not None:
                vel[e, i] = cmd.velocity
                changed[e, i] = cmd.changed
    return vel, changed
