"""ORCA safety filter: the last word between a brain and its robot's motors.

Every step, each robot replaces its brain's *preferred* velocity by the velocity
closest to it that ORCA (optimal reciprocal collision avoidance, van den Berg,
Guy, Lin and Manocha, 2011) deems collision-free with respect to its
neighbours. The algorithm is a line-for-line port of RVO2's
``Agent::computeNewVelocity`` (agent-agent part) with its three linear programs
``linearProgram1/2/3``, in plain Python floats: at k <= 10 neighbours that is
several times faster than numpy, whose per-call overhead dominates.

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
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "FilterResult",
    "OrcaParams",
    "landing",
    "nearest_in_range",
    "orca_filter",
    "orca_filter_batch",
    "orca_velocity",
]

_EPS = 1e-5  # RVO_EPSILON: parallel-line test in the linear programs
_CHANGE_TOL_MPS = 1e-9  # |safe - preferred| above which a velocity counts as changed

Vec2 = tuple[float, float] | Sequence[float] | npt.NDArray[np.floating]
Rows = Sequence[Sequence[float]] | npt.NDArray[np.floating]
# An ORCA line: point (px, py) on it and unit direction (dx, dy); the allowed
# half-plane lies to the left of the direction.
_Line = tuple[float, float, float, float]
# A neighbour the filter considers: squared distance (m^2), position relative to
# the robot (m), and its index among the robot's neighbours.
_Near = tuple[float, float, float, int]


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
    landing: bool = True
    """For a team on a synchronised plan (plan brains, frame rules), the horizon is
    at most the plan's time left, ``K dt`` (see "Landing" in the module docstring
    and :func:`landing`)."""


@functools.lru_cache(maxsize=64)
def _with_horizon(params: OrcaParams, horizon_s: float) -> OrcaParams:
    return replace(params, time_horizon_s=horizon_s)


def landing(params: OrcaParams | None, steps_left: float | None,
            world: WorldConfig = DEFAULT_WORLD) -> OrcaParams | None:
    """The filter's parameters for a team whose plan has ``steps_left`` (K) steps to go.

    With ``params.landing`` the horizon is ``min(time_horizon_s, max(K, 1) dt)``:
    every robot of the team computes the same K from the same poses, and after
    K steps all of them rest on their slots. ``steps_left`` None (a brain
    without a plan) or ``params`` None leave ``params`` as they are.
    """
    if params is None or steps_left is None or not params.landing:
        return params
    horizon = max(float(steps_left), 1.0) * world.dt_s
    if not horizon < params.time_horizon_s:
        return params
    return _with_horizon(params, horizon)


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


# --------------------------------------------------------------------------
# Linear programs (RVO2 linearProgram1/2/3), on lists of float tuples.
# --------------------------------------------------------------------------


def clamp_speed(vx: float, vy: float, v_max: float) -> tuple[float, float]:
    """(vx, vy) scaled down to norm <= v_max (exactly, both ways of taking the norm)."""
    sp = math.hypot(vx, vy)
    if sp > v_max:
        s = v_max / sp
        vx, vy = vx * s, vy * s
        while max(math.hypot(vx, vy), math.sqrt(vx * vx + vy * vy)) > v_max:
            vx, vy = vx * (1.0 - 1e-15), vy * (1.0 - 1e-15)
    return vx, vy


def _lp1(
    lines: list[_Line],
    line_no: int,
    radius: float,
    opt_x: float,
    opt_y: float,
    direction_opt: bool,
) -> tuple[float, float] | None:
    """Best point on line ``line_no`` within the circle and lines before it."""
    px, py, dx, dy = lines[line_no]
    dot = px * dx + py * dy
    discriminant = dot * dot + radius * radius - (px * px + py * py)
    if discriminant < 0.0:
        return None  # the max-speed circle misses this line entirely
    sqrt_disc = math.sqrt(discriminant)
    t_left = -dot - sqrt_disc
    t_right = -dot + sqrt_disc
    for i in range(line_no):
        qx, qy, ex, ey = lines[i]
        denominator = dx * ey - dy * ex
        numerator = ex * (py - qy) - ey * (px - qx)
        if abs(denominator) <= _EPS:
            if numerator < 0.0:
                return None  # parallel and on the wrong side
            continue
        t = numerator / denominator
        if denominator >= 0.0:
            if t < t_right:
                t_right = t
        elif t > t_left:
            t_left = t
        if t_left > t_right:
            return None
    if direction_opt:
        t = t_right if opt_x * dx + opt_y * dy > 0.0 else t_left
    else:
        t = dx * (opt_x - px) + dy * (opt_y - py)
        if t < t_left:
            t = t_left
        elif t > t_right:
            t = t_right
    return px + t * dx, py + t * dy


def _lp2(
    lines: list[_Line],
    radius: float,
    opt_x: float,
    opt_y: float,
    direction_opt: bool,
) -> tuple[int, float, float]:
    """Closest point to the optimum satisfying all lines; (failed line, x, y).

    The failed-line index equals ``len(lines)`` on success.
    """
    if direction_opt:
        rx, ry = opt_x * radius, opt_y * radius
    else:
        n2 = opt_x * opt_x + opt_y * opt_y
        if n2 > radius * radius:
            s = radius / math.sqrt(n2)
            rx, ry = opt_x * s, opt_y * s
        else:
            rx, ry = opt_x, opt_y
    for i, (px, py, dx, dy) in enumerate(lines):
        if dx * (py - ry) - dy * (px - rx) > 0.0:
            found = _lp1(lines, i, radius, opt_x, opt_y, direction_opt)
            if found is None:
                return i, rx, ry
            rx, ry = found
    return len(lines), rx, ry


def _lp3(
    lines: list[_Line], begin_line: int, radius: float, rx: float, ry: float
) -> tuple[float, float]:
    """Infeasible case: minimise the largest violation (no obstacle lines)."""
    distance = 0.0
    for i in range(begin_line, len(lines)):
        px, py, dx, dy = lines[i]
        if dx * (py - ry) - dy * (px - rx) > distance:
            proj: list[_Line] = []
            for j in range(i):
                qx, qy, ex, ey = lines[j]
                determinant = dx * ey - dy * ex
                if abs(determinant) <= _EPS:
                    if dx * ex + dy * ey > 0.0:
                        continue  # same direction: line j is implied
                    lx, ly = 0.5 * (px + qx), 0.5 * (py + qy)
                else:
                    t = (ex * (py - qy) - ey * (px - qx)) / determinant
                    lx, ly = px + t * dx, py + t * dy
                ux, uy = ex - dx, ey - dy
                un = math.sqrt(ux * ux + uy * uy)
                proj.append((lx, ly, ux / un, uy / un))
            fail, nx, ny = _lp2(proj, radius, -dy, dx, True)
            if fail >= len(proj):
                rx, ry = nx, ny
            # else: keep the previous result (numerical failure, as RVO2 does)
            distance = dx * (py - ry) - dy * (px - rx)
    return rx, ry


# --------------------------------------------------------------------------
# ORCA lines and the filter
# --------------------------------------------------------------------------


def _finite2(v: Vec2) -> tuple[float, float, bool]:
    """(x, y, was_finite); non-finite vectors become zero."""
    x, y = float(v[0]), float(v[1])
    if math.isfinite(x) and math.isfinite(y):
        return x, y, True
    return 0.0, 0.0, False


def _as_rows(a: Rows) -> list[list[float]]:
    if isinstance(a, np.ndarray):
        rows: list[list[float]] = (a if a.ndim == 2 else a.reshape(-1, 2)).tolist()
        return rows
    return [[float(r[0]), float(r[1])] for r in a]


def nearest_in_range(rel_pos: list[list[float]], params: OrcaParams) -> list[_Near]:
    """The neighbours the filter considers: (d^2, dx, dy, index) of the nearest
    ``max_neighbours`` rows of ``rel_pos`` closer than ``neighbour_dist_m``, nearest
    first (ties by dx, dy, then index)."""
    range_sq = params.neighbour_dist_m * params.neighbour_dist_m
    near: list[_Near] = []
    for idx, (rpx, rpy) in enumerate(rel_pos):
        d2 = rpx * rpx + rpy * rpy
        if d2 < range_sq:  # False for NaN
            near.append((d2, rpx, rpy, idx))
    near.sort()
    del near[params.max_neighbours :]
    return near


def _orca_lines(
    vx: float,
    vy: float,
    near: list[_Near],
    nb_vel: Sequence[Sequence[float]],
    world: WorldConfig,
    params: OrcaParams,
) -> list[_Line]:
    """ORCA half-planes for the neighbours ``near`` (:func:`nearest_in_range`), in
    their order; ``nb_vel[k]`` is the absolute velocity of ``near[k]``."""
    combined = 2.0 * (world.radius_m + params.radius_margin_m)
    combined_sq = combined * combined
    inv_tau = 1.0 / params.time_horizon_s
    inv_dt = 1.0 / world.dt_s
    lines: list[_Line] = []
    for (dist_sq, rpx, rpy, _), (nvx, nvy) in zip(near, nb_vel, strict=True):
        if not (math.isfinite(nvx) and math.isfinite(nvy)):
            nvx = nvy = 0.0
        rvx, rvy = vx - nvx, vy - nvy  # own velocity relative to the neighbour
        if dist_sq > combined_sq:
            # No collision yet: velocity obstacle truncated at time_horizon.
            wx, wy = rvx - inv_tau * rpx, rvy - inv_tau * rpy
            w_len_sq = wx * wx + wy * wy
            dot1 = wx * rpx + wy * rpy
            if dot1 < 0.0 and dot1 * dot1 > combined_sq * w_len_sq:
                # Project on the cut-off circle.
                w_len = math.sqrt(w_len_sq)
                ux_, uy_ = wx / w_len, wy / w_len
                dx, dy = uy_, -ux_
                s = combined * inv_tau - w_len
                ux, uy = s * ux_, s * uy_
            else:
                # Project on a leg of the cone.
                leg = math.sqrt(dist_sq - combined_sq)
                if rpx * wy - rpy * wx > 0.0:  # left leg
                    dx = (rpx * leg - rpy * combined) / dist_sq
                    dy = (rpx * combined + rpy * leg) / dist_sq
                else:  # right leg
                    dx = -(rpx * leg + rpy * combined) / dist_sq
                    dy = -(-rpx * combined + rpy * leg) / dist_sq
                dot2 = rvx * dx + rvy * dy
                ux, uy = dot2 * dx - rvx, dot2 * dy - rvy
        else:
            # Already closer than the inflated radius: be apart again after one
            # time step dt (project on the cut-off circle at time step).
            wx, wy = rvx - inv_dt * rpx, rvy - inv_dt * rpy
            w_len = math.sqrt(wx * wx + wy * wy)
            if w_len > 1e-12:
                ux_, uy_ = wx / w_len, wy / w_len
            else:
                # Exactly where the separation target is: push straight away
                # from the neighbour (or, if coincident, an arbitrary axis).
                d = math.sqrt(dist_sq)
                ux_, uy_ = (-rpx / d, -rpy / d) if d > 1e-12 else (0.0, -1.0)
            dx, dy = uy_, -ux_
            s = combined * inv_dt - w_len
            ux, uy = s * ux_, s * uy_
        # Half the responsibility each.
        lines.append((vx + 0.5 * ux, vy + 0.5 * uy, dx, dy))
    return lines


def _lp(lines: list[_Line], radius: float, opt_x: float, opt_y: float) -> tuple[float, float]:
    """RVO2's solve: linear program 2, falling back on 3 when infeasible."""
    fail, rx, ry = _lp2(lines, radius, opt_x, opt_y, False)
    if fail < len(lines):
        rx, ry = _lp3(lines, fail, radius, rx, ry)
    return rx, ry


