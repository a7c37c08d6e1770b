"""ORCA safety filter: the last word between a brain and its robot's motors.

Every step, each robot replaces its brain's *preferred* velocity by the velocity
closest to it that ORCA (optimal reciprocal collision avoidance, van den Berg,
Guy, Lin and Manocha, 2011) deems collision-free with respect to its
neighbours. The algorithm is a line-for-line port of RVO2's
``Agent::computeNewVelocity`` (agent-agent part), written once in
:mod:`runtime.core.orca` with its neighbour choice inside it, and of its three linear
programs ``linearProgram1/2/3``, in :mod:`runtime.core.orca_lp` (both compiled at
install, the same source runs as Python without a compiler). This module holds the
filter's tuning (:class:`OrcaParams`), the landing horizon and the one-robot
convenience call :func:`orca_filter`.

The filter works from the robot's own observation only: neighbours' positions
relative to its own and their velocities (which the caller estimates from two
consecutive frames). Each robot takes half the responsibility for each pair;
when both robots of a pair run the filter with consistent velocity estimates,
and the linear program is feasible, their centres stay at least
``2 * (R + radius_margin_m)`` apart over the time horizon.

Choices, all documented here:

* **Time horizon** ``OrcaParams.time_horizon_s`` (tau) for other robots.
* **Collision case.** When two robots already overlap the *inflated* radius
  ``2 * (R + radius_margin_m)``, RVO2 "projects on the cut-off circle at time
  step": the constraint asks the pair to be separated again after one time
  step. We use the world's ``dt_s`` as that time step, so one discrete step
  never brings two centres below ``2R`` when both robots run the filter.
* **Speed limit.** The linear program uses the max-speed circle of radius
  ``v_max``; the result is also clamped, so ``|v| <= v_max`` always.
* **Non-finite input.** A NaN/inf preferred or own velocity is treated as zero;
  a neighbour with a non-finite position is ignored, one with a non-finite
  velocity is assumed still.
* **Deadlock breaking ("keep right").** ORCA is symmetric, and symmetric
  encounters stall: two robots crossing at right angles, mirror images of each
  other, or a ring of robots swapping antipodes, all slow down and freeze. (An
  exactly head-on pair does not: RVO2's tie rule picks the right leg.)
  Whenever the preferred velocity violates at least one ORCA half-plane, we
  rotate it clockwise by the small fixed angle ``OrcaParams.keep_right_rad``
  (default 0.2 rad, about 11 degrees) before solving the linear program. Every
  robot thus veers slightly to its own right when something is in its way:
  mirror-symmetric pairs resolve, and a symmetric crowd tends to turn into a
  roundabout instead of a jam (8 robots swapping antipodes on a 2 m circle
  arrive with the defaults, tau = 0.75 s and a 2 cm margin, in 71 steps, and
  12 in 88; at tau = 0.5 s with a 1 cm margin they stall, without collision:
  ``benchmarks/orca_sweep.py`` measures which settings stall).
  The rule is a symmetry breaker, not a traffic law: it does not
  override an encounter that is already asymmetric (a head-on pair offset by
  a few millimetres passes on whichever side ORCA picks). It is deterministic
  (no RNG) and does nothing when the preferred velocity is already safe.
  Set the angle to 0 to recover plain RVO2 behaviour (the RVO2 examples
  perturb the preference randomly instead).
* **Landing.** ORCA predicts every robot at constant velocity over its horizon,
  so a robot running at full speed toward a slot 0.4 m from a neighbour's looks
  bound for a collision that its landing would never reach; the filter slowed
  or turned it, and since the farthest robot sets a synchronised team's pace,
  the whole team lost a step each time (86-100 % of the steps the filter cost
  `rule:frame-balanced` fell in the last third of an episode, docs/frontier.md).
  A team on a synchronised plan (the plan observation's brains, the frame
  rules) knows better: every robot computes the same steps left K from the
  same poses, and after K steps every robot rests on its slot, the slots at
  least the pattern spacing apart. So its horizon is ``min(tau, K dt)``
  (:func:`landing`, ``OrcaParams.landing``): both robots of a pair use the same
  one, so the reciprocal guarantee holds up to the landing, and the horizon
  never falls below dt, which keeps the guarantee for the next step. A robot
  whose brain leaves the plan meets a K that does not fall and keeps its
  longer horizon. Measured (``benchmarks/frontier.py``, 20 cases up to 50
  robots): ``rule:frame-balanced`` behind the filter 1.160 -> 1.070 of the
  steps lower bound and 1.109 -> 1.081 of the travel one (1.066 / 1.081
  without any filter), no collision.
* **Infeasible crowds.** When the half-planes leave no velocity within the
  speed circle, RVO2's third linear program picks the velocity that violates
  them least; the 2R guarantee is then lost. In dense random crowds (30
  robots in 3 m x 3 m) centres were seen to dip to about 0.19 m; up to 20
  robots in 3 m x 3 m they stayed above 0.2 m.
* **The guard, under real-world conditions.** ORCA's guarantee rests on both robots of a
  pair predicting each other's velocity alike; noisy, late and gappy views break it (a
  brain that drives every robot at its nearest peer, :mod:`trainer.adversary`, collided
  0.5-195 times per episode behind ORCA alone with 5 cm of noise, 2 steps of latency or 30 %
  of updates lost). Under any condition but the perfect world (:func:`uncertainty_params`)
  a last-resort guard follows the linear program (:meth:`runtime.core.orca.OrcaFilter.robot`):
  each robot keeps its approach to each neighbour, counted from the pair as it last saw it,
  within half the room above ``2 (R + radius_margin_m + guard_margin_m)``, along the seen
  direction and the two edges of the cone a noisy view leaves. It needs distances only:
  a late view is paired with the robot's own pose of the same age, so latency needs no
  margin (a lost one, older than the latency, with the robot's pose of the latency's age,
  its peer taken to have come its unseen way meanwhile); the margin is
  :data:`GUARD_SIGMAS` of the raw noise plus the wheels' noise (:func:`guard_bound`), and
  the bounds on the command are divided by one plus the
  wheels' gain spread (``OrcaParams.guard_gain``), which errs in proportion to the step
  asked: a landing's short steps keep nearly all their room, where a full step's gain
  error added to the guard's distance had cost every step of every pair. With the sensing
  and actuation noises added in quadrature (:func:`guard_bound`), the realistic preset went
  from 1.37x to 1.30x the steps lower bound (rule + tracker, n = 10, 100 episodes; 1.62x ->
  1.49x at n = 25), the charging adversary 0 collisions; 1.25x with every robot of a landing
  keeping the landed guard (:mod:`runtime.decision.settle`, "The guard near the slot"). On
  a differential-drive base the controller scales the command until what the wheels will drive
  along the heading stays within it (:meth:`runtime.core.orca.OrcaFilter.guard_scale`).
  Measured with the charging adversary (``benchmarks/conditions.py``, n = 10, 100 episodes per
  condition): 0 collisions under 5 and 10 cm noise, 1-3 steps late, 30 % lost, noisy wheels,
  differential drive and the realistic preset; tests/unit/runtime/decision/test_conditions.py
  holds it per condition.
* **Who needs the room takes it.** Half the room each is the only split two robots agree on
  when their views of the pair differ. Under exact sensing (no noise, no loss: latency and
  wheels only) they do not: both know the pair as it was when last seen to the bit, each
  robot's position and its last step, the robot's own from its pose history and the peer's
  from two consecutive views. So they split the room by how fast each was closing on the
  other then, ``(a + c) / (a + a' + 2 c)`` (:func:`guard_shares`, ``c`` =
  :data:`GUARD_SHARE_EVEN` of full speed): a robot arriving next to a landed peer may take
  nearly all of it, the landed one nearly none, and the two shares sum to 1, so the
  guarantee stands; they move by at most
  :data:`runtime.decision.local.GUARD_SHARE_RATE` a step, as the bound counts an approach
  made under the shares of the steps before. Under noise or loss each robot keeps half.
  Measured with the landing in the centroid frame (:func:`runtime.decision.settle.settle_for`;
  ``benchmarks/conditions.py``, n = 10, 100 episodes per case, `rule:frame-balanced` + the
  tracker): 3 steps late 1.26x -> 1.11x the steps lower bound, 2 steps 1.15x -> 1.08x, 1 step
  1.08x -> 1.07x, all held, and the charging adversary 0 collisions; on other seeds (20
  episodes per shape) ``c`` of 0.5 % of full speed let it collide 0.02 times per episode at
  3 steps late, 2 % and 5 % did not.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
import numpy.typing as npt

from runtime.conditions import PERFECT, Conditions
from runtime.core.orca import CHANGE_TOL_MPS, OrcaFilter
from runtime.core.orca_lp import clamp_speed
from runtime.decision.estimator import steady_sigma
from runtime.decision.patterns import min_spacing
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "SAFETY_MODES",
    "FilterResult",
    "OrcaFilter",
    "OrcaParams",
    "clamp_speed",
    "guard_bound",
    "guard_distance",
    "guard_note",
    "guard_shares",
    "landing",
    "make_filter",
    "orca_filter",
    "pattern_guard_note",
    "safety_mode",
    "safety_params",
    "uncertainty_bound",
    "uncertainty_margin",
    "uncertainty_params",
]

Vec2 = tuple[float, float] | Sequence[float] | npt.NDArray[np.floating]
Vec2s = Sequence[Sequence[float]] | npt.NDArray[np.floating]
"""k 2-vectors, one a row (k x 2): neighbours' relative positions or velocities."""


