# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The ORCA safety filter, with its neighbour choice and its last-resort guard: written once.

ORCA (van den Berg et al., "Reciprocal n-body collision avoidance", 2011; RVO2's
``Agent::computeNewVelocity``, agent-agent part): each of the robot's nearest
neighbours in range gives one half-plane of velocities that keeps the pair apart for
the time horizon, each robot taking half the responsibility; a 2-d linear program
picks the velocity closest to the preferred one within v_max, and when the
half-planes leave no room, the one that violates them least (:mod:`runtime.core.orca_lp`,
with the speed clamp). A new constraint (a margin for an uncertain view, a wheel's
limits, an obstacle) is a new loop in :meth:`OrcaFilter.robot`, here and nowhere else.

:class:`OrcaFilter` holds the filter's settings and its scratch; :meth:`OrcaFilter.robot`
filters one robot's velocity (the robot's own step), :meth:`OrcaFilter.teams` every
robot of E teams (``eval``, the training world), calling the same code. The tuning
and its reasons live in :mod:`runtime.decision.safety` (``OrcaParams``).

Plain Python in Cython's pure-Python mode (see :mod:`runtime.core`). Units: m, s, m/s.
"""

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.libc.math import cos, hypot, isfinite, sin, sqrt
    from cython.cimports.runtime.core.neighbours import nearest
    from cython.cimports.runtime.core.orca_lp import LinearProgram, clamp
else:
    from math import cos, hypot, isfinite, sin, sqrt

    from runtime.core.neighbours import nearest
    from runtime.core.orca_lp import LinearProgram, clamp

__all__ = ["CHANGE_TOL_MPS", "GUARD_REF_COLUMNS", "MAX_NEIGHBOURS", "OrcaFilter"]

CHANGE_TOL_MPS = 1e-9
"""A filtered velocity this close to the preferred one counts as unchanged (m/s)."""
_CHANGE_TOL = cython.declare(cython.double, 1e-9)  # the same, as a C constant
MAX_NEIGHBOURS = 64
"""The most neighbours the filter considers (``OrcaParams.max_neighbours``)."""
GUARD_REF_COLUMNS = 6
"""The numbers per peer of the guard's references (``guard_ref`` of :meth:`OrcaFilter.robot`)."""
GUARD_PASSES = 4
"""Rounds of projection on the guard's bounds before it scales what is left (see
:meth:`OrcaFilter.robot`)."""
_GUARD_PASSES = cython.declare(cython.Py_ssize_t, 4)  # the same, as a C constant
MARGIN_ROOM_M = 1e-3
"""Inside a pair's uncertainty margin, the margin shrinks to the distance less this (m)."""


