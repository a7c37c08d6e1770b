# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""ORCA's linear programs and the speed clamp: the velocity within v_max closest to the
preferred one, inside a set of half-planes.

RVO2's ``linearProgram1/2/3`` (van den Berg et al., "Reciprocal n-body collision
avoidance", 2011), called as one (:meth:`LinearProgram.solve`): the velocity closest to
the optimum where the half-planes leave room, else the one that violates them least.
:class:`runtime.core.orca.OrcaFilter` writes the half-planes; :func:`clamp_speed` is the
clamp every velocity leaves the decision through. One entry point: the linear programs
call one another often, and within this module the compiler inlines them. Plain Python
in Cython's pure-Python mode (see :mod:`runtime.core`); ``orca_lp.pxd`` declares
:class:`LinearProgram` and :func:`clamp` for the compiled filter. Units: m/s.
"""

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.libc.math import hypot, sqrt
else:
    from math import hypot, sqrt

__all__ = ["LinearProgram", "clamp", "clamp_speed"]

RVO_EPS = cython.declare(cython.double, 1e-5)
"""RVO2's tolerance for parallel lines in the linear programs."""


@cython.cfunc
@cython.exceptval(check=False)
def clamp(vx: cython.double, vy: cython.double,
          v_max: cython.double) -> tuple[cython.double, cython.double]:
    """:func:`clamp_speed` for compiled callers: a C call, no Python object."""
    a: cython.double = hypot(vx, vy)
    b: cython.double = sqrt(vx * vx + vy * vy)
    sp: cython.double = a if a > b else b
    s: cython.double
    if sp > 1e300:  # the squares overflow: scale first, the direction is what counts
        vx = vx * 1e-300
        vy = vy * 1e-300
        a = hypot(vx, vy)
        b = sqrt(vx * vx + vy * vy)
        sp = a if a > b else b
    if sp > v_max:
        s = v_max / sp
        vx = vx * s
        vy = vy * s
        # within v_max both ways of taking the norm, and a unit in the last place below it:
        # C libraries' hypot and Python's round differently by that much
        lim: cython.double = v_max * (1.0 - 1e-16)
        while True:
            a = hypot(vx, vy)
            b = sqrt(vx * vx + vy * vy)
            if not (a if a > b else b) > lim:
                break
            vx = vx * (1.0 - 1e-15)
            vy = vy * (1.0 - 1e-15)
    return vx, vy


@cython.ccall
def clamp_speed(vx: cython.double, vy: cython.double,
                v_max: cython.double) -> tuple[cython.double, cython.double]:
    """(vx, vy) scaled down to norm <= v_max (m/s): a clamped velocity's norm is at most v_max
    whichever way it is taken (``hypot`` of C or Python, or ``sqrt(x*x + y*y)``)."""
    return clamp(vx, vy, v_max)


# --------------------------------------------- linear programs (RVO2's 1, 2 and 3)
# A line is a row [px, py, dx, dy] of a (m, 4) array: a point on it and its unit
# direction; the allowed half-plane lies to the left of the direction.


@cython.cfunc
@cython.exceptval(check=False)
def _lp1(lines: cython.double[:, ::1], no: cython.Py_ssize_t, radius: cython.double,
         ox: cython.double, oy: cython.double, dir_opt: cython.bint,
         out: cython.double[::1]) -> cython.bint:
    """The best point on line ``no`` within the circle and the lines before it, into
    ``out[0:2]``; False when there is none."""
    px: cython.double = lines[no, 0]
    py: cython.double = lines[no, 1]
    dx: cython.double = lines[no, 2]
    dy: cython.double = lines[no, 3]
    dot: cython.double = px * dx + py * dy
    disc: cython.double = dot * dot + radius * radius - (px * px + py * py)
    sq: cython.double
    tl: cython.double
    tr: cython.double
    t: cython.double
    den: cython.double
    num: cython.double
    i: cython.Py_ssize_t
    if disc < 0.0:
        return False  # the max-speed circle misses this line entirely
    sq = sqrt(disc)
    tl = -dot - sq
    tr = -dot + sq
    for i in range(no):
        den = dx * lines[i, 3] - dy * lines[i, 2]
        num = lines[i, 2] * (py - lines[i, 1]) - lines[i, 3] * (px - lines[i, 0])
        if abs(den) <= RVO_EPS:
            if num < 0.0:
                return False  # parallel and on the wrong side
            continue
        t = num / den
        if den >= 0.0:
            if t < tr:
                tr = t
        elif t > tl:
            tl = t
        if tl > tr:
            return False
    if dir_opt:
        t = tr if ox * dx + oy * dy > 0.0 else tl
    else:
        t = dx * (ox - px) + dy * (oy - py)
        if t < tl:
            t = tl
        elif t > tr:
            t = tr
    out[0] = px + t * dx
    out[1] = py + t * dy
    return True