@dataclass(frozen=True)
class OrcaParams:
    """Tuning of the ORCA filter. Units are in the names (s, m, rad)."""

    time_horizon_s: float = 0.75
    """ORCA tau for other robots: avoid collisions this far ahead. 0.75 s with a
    2 cm margin is the least-cost point of a measured sweep that keeps 2R, no
    collision and no stalled crowd (``benchmarks/orca_sweep.py``, docs/frontier.md)."""
    radius_margin_m: float = 0.02
    """Added to R: the pair's combined radius is ``2 * (R + margin)``."""
    max_neighbours: int = 10
    """Only the nearest this many neighbours in range are considered."""
    neighbour_dist_m: float = 2.0
    """Neighbours whose centre is this far or farther are ignored."""
    keep_right_rad: float = 0.2
    """Clockwise rotation of the preferred velocity when it violates an ORCA
    constraint (deadlock breaking, see the module docstring). 0 disables it."""
    uncertainty_margin_m: float = 0.0
    """Added to ``radius_margin_m`` for what a robot does not know exactly of its peers and
    its wheels (:func:`uncertainty_params`). Unlike ``radius_margin_m`` it is kept only where
    there is room: a pair already closer keeps its distance, and only a pair closer than
    ``2 (R + radius_margin_m)`` is pushed apart as colliding."""
    guard_margin_m: float = -1.0
    """The last-resort guard (:meth:`runtime.core.orca.OrcaFilter.robot`) keeps centres, as
    the robot sees them, ``2 (R + radius_margin_m + guard_margin_m)`` apart, whatever it
    believes of its neighbours' velocities. Negative: no guard (ORCA alone, as in the
    perfect world, where every robot predicts every other exactly);
    :func:`uncertainty_params` sets it to the whole uncertainty bound."""
    guard_gain: float = 0.0
    """How much more than commanded the wheels may drive (a share of the command: the
    wheels' gain spread, ``Conditions.gain_noise``); the guard divides its bounds on the
    command by ``1 + guard_gain`` (:func:`guard_bound`)."""
    landing: bool = True
    """For a team on a synchronised plan (plan brains, frame rules), the horizon is
    at most the plan's time left, ``K dt`` (see "Landing" in the module docstring
    and :func:`landing`)."""
    guard: bool = True
    """Whether :func:`uncertainty_params` gives the filter its last-resort guard. False is for
    measuring what the guard costs (``eval --safety orca-no-guard``): ORCA alone is not safe
    on imperfect views, so no robot runs without it."""