@cython.cclass
class OrcaFilter:
    """The ORCA filter's settings and its scratch: one per robot (or per batch), not shared
    between threads."""

    max_neighbours: cython.Py_ssize_t
    range_sq: cython.double
    combined: cython.double
    hard: cython.double
    dt: cython.double
    keep_right: cython.double
    v_max: cython.double
    guard: cython.double
    guard_gain: cython.double
    _ids: cython.Py_ssize_t[:, :, ::1]
    _d2: cython.double[:, :, ::1]
    _count: cython.Py_ssize_t[:, ::1]
    _lp: LinearProgram
    _no_ref: cython.double[:, :, ::1]
    _bound: cython.double[:, ::1]

    def __init__(self, max_neighbours: int, neighbour_dist_m: float, combined_radius_m: float,
                 dt_s: float, keep_right_rad: float, v_max_mps: float,
                 hard_radius_m: float = -1.0, guard_m: float = 0.0,
                 guard_gain: float = 0.0) -> None:
        """``max_neighbours`` at most :data:`MAX_NEIGHBOURS` nearest, closer than
        ``neighbour_dist_m`` (m); ``combined_radius_m`` the pair's radius with its margin
        (m); ``dt_s`` the step (s); ``keep_right_rad`` the clockwise turn of a blocked
        preferred velocity (rad, 0: none); ``v_max_mps`` the speed limit (m/s);
        ``hard_radius_m`` (m, at most ``combined_radius_m``; negative: the same) the radius
        below which a pair is taken as colliding: between it and ``combined_radius_m`` (the
        margin for a robot's uncertainty) a pair keeps its distance rather than being
        pushed apart within one step; ``guard_m`` (m, 0: none) the distance between centres,
        as the robot sees them, that the last-resort guard keeps (see :meth:`robot`);
        ``guard_gain`` (>= 0) how much more than commanded the wheels may drive, as a share
        of the command: the guard's bounds on the command are its bounds on the motion
        divided by ``1 + guard_gain``."""
        if not 0 <= max_neighbours <= MAX_NEIGHBOURS:
            raise ValueError(f"ORCA considers 0 to {MAX_NEIGHBOURS} neighbours, "
                             f"not {max_neighbours}")
        self.max_neighbours = max_neighbours
        self.range_sq = neighbour_dist_m * neighbour_dist_m
        self.combined = combined_radius_m
        self.hard = combined_radius_m if hard_radius_m < 0 else min(hard_radius_m,
                                                                     combined_radius_m)
        self.dt = dt_s
        self.keep_right = keep_right_rad
        self.v_max = v_max_mps
        self.guard = guard_m if guard_m > 0.0 else 0.0
        self.guard_gain = guard_gain if guard_gain > 0.0 else 0.0
        k = max(max_neighbours, 1)
        self._ids = None  # the neighbour tables, made for the first batch's shape
        self._tables(1, 1)
        self._lp = LinearProgram(k)
        self._no_ref = np.zeros((0, 0, 0))
        self._bound = np.zeros((3 * k, 4))  # each neighbour: its direction and the cone's edges

    def _tables(self, E: int, n: int) -> None:
        """The neighbour tables (E, n, max_neighbours), kept while E and n stay."""
        if self._ids is None or self._ids.shape[0] != E or self._ids.shape[1] != n:
            k = max(self.max_neighbours, 1)
            self._ids = np.zeros((E, n, k), dtype=np.intp)
            self._d2 = np.zeros((E, n, k))
            self._count = np.zeros((E, n), dtype=np.intp)

    @cython.ccall
    def robot(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t,
              pos: cython.const[cython.double][:, :, ::1],
              vel: cython.const[cython.double][:, :, ::1],
              pref_x: cython.double, pref_y: cython.double, horizon_s: cython.double,
              guard_ref: cython.const[cython.double][:, :, ::1] = None
              ) -> tuple[cython.double, cython.double, cython.bint, cython.double]:
        """Robot i of team e: its safe velocity (vx, vy, changed, change_mps).

        ``pos`` (E, n, 2) the teams' positions as robot i sees them (m; a robot passes its
        one team as E = 1), ``vel`` (E, n, 2) their
        velocities (m/s; a non-finite one counts as zero); (pref_x, pref_y) the preferred
        velocity (m/s, finite), first clamped to v_max; ``horizon_s`` ORCA's time horizon
        (s). The result has norm <= v_max; ``changed`` says it differs from the clamped
        preferred velocity by more than :data:`CHANGE_TOL_MPS`, ``change_mps`` by how much.

        The last-resort guard (``guard_m`` > 0) then bounds the robot's approach to each
        peer: with ``guard_ref``, every peer of the team whose bound can bind, as sensed,
        whatever ``pos`` (the estimates ORCA plans from) says of it (an estimate that
        misplaces a near peer, out of ORCA's nearest or its range, left it unguarded);
        without, ORCA's neighbours. ORCA's guarantee rests on both robots predicting each
        other's velocity alike, which noisy and late views break; the guard needs only
        distances. From the pair as this robot last saw it (``guard_ref`` (E, n, 6): the
        peer's sensed position, this robot's own pose at that step, the way the peer may
        have come since, unseen, and this robot's share of the room, 0.5 for half) at
        distance ``D`` along ``u``, the robot keeps its own approach along ``u`` since then,
        this step included, within its share of the room, ``share (D - guard_m)``: two
        robots that both obey, from views of the same age and shares that sum to 1 (both
        half, or :func:`runtime.decision.safety.guard_shares`), end the step at least
        ``guard_m`` apart along ``u``, whatever either did meanwhile, unseen (latency needs
        no margin). A share outside [0, 1] is clipped to it, one not finite is half. A pair
        already inside keeps its distance: a robot with no room left gives back what it has
        closed since, which its late view let it take (a bound below zero: a retreat), and
        both robots then end the step no closer than they were seen. The bound holds along
        ``u`` and along the two edges of the cone the peer may lie in,
        ``asin((guard_m - 2R') / D)``, for the error of a noisy view. Where the peer's
        last update was lost, the two robots' views differ in age: this robot pairs the
        peer's last view with its own pose of the freshest age a view can have (the
        latency's), the moment its peer's bound counts from, and the peer may lie
        ``guard_ref[..., 4]`` (m; 0: seen on time) off its view, the way it may have come
        unseen in between: the room shrinks by it and the cone widens by it,
        ``asin((guard_m - 2R' + unseen) / D)``.
        Without ``guard_ref`` the pair is taken as it is in ``pos``. The guard projects the
        velocity on each bound in turn (:data:`GUARD_PASSES` rounds) and clamps it to v_max;
        where the rounds do not settle (retreats from two sides at once), it scales the
        velocity down until every bound holds with its retreats taken as zero (zero always
        does).
        """
        if not (0 <= e < pos.shape[0] and 0 <= i < pos.shape[1]) \
                or vel.shape[0] != pos.shape[0] or vel.shape[1] != pos.shape[1]:
            raise ValueError("ORCA: robot index or velocities do not fit the positions")
        nearest(pos, e, e + 1, i, i + 1, self.max_neighbours, self.range_sq, self._ids,
                self._d2, self._count)
        if guard_ref is None:
            return self._safe(e, i, 0, 0, pos, vel, pref_x, pref_y, horizon_s, self._no_ref)
        if guard_ref.shape[0] != pos.shape[0] or guard_ref.shape[1] != pos.shape[1] \
                or guard_ref.shape[2] != GUARD_REF_COLUMNS:
            raise ValueError("ORCA: the guard's references do not fit the positions")
        self._bound_rows(pos.shape[1])
        return self._safe(e, i, 0, 0, pos, vel, pref_x, pref_y, horizon_s, guard_ref)

    def _bound_rows(self, n: cython.Py_ssize_t) -> None:
        """Room in ``_bound`` for the guard's bounds of every peer of a team of ``n``."""
        if self._bound.shape[0] < 3 * n:
            self._bound = np.zeros((3 * n, 4))

    @cython.cfunc
    def _safe(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t, a: cython.Py_ssize_t,
              b: cython.Py_ssize_t, pos: cython.const[cython.double][:, :, ::1],
              vel: cython.const[cython.double][:, :, ::1],
              pref_x: cython.double, pref_y: cython.double, horizon_s: cython.double,
              guard_ref: cython.const[cython.double][:, :, ::1]
              ) -> tuple[cython.double, cython.double, cython.bint, cython.double]:
        """Robot i of team e, its neighbours at [a, b] of the tables: :meth:`robot`."""
        pref_x, pref_y = clamp(pref_x, pref_y, self.v_max)
        m: cython.Py_ssize_t = self._count[a, b]
        lines = self._lp.lines
        out = self._lp.out
        c: cython.Py_ssize_t
        j: cython.Py_ssize_t
        ox: cython.double = vel[e, i, 0]
        oy: cython.double = vel[e, i, 1]
        combined: cython.double = self.combined
        combined_sq: cython.double = combined * combined
        hard: cython.double = self.hard
        r: cython.double
        r_sq: cython.double
        inv_tau: cython.double = 1.0 / horizon_s
        inv_dt: cython.double = 1.0 / self.dt
        v_max: cython.double = self.v_max
        dist_sq: cython.double
        rpx: cython.double
        rpy: cython.double
        nvx: cython.double
        nvy: cython.double
        rvx: cython.double
        rvy: cython.double
        wx: cython.double
        wy: cython.double
        w_len: cython.double
        w_len_sq: cython.double
        dot: cython.double
        leg: cython.double
        d: cython.double
        dx: cython.double
        dy: cython.double
        ux: cython.double
        uy: cython.double
        s: cython.double
        rx: cython.double
        ry: cython.double
        cx: cython.double
        cy: cython.double
        optx: cython.double = pref_x
        opty: cython.double = pref_y
        if m == 0:
            rx = pref_x
            ry = pref_y
        else:
            if not (isfinite(ox) and isfinite(oy)):
                ox = oy = 0.0
            for c in range(m):
                j = self._ids[a, b, c]
                dist_sq = self._d2[a, b, c]
                rpx = pos[e, j, 0] - pos[e, i, 0]
                rpy = pos[e, j, 1] - pos[e, i, 1]
                nvx = vel[e, j, 0]
                nvy = vel[e, j, 1]
                if not (isfinite(nvx) and isfinite(nvy)):
                    nvx = nvy = 0.0
                rvx = ox - nvx  # own velocity relative to the neighbour
                rvy = oy - nvy
                r = combined
                r_sq = combined_sq
                if dist_sq <= combined_sq and hard < combined:
                    # inside the margin, not the hard radius: the margin shrinks to the room
                    # there is (keep this distance), never an escape within one step
                    r = sqrt(dist_sq) - MARGIN_ROOM_M
                    if r < hard:
                        r = hard
                    r_sq = r * r
                if dist_sq > r_sq:
                    # no collision yet: the velocity obstacle, cut off at the horizon
                    wx = rvx - inv_tau * rpx
                    wy = rvy - inv_tau * rpy
                    w_len_sq = wx * wx + wy * wy
                    dot = wx * rpx + wy * rpy
                    if dot < 0.0 and dot * dot > r_sq * w_len_sq:
                        w_len = sqrt(w_len_sq)  # project on the cut-off circle
                        dx = wy / w_len
                        dy = -(wx / w_len)
                        s = r * inv_tau - w_len
                        ux = s * (wx / w_len)
                        uy = s * (wy / w_len)
                    else:
                        leg = sqrt(dist_sq - r_sq)  # project on a leg of the cone
                        if rpx * wy - rpy * wx > 0.0:  # left leg
                            dx = (rpx * leg - rpy * r) / dist_sq
                            dy = (rpx * r + rpy * leg) / dist_sq
                        else:  # right leg
                            dx = -(rpx * leg + rpy * r) / dist_sq
                            dy = -(-rpx * r + rpy * leg) / dist_sq
                        dot = rvx * dx + rvy * dy
                        ux = dot * dx - rvx
                        uy = dot * dy - rvy
                else:
                    # already closer than the inflated radius: apart again after one step
                    wx = rvx - inv_dt * rpx
                    wy = rvy - inv_dt * rpy
                    w_len = sqrt(wx * wx + wy * wy)
                    if w_len > 1e-12:
                        cx = wx / w_len
                        cy = wy / w_len
                    else:  # exactly at the separation target: straight away from it
                        d = sqrt(dist_sq)
                        if d > 1e-12:
                            cx = -rpx / d
                            cy = -rpy / d
                        else:  # coincident: an arbitrary axis
                            cx = 0.0
                            cy = -1.0
                    dx = cy
                    dy = -cx
                    s = r * inv_dt - w_len
                    ux = s * cx
                    uy = s * cy
                lines[c, 0] = ox + 0.5 * ux  # half the responsibility each
                lines[c, 1] = oy + 0.5 * uy
                lines[c, 2] = dx
                lines[c, 3] = dy
            # keep right: a (speed-limited) preferred velocity that breaks a constraint
            # turns slightly clockwise, so that two robots head-on pass each other
            cx = pref_x
            cy = pref_y
            s = pref_x * pref_x + pref_y * pref_y
            if s > v_max * v_max:
                s = v_max / sqrt(s)
                cx = cx * s
                cy = cy * s
            if self.keep_right != 0.0:
                for c in range(m):
                    if lines[c, 2] * (lines[c, 1] - cy) - lines[c, 3] * (lines[c, 0] - cx) > 0.0:
                        cs: cython.double = cos(self.keep_right)
                        s = sin(self.keep_right)
                        optx = cs * pref_x + s * pref_y
                        opty = -s * pref_x + cs * pref_y
                        break
            self._lp.solve(m, v_max, optx, opty)
            rx, ry = clamp(out[0], out[1], v_max)  # the LP's rounding: exactly within v_max
            if self.guard > 0.0:
                rx, ry = self._guard(e, i, a, b, m, pos, guard_ref, rx, ry)
        s = hypot(rx - pref_x, ry - pref_y)
        return rx, ry, s > _CHANGE_TOL, s

    @cython.cfunc
    @cython.exceptval(check=False)
    def _bounds(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t, a: cython.Py_ssize_t,
                b: cython.Py_ssize_t, m: cython.Py_ssize_t,
                pos: cython.const[cython.double][:, :, ::1],
                ref: cython.const[cython.double][:, :, ::1]) -> cython.Py_ssize_t:
        """The guard's bounds into ``_bound`` (rows [wx, wy, cap, cap or 0]: the velocity's
        component along w at most cap, m/s, below zero for a retreat, and the same with a
        retreat taken as zero); how many. With references (``ref``), for every peer of team
        e whose bound can bind (a cap under v_max), whatever ``pos`` says of it: the
        references are the views as sensed, and a peer that an estimate misplaces is as near
        as its view says (see :meth:`robot`); without them, for the ``m`` neighbours at
        [a, b] (``pos`` is then the pair as it is)."""
        inv_dt: cython.double = 1.0 / self.dt
        g: cython.double = self.guard
        out = self._bound
        c: cython.Py_ssize_t
        j: cython.Py_ssize_t
        side: cython.Py_ssize_t
        k: cython.Py_ssize_t = 0
        d: cython.double
        ux: cython.double
        uy: cython.double
        sx: cython.double
        sy: cython.double
        cs: cython.double
        sn: cython.double
        cap: cython.double
        room: cython.double
        has_ref: cython.bint = ref.shape[0] > 0
        share: cython.double
        peers: cython.Py_ssize_t = pos.shape[1] if has_ref else m
        for c in range(peers):
            if has_ref:  # every peer, as sensed: not the estimates' nearest
                j = c
                if j == i:
                    continue
            else:
                j = self._ids[a, b, c]
            unseen = 0.0
            share = 0.5
            if has_ref:  # the pair as last seen, and where this robot stood then
                sx = ref[e, j, 2]
                sy = ref[e, j, 3]
                ux = ref[e, j, 0] - sx
                uy = ref[e, j, 1] - sy
                unseen = ref[e, j, 4]  # the way a peer whose update was lost may have come
                if not unseen > 0.0:
                    unseen = 0.0
                share = ref[e, j, 5]
                if not isfinite(share):
                    share = 0.5
                elif share < 0.0:
                    share = 0.0
                elif share > 1.0:
                    share = 1.0
            else:
                sx = pos[e, i, 0]
                sy = pos[e, i, 1]
                ux = pos[e, j, 0] - sx
                uy = pos[e, j, 1] - sy
            d = sqrt(ux * ux + uy * uy)
            if not (d > 1e-12 and isfinite(d) and isfinite(sx) and isfinite(sy)
                    and isfinite(unseen)):
                continue
            ux = ux / d
            uy = uy / d
            # its share of the room there was then (none for a pair already inside, which
            # keeps its distance), less what this robot has closed since: below zero where
            # it has closed more, in the steps its view was late, and must give that back
            room = share * (d - unseen - g)
            if not room > 0.0:
                room = 0.0
            cap = (room - ((pos[e, i, 0] - sx) * ux + (pos[e, i, 1] - sy) * uy)) * inv_dt
            if not isfinite(cap):
                cap = 0.0
            if cap > 0.0:
                cap = cap / (1.0 + self.guard_gain)  # what the wheels may add to the command
                if has_ref and cap >= self.v_max:
                    continue  # room for a full step along every edge: it cannot bind
            elif self.guard_gain < 1.0:
                cap = cap / (1.0 - self.guard_gain)  # or take from a retreat
            # the peer may lie off the seen direction by the error the guard allows for
            # (g - hard) and the way it may have come: the seen direction, then both edges
            # of that cone
            sn = (g - self.hard + unseen) / d
            if sn > 1.0:
                sn = 1.0
            cs = sqrt(1.0 - sn * sn)
            for side in range(3):
                if side == 0:
                    out[k, 0] = ux
                    out[k, 1] = uy
                else:
                    out[k, 0] = cs * ux - sn * uy
                    out[k, 1] = sn * ux + cs * uy
                    sn = -sn
                out[k, 2] = cap
                out[k, 3] = cap if cap > 0.0 else 0.0
                k += 1
        return k

    @cython.cfunc
    @cython.exceptval(check=False)
    def _scale(self, k: cython.Py_ssize_t, vx: cython.double, vy: cython.double,
               any_heading: cython.bint) -> cython.double:
        """The largest s in [0, 1] with s (vx, vy) within the first ``k`` bounds, their
        retreats taken as zero (which s = 0 always keeps); with
        ``any_heading``, for whatever a differential-drive base at an unknown heading drives
        of it (at most ``(|v| + v.w) / 2`` along w)."""
        out = self._bound
        c: cython.Py_ssize_t
        vu: cython.double
        s: cython.double = 1.0
        sp: cython.double = sqrt(vx * vx + vy * vy)
        for c in range(k):
            vu = vx * out[c, 0] + vy * out[c, 1]
            if any_heading:
                vu = 0.5 * (sp + vu)
            if vu > out[c, 3] and vu * s > out[c, 3]:
                s = out[c, 3] / vu
        return s

    @cython.cfunc
    @cython.exceptval(check=False)
    def _guard(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t, a: cython.Py_ssize_t,
               b: cython.Py_ssize_t, m: cython.Py_ssize_t,
               pos: cython.const[cython.double][:, :, ::1],
               ref: cython.const[cython.double][:, :, ::1], vx: cython.double,
               vy: cython.double) -> tuple[cython.double, cython.double]:
        """(vx, vy) within the guard of the ``m`` neighbours at [a, b] (see :meth:`robot`)."""
        k: cython.Py_ssize_t = self._bounds(e, i, a, b, m, pos, ref)
        out = self._bound
        c: cython.Py_ssize_t
        _p: cython.Py_ssize_t
        over: cython.double
        s: cython.double
        moved: cython.bint
        for _p in range(_GUARD_PASSES):  # project on each bound in turn
            moved = False
            for c in range(k):
                over = vx * out[c, 0] + vy * out[c, 1] - out[c, 2]
                if over > 0.0:
                    vx = vx - over * out[c, 0]
                    vy = vy - over * out[c, 1]
                    moved = True
            if not moved:
                return clamp(vx, vy, self.v_max)  # a retreat may ask for more than v_max
        s = self._scale(k, vx, vy, False)  # then scale what is left (zero keeps them all)
        return clamp(vx * s, vy * s, self.v_max)

    @cython.ccall
    def guard_scale(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t,
                    pos: cython.const[cython.double][:, :, ::1],
                    drive_x: cython.double, drive_y: cython.double,
                    any_heading: cython.bint = False,
                    guard_ref: cython.const[cython.double][:, :, ::1] = None
                    ) -> cython.double:
        """The largest s in [0, 1] such that ``s`` (drive_x, drive_y), the velocity (m/s)
        the robot's wheels will actually drive for its filtered command, stays within the
        guard; call it right after :meth:`robot` for the same robot, ``pos`` and
        ``guard_ref``. A command scaled by s drives s times as fast (a differential-drive
        base turns by the command's direction only). ``any_heading``: the base's heading is
        not known, and (drive_x, drive_y) is the command itself. 1 without a guard."""
        if self.guard <= 0.0:
            return 1.0
        if not (0 <= e < pos.shape[0] and 0 <= i < pos.shape[1]):
            raise ValueError("ORCA: robot index does not fit the positions")
        ref = self._no_ref if guard_ref is None else guard_ref
        if ref.shape[0] > 0 and (ref.shape[0] != pos.shape[0] or ref.shape[1] != pos.shape[1]
                                 or ref.shape[2] != GUARD_REF_COLUMNS):
            raise ValueError("ORCA: the guard's references do not fit the positions")
        if ref.shape[0] > 0:
            self._bound_rows(pos.shape[1])
        k: cython.Py_ssize_t = self._bounds(e, i, 0, 0, self._count[0, 0], pos, ref)
        return self._scale(k, drive_x, drive_y, any_heading)

    @cython.ccall
    def teams(self, pos: cython.const[cython.double][:, :, ::1],
              vel: cython.const[cython.double][:, :, ::1],
              pref: cython.const[cython.double][:, :, ::1],
              horizon_s: cython.const[cython.double][::1],
              out: cython.double[:, :, ::1], changed: cython.uchar[:, ::1]) -> cython.void:
        """Every robot of E teams: ``pos``, ``vel``, ``pref`` (E, n, 2) as in :meth:`robot`,
        ``horizon_s`` (E,) each team's horizon (s); writes ``out`` (E, n, 2) m/s and
        ``changed`` (E, n). A robot whose preferred velocity is not finite holds still
        (zero, unchanged)."""
        E: cython.Py_ssize_t = pos.shape[0]
        n: cython.Py_ssize_t = pos.shape[1]
        e: cython.Py_ssize_t
        i: cython.Py_ssize_t
        px: cython.double
        py: cython.double
        ch: cython.bint
        if vel.shape[0] != E or pref.shape[0] != E or out.shape[0] != E \
                or changed.shape[0] != E or horizon_s.shape[0] != E or vel.shape[1] != n \
                or pref.shape[1] != n or out.shape[1] != n or changed.shape[1] != n:
            raise ValueError("ORCA: the arrays' shapes do not fit")
        self._tables(E, n)
        nearest(pos, 0, E, 0, n, self.max_neighbours, self.range_sq, self._ids, self._d2,
                self._count)
        for e in range(E):
            for i in range(pos.shape[1]):
                px = pref[e, i, 0]
                py = pref[e, i, 1]
                if not (isfinite(px) and isfinite(py)):
                    out[e, i, 0] = 0.0
                    out[e, i, 1] = 0.0
                    changed[e, i] = 0
                    continue
                out[e, i, 0], out[e, i, 1], ch, _ = self._safe(e, i, e, i, pos, vel, px, py,
                                                               horizon_s[e], self._no_ref)
                changed[e, i] = ch