def _solve(
    pref_x: float,
    pref_y: float,
    vx: float,
    vy: float,
    near: list[_Near],
    nb_vel: Sequence[Sequence[float]],
    world: WorldConfig,
    params: OrcaParams,
) -> tuple[float, float]:
    """Safe velocity for finite inputs, norm <= v_max."""
    v_max = world.v_max_mps
    if not near:
        return clamp_speed(pref_x, pref_y, v_max)
    lines = _orca_lines(vx, vy, near, nb_vel, world, params)
    # Keep right: if the (speed-limited) preferred velocity violates a
    # constraint, steer the optimum slightly clockwise.
    n2 = pref_x * pref_x + pref_y * pref_y
    cx, cy = pref_x, pref_y
    if n2 > v_max * v_max:
        s = v_max / math.sqrt(n2)
        cx, cy = cx * s, cy * s
    if params.keep_right_rad != 0.0:
        for px, py, dx, dy in lines:
            if dx * (py - cy) - dy * (px - cx) > 0.0:
                c, s = math.cos(params.keep_right_rad), math.sin(params.keep_right_rad)
                pref_x, pref_y = c * pref_x + s * pref_y, -s * pref_x + c * pref_y
                break
    rx, ry = _lp(lines, v_max, pref_x, pref_y)
    # The LP stays in the max-speed circle up to rounding; make it exact.
    return clamp_speed(rx, ry, v_max)