def landing(params: OrcaParams, steps_left: float | None,
            world: WorldConfig = DEFAULT_WORLD) -> float:
    """The filter's time horizon (s) for a team whose plan has ``steps_left`` (K) steps to go.

    With ``params.landing`` it is ``min(time_horizon_s, max(K, 1) dt)``: every
    robot of the team computes the same K from the same poses, and after K steps
    all of them rest on their slots. ``steps_left`` None (a brain without a plan)
    keeps ``time_horizon_s``.
    """
    if steps_left is None or not params.landing:
        return params.time_horizon_s
    horizon = max(float(steps_left), 1.0) * world.dt_s
    return horizon if horizon < params.time_horizon_s else params.time_horizon_s


def uncertainty_margin(conditions: Conditions, world: WorldConfig = DEFAULT_WORLD) -> float:
    """How much (m) a robot widens each robot's radius for the uncertainty it knows it has.

    A pair is kept ``2 (R + margin)`` apart as the robot sees it; the truth may differ by
    the peer's position error and by what the wheels did not do as asked. Per robot:

    * sensing: ``MARGIN_SIGMAS`` sigma of the peer's position error the tracker leaves
      (:func:`runtime.decision.estimator.steady_sigma`; the filter always works from the
      tracker under imperfect sensing, :class:`runtime.decision.local.Perception`);
    * latency: the tracker carries a late view forward at the peer's velocity, so what is
      left is a change of velocity over the latency, taken as a quarter of full speed per
      late step;
    * wheels: the gain spread and the actuation noise over one step, and a differential
      drive base's sideways error (the command's part it cannot drive this step, at most
      a step at full speed times ``sin(turn rate dt)``).
    Loss adds nothing here: a lost update makes a view late, and the estimator's sigma
    grows with it (the fixed margin covers the stated conditions; see the table in
    ``benchmarks/conditions.py`` for where it stops holding).
    """
    return MARGIN_SHARE * uncertainty_bound(conditions, world)