@cython.cfunc
@cython.exceptval(check=False)
def _lp2(lines: cython.double[:, ::1], m: cython.Py_ssize_t, radius: cython.double,
         ox: cython.double, oy: cython.double, dir_opt: cython.bint,
         out: cython.double[::1]) -> cython.Py_ssize_t:
    """The point closest to the optimum (ox, oy) that satisfies lines[:m], into
    ``out[0:2]``; returns the line that failed (m on success)."""
    n2: cython.double
    s: cython.double
    i: cython.Py_ssize_t
    if dir_opt:
        out[0] = ox * radius
        out[1] = oy * radius
    else:
        n2 = ox * ox + oy * oy
        if n2 > radius * radius:
            s = radius / sqrt(n2)
            out[0] = ox * s
            out[1] = oy * s
        else:
            out[0] = ox
            out[1] = oy
    for i in range(m):
        if lines[i, 2] * (lines[i, 1] - out[1]) - lines[i, 3] * (lines[i, 0] - out[0]) > 0.0:
            if not _lp1(lines, i, radius, ox, oy, dir_opt, out):
                return i
    return m


@cython.cfunc
@cython.exceptval(check=False)
def _lp3(lines: cython.double[:, ::1], m: cython.Py_ssize_t, begin: cython.Py_ssize_t,
         radius: cython.double, proj: cython.double[:, ::1], out: cython.double[::1],
         found: cython.double[::1]) -> cython.void:
    """The infeasible case: the velocity of least largest violation, from ``out[0:2]``
    (lines[:begin] hold); ``proj`` (m, 4) and ``found`` (2,) are scratch."""
    distance: cython.double = 0.0
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    k: cython.Py_ssize_t
    px: cython.double
    py: cython.double
    dx: cython.double
    dy: cython.double
    det: cython.double
    t: cython.double
    ux: cython.double
    uy: cython.double
    un: cython.double
    for i in range(begin, m):
        px = lines[i, 0]
        py = lines[i, 1]
        dx = lines[i, 2]
        dy = lines[i, 3]
        if dx * (py - out[1]) - dy * (px - out[0]) > distance:
            k = 0
            for j in range(i):
                det = dx * lines[j, 3] - dy * lines[j, 2]
                if abs(det) <= RVO_EPS:
                    if dx * lines[j, 2] + dy * lines[j, 3] > 0.0:
                        continue  # the same direction: line j is implied
                    proj[k, 0] = 0.5 * (px + lines[j, 0])
                    proj[k, 1] = 0.5 * (py + lines[j, 1])
                else:
                    t = (lines[j, 2] * (py - lines[j, 1]) - lines[j, 3] * (px - lines[j, 0])) / det
                    proj[k, 0] = px + t * dx
                    proj[k, 1] = py + t * dy
                ux = lines[j, 2] - dx
                uy = lines[j, 3] - dy
                un = sqrt(ux * ux + uy * uy)
                proj[k, 2] = ux / un
                proj[k, 3] = uy / un
                k += 1
            if _lp2(proj, k, radius, -dy, dx, True, found) >= k:
                out[0] = found[0]
                out[1] = found[1]
            # else: keep the previous result (a numerical failure, as RVO2 does)
            distance = dx * (py - out[1]) - dy * (px - out[0])


@cython.cclass
class LinearProgram:
    """ORCA's linear program over at most ``k`` half-planes: the lines, the result and the
    scratch, kept from one solve to the next (one per filter, not shared between threads).
    A class so that the compiled filter's call passes one object, not four arrays' views
    (``orca_lp.pxd`` declares its fields)."""

    def __init__(self, k: int) -> None:
        """Room for ``k`` (>= 1) lines: ``lines`` (k, 4), a row [px, py, dx, dy] each (the
        caller's to write), the result in ``out`` (2,)."""
        self.lines = np.zeros((k, 4))
        self.out = np.zeros(2)
        self._proj = np.zeros((k, 4))
        self._found = np.zeros(2)

    @cython.cfunc
    @cython.exceptval(check=False)
    def solve(self, m: cython.Py_ssize_t, radius: cython.double, ox: cython.double,
              oy: cython.double) -> cython.void:
        """The velocity within ``radius`` (m/s) closest to (ox, oy) that satisfies
        lines[:m], or, where none does, the one of least largest violation, into
        ``out``."""
        c: cython.Py_ssize_t = _lp2(self.lines, m, radius, ox, oy, False, self.out)
        if c < m:
            _lp3(self.lines, m, c, radius, self._proj, self.out, self._found)