def orca_velocity(
    pref_x: float,
    pref_y: float,
    own_x: float,
    own_y: float,
    near: list[_Near],
    nb_vel: Sequence[Sequence[float]],
    world: WorldConfig = DEFAULT_WORLD,
    params: OrcaParams = OrcaParams(),  # frozen dataclass: a safe default
) -> tuple[float, float, bool, float]:
    """:func:`orca_filter` for finite velocities and neighbours already chosen: the
    robot's path, with nothing converted or allocated beyond the lines.

    ``near``: what :func:`nearest_in_range` gives for the robot's neighbours (or
    the same list built another way); ``nb_vel[k]``: ``near[k]``'s absolute
    velocity (m/s). Returns (vx, vy, changed, change_mps) as
    :class:`FilterResult`'s fields.
    """
    rx, ry = _solve(pref_x, pref_y, own_x, own_y, near, nb_vel, world, params)
    change = math.hypot(rx - pref_x, ry - pref_y)
    return rx, ry, change > _CHANGE_TOL_MPS, change


def orca_filter(
    pref_vel: Vec2,
    own_vel: Vec2,
    rel_pos: Rows,
    nb_vel: Rows,
    *,
    world: WorldConfig = DEFAULT_WORLD,
    params: OrcaParams = OrcaParams(),  # frozen dataclass: a safe default
) -> FilterResult:
    """The ORCA-safe velocity closest to a robot's preferred velocity.

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
    px, py, pref_ok = _finite2(pref_vel)
    vx, vy, _ = _finite2(own_vel)
    near = nearest_in_range(_as_rows(rel_pos), params)
    vel = _as_rows(nb_vel)
    rx, ry = _solve(px, py, vx, vy, near, [vel[k[3]] for k in near], world, params)
    change = math.hypot(rx - px, ry - py)
    return FilterResult(
        velocity=(rx, ry),
        changed=(not pref_ok) or change > _CHANGE_TOL_MPS,
        change_mps=change,
    )


def orca_filter_batch(
    pref_vel: npt.ArrayLike,
    own_vel: npt.ArrayLike,
    rel_pos: npt.ArrayLike,
    nb_vel: npt.ArrayLike,
    mask: npt.ArrayLike,
    *,
    world: WorldConfig = DEFAULT_WORLD,
    params: OrcaParams = OrcaParams(),  # frozen dataclass: a safe default
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """:func:`orca_filter` for m robots at once.

    Args:
        pref_vel: shape (m, 2), m/s: preferred velocities.
        own_vel: shape (m, 2), m/s: the robots' current velocities.
        rel_pos: shape (m, k, 2), m: robot i's neighbour j minus robot i.
        nb_vel: shape (m, k, 2), m/s: neighbours' absolute velocities.
        mask: shape (m, k), bool: which neighbour slots are valid.
        world, params: as for :func:`orca_filter`.

    Returns:
        (safe velocities of shape (m, 2) in m/s, changed flags of shape (m,)).
    """
    pref = np.asarray(pref_vel, dtype=np.float64).reshape(-1, 2)
    own = np.asarray(own_vel, dtype=np.float64).reshape(-1, 2)
    m = pref.shape[0]
    pos = np.asarray(rel_pos, dtype=np.float64).reshape(m, -1, 2)
    vel = np.asarray(nb_vel, dtype=np.float64).reshape(m, -1, 2)
    valid = np.asarray(mask, dtype=bool).reshape(m, -1)
    safe = np.zeros((m, 2), dtype=np.float64)
    changed = np.zeros(m, dtype=bool)
    pref_l: list[list[float]] = pref.tolist()
    own_l: list[list[float]] = own.tolist()
    for i in range(m):
        sel = valid[i]
        res = orca_filter(pref_l[i], own_l[i], pos[i][sel], vel[i][sel], world=world, params=params)
        safe[i] = res.velocity
        changed[i] = res.changed
    return safe, changed