def uncertainty_bound(conditions: Conditions, world: WorldConfig = DEFAULT_WORLD,
                      sensing_m: float | None = None) -> float:
    """The whole per-robot bound (m) of :func:`uncertainty_margin`, which keeps a share of it
    for ORCA. ``sensing_m``: the sensing term, ``sigmas x sigma`` of a peer's position
    error (default ``MARGIN_SIGMAS`` of the tracker's steady error)."""
    reach = world.v_max_mps * world.dt_s
    if sensing_m is None:
        sensing_m = MARGIN_SIGMAS * steady_sigma(conditions.noise_m)
    late = _late_m(conditions, world)
    wheels = (conditions.gain_noise * reach + MARGIN_SIGMAS * conditions.act_noise_mps
              * world.dt_s)
    if conditions.kinematics == "diff":
        wheels += reach * math.sin(min(conditions.turn_rate_rps * world.dt_s, math.pi / 2))
    return 0.5 * (sensing_m * math.sqrt(2.0) + late) + wheels


def guard_bound(conditions: Conditions, world: WorldConfig = DEFAULT_WORLD) -> float:
    """The last-resort guard's margin (m, per robot): the terms of :func:`uncertainty_bound`
    for views as sensed, ``GUARD_SIGMAS`` of the raw noise (the guard reads the raw views,
    see :meth:`runtime.decision.local.Perception.perceive`), and the wheels' actuation noise,
    two independent Gaussian errors whose bounds add in quadrature: the pair's approach is
    off by the mean of the two robots' view errors plus each one's actuation error (at 5 cm
    of noise and 2 cm/s of actuation noise 0.053 m per robot, where their sum was 0.057 m).
    Latency is not in it: the guard pairs each view with the robot's own pose of its age, so a
    late view needs no margin of its own (a lost one, older than the latency, counts per peer
    the way its peer may have come unseen since:
    :meth:`runtime.decision.local.Perception.perceive`). It did keep the bound's latency term as
    slack while a pair already inside the guard kept only the approach its late view had let it
    make: the charging adversary of ``benchmarks/conditions.py`` (n = 10, 100 episodes) collided
    3.98 times per episode on views 3 steps late without it. Since such a robot gives that
    approach back (:meth:`runtime.core.orca.OrcaFilter.robot`), none does without the slack, and
    `rule:frame-balanced` + the tracker took 1.115x -> 1.101x the steps lower bound. A
    differential drive's sideways error is not in it: the guard bounds what the wheels will
    drive along the heading (:meth:`runtime.core.orca.OrcaFilter.guard_scale`); nor is the
    wheels' gain spread, which bounds the command instead (``OrcaParams.guard_gain``)."""
    sensing = 0.5 * GUARD_SIGMAS * conditions.noise_m * math.sqrt(2.0)
    acting = MARGIN_SIGMAS * conditions.act_noise_mps * world.dt_s
    return math.hypot(sensing, acting)


def _late_m(conditions: Conditions, world: WorldConfig) -> float:
    """The latency's term of the bounds (m, for the pair): a quarter of a full step per
    step of latency (see :func:`uncertainty_margin`)."""
    return conditions.latency_steps * world.v_max_mps * world.dt_s * 0.25


MARGIN_SIGMAS = 2.0
"""Sensing and actuation errors are bounded to this many standard deviations."""
GUARD_SIGMAS = 1.5
"""The guard's margin in sigmas of the raw sensing noise. A pair closes by at most the room
its two robots see, each view off by N(0, sigma) along the line: the pair's room is then
off by sigma / sqrt(2), and the guard's ``2 (radius margin + guard margin)`` of slack is
about 4 of those at 5 cm of noise. Measured (``benchmarks/conditions.py``, n = 10, 4
episodes of each shape, the charging adversary): 1, 1.5 and 2 sigmas all kept 5 cm noise
and the realistic preset at 0 collisions; 2 took `rule:frame-balanced` + the estimator
from 1.39x to 1.85x the steps lower bound on the realistic preset, 1.5 to 1.49x."""
MARGIN_SHARE = 0.3
"""The share of that bound kept as margin. The filter works from the tracker's estimates,
which removes most of the error already, and a wide margin makes crowds infeasible for
ORCA's linear programs: on circle, n = 10, 4 episodes each of 5 cm noise with 2 steps of
latency (and with 30 % loss, and with wheel noise), collisions of `rule:assign` /
`rule:frame-balanced` were 7+8+6 / 0 with no widening, 0+16+14 / 0 at 0.3, 14+80+44 / 4
at 0.6 and 49+150+176 / 4 at 1 (``uncertainty_margin_m``, kept only where there is room)."""


GUARD_SHARE_EVEN = 0.02
"""The approach speed (a share of full speed) under which two robots of a pair split the
guard's room about evenly (:func:`guard_shares`)."""


def guard_shares(own_step: npt.ArrayLike, peer_step: npt.ArrayLike, toward: npt.ArrayLike,
                 world: WorldConfig = DEFAULT_WORLD) -> npt.NDArray[np.float64]:
    """A robot's share of the guard's room in each pair (...,) from the pair as it was last
    seen: ``toward`` (..., 2) m from the robot to the peer, ``own_step`` and ``peer_step``
    (..., 2) m the last step each had taken then. Each robot's approach speed along the
    line, ``a`` (the peer's ``a'``), gives ``(a + c) / (a + a' + 2 c)``, ``c`` =
    :data:`GUARD_SHARE_EVEN` of a full step; the peer, computing from the same numbers, takes
    the rest. 0.5 where the pair has no direction or a number is not finite."""
    d = np.asarray(toward, dtype=np.float64)
    dist = np.hypot(d[..., 0], d[..., 1])
    ok = np.isfinite(dist) & (dist > 1e-12)
    u = d / np.where(ok, dist, 1.0)[..., None]
    mine = np.maximum(0.0, (np.asarray(own_step, dtype=np.float64) * u).sum(axis=-1))
    theirs = np.maximum(0.0, -(np.asarray(peer_step, dtype=np.float64) * u).sum(axis=-1))
    c = GUARD_SHARE_EVEN * world.v_max_mps * world.dt_s
    with np.errstate(invalid="ignore"):
        share = (mine + c) / (mine + theirs + 2.0 * c)
    out: npt.NDArray[np.float64] = np.where(ok & np.isfinite(share), share, 0.5)
    return out


SAFETY_MODES: Final = ("orca", "off", "orca-no-guard")
"""What ``eval --safety`` and ``benchmarks/conditions.py --safety`` may run: the robot's filter,
the raw brain, or ORCA without its last-resort guard (for measuring what the guard costs)."""


def safety_params(mode: str, params: OrcaParams = OrcaParams()) -> OrcaParams | None:
    """The filter a mode of :data:`SAFETY_MODES` runs, from ``params`` (None: the raw brain)."""
    if mode not in SAFETY_MODES:
        raise ValueError(f"safety mode must be one of {', '.join(SAFETY_MODES)}, got {mode!r}")
    if mode == "off":
        return None
    return params if mode == "orca" else replace(params, guard=False)


def safety_mode(params: OrcaParams | None) -> str:
    """The mode of :data:`SAFETY_MODES` that ``params`` run (the inverse of
    :func:`safety_params`)."""
    return "off" if params is None else "orca" if params.guard else "orca-no-guard"


def uncertainty_params(params: OrcaParams, conditions: Conditions,
                       world: WorldConfig = DEFAULT_WORLD) -> OrcaParams:
    """``params`` with :func:`uncertainty_margin` as their ``uncertainty_margin_m`` and
    :func:`guard_bound` as their guard (none where ``params.guard`` is False; the same params
    under perfect conditions)."""
    if conditions == PERFECT:
        return params
    return replace(params, uncertainty_margin_m=uncertainty_margin(conditions, world),
                   guard_margin_m=guard_bound(conditions, world) if params.guard else -1.0,
                   guard_gain=conditions.gain_noise)


def guard_distance(params: OrcaParams | None, world: WorldConfig = DEFAULT_WORLD) -> float:
    """The distance between centres (m), as a robot sees them, inside which the last-resort
    guard lets a pair come no closer (:attr:`OrcaParams.guard_margin_m`; 0: no guard)."""
    if params is None or not params.guard_margin_m >= 0.0:
        return 0.0
    return 2.0 * (world.radius_m + params.radius_margin_m + params.guard_margin_m)


def guard_note(guard_m: float, spacing_m: float) -> str | None:
    """One line for a pattern whose closest pair (``spacing_m``) lies inside the guard's
    distance ``guard_m`` (:func:`guard_distance`), None where it does not: two robots landing
    next to each other there may come no closer, as they see each other, and only the noise
    lets them reach their slots. Under the ``harsh`` preset (0.45 m against the built-in
    patterns' 0.40 m; ``benchmarks/conditions.py --cases harsh``, n = 10, 100 episodes,
    `rule:frame-balanced` + the tracker) the team formed 88 % of episodes at 5.1x the steps
    lower bound; with its shapes spaced 0.55 m (``--spacing``) 100 % at 2.6x."""
    if not (guard_m > spacing_m):  # NaN: nothing to say
        return None
    return (f"the pattern's closest pair is {spacing_m:.2f} m apart, inside the {guard_m:.2f} m "
            f"the safety guard keeps between robots under these conditions: neighbours reach "
            f"their slots only where the noise lets them (space it {guard_m:.2f} m or more)")


def pattern_guard_note(points: npt.ArrayLike | None, conditions: Conditions,
                       params: OrcaParams | None = OrcaParams(),
                       world: WorldConfig = DEFAULT_WORLD) -> str | None:
    """:func:`guard_note` for a pattern's ``points`` (None: the built-ins' spacing, as the
    random shapes have it) under ``conditions``, with the filter ``params`` (None: off)."""
    if params is None:
        return None
    spacing = world.pattern_spacing_m if points is None else min_spacing(
        np.asarray(points, dtype=np.float64))
    return guard_note(guard_distance(uncertainty_params(params, conditions, world), world),
                      spacing)


def make_filter(params: OrcaParams | None, world: WorldConfig = DEFAULT_WORLD) -> OrcaFilter:
    """The filter these settings describe, with its own scratch (one per robot or batch).
    ``params`` None: no filter, only the speed clamp (no neighbour is ever considered)."""
    p = OrcaParams(max_neighbours=0) if params is None else params
    hard = 2.0 * (world.radius_m + p.radius_margin_m)
    combined = hard + 2.0 * p.uncertainty_margin_m
    guard = guard_distance(p, world)
    return OrcaFilter(p.max_neighbours, p.neighbour_dist_m, combined, world.dt_s,
                      p.keep_right_rad, world.v_max_mps, hard, guard, p.guard_gain)


@dataclass
class FilterResult:
    """Outcome of :func:`orca_filter` for one robot."""

    velocity: tuple[float, float]
    """The safe velocity (m/s), norm <= v_max."""
    changed: bool
    """True if ``velocity`` differs from the preferred velocity by > 1e-9 m/s
    (or the preferred velocity was not finite)."""
    change_mps: float
    """Norm of (safe - preferred), preferred taken as 0 where not finite."""


def orca_filter(
    pref_vel: Vec2,
    own_vel: Vec2,
    rel_pos: Vec2s,
    nb_vel: Vec2s,
    *,
    world: WorldConfig = DEFAULT_WORLD,
    params: OrcaParams = OrcaParams(),  # frozen dataclass: a safe default
) -> FilterResult:
    """The ORCA-safe velocity closest to one robot's preferred velocity, from its own view.

    Args:
        pref_vel: the brain's desired velocity (vx, vy), m/s. NaN/inf -> zero.
        own_vel: the robot's current velocity (vx, vy), m/s, as its neighbours
            see it (e.g. last executed command or frame difference / dt).
            NaN/inf -> zero.
        rel_pos: shape (k, 2), m: neighbours' positions minus own position.
            k may be 0. Rows farther than ``params.neighbour_dist_m`` or not
            finite are ignored; of the rest the nearest
            ``params.max_neighbours`` are used.
        nb_vel: shape (k, 2), m/s: neighbours' absolute velocities, row for
            row with ``rel_pos`` (NaN/inf rows -> zero).
        world: the world's constants (R, v_max, dt).
        params: ORCA tuning.

    Returns:
        A :class:`FilterResult`; its velocity has norm <= ``world.v_max_mps``.
    """
    px, py = float(pref_vel[0]), float(pref_vel[1])
    pref_ok = math.isfinite(px) and math.isfinite(py)
    if not pref_ok:
        px = py = 0.0
    rel = np.asarray(rel_pos, dtype=np.float64).reshape(-1, 2)
    pos = np.zeros((1, len(rel) + 1, 2))
    pos[0, 1:] = rel
    vel = np.zeros_like(pos)
    vel[0, 0] = np.asarray(own_vel, dtype=np.float64).reshape(2)
    vel[0, 1:] = np.asarray(nb_vel, dtype=np.float64).reshape(-1, 2)
    vx, vy, _, _ = make_filter(params, world).robot(0, 0, pos, vel, px, py, params.time_horizon_s)
    # from the preference as given, not as clamped (a finite figure even for the largest)
    change = min(math.hypot(vx - px, vy - py), sys.float_info.max)
    return FilterResult(velocity=(vx, vy), changed=(not pref_ok) or change > CHANGE_TOL_MPS,
                        change_mps=change)
