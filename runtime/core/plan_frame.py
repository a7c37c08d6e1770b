# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# mypy: allow-untyped-decorators
"""The synchronised plan's frame: the smallest enclosing circle, the blend, the steps left.

One team of n robots, robot j at ``p_j`` heading for its pattern point ``q_j``
(the shared assignment's slot, at any translation of the pattern). With the
displacements ``d_j = p_j - q_j`` the plan's frame is (:mod:`runtime.decision.rules`)::

    c = centre of the smallest circle enclosing the d_j        (Welzl)
    t = c + travel_weight * (mean_j d_j - c)                   (t = mean_j d_j from weight 1)
    K = max(1, ceil(max_j |t - d_j| / reach - STEP_TOL))       steps left, reach = v_max dt

and robot j's slot is ``q_j + t``. :func:`plan_frame` solves one team for a
robot, keeping the last step's support (the two or three displacements on the
circle) from call to call; :func:`plan_frames` solves E teams afresh, for the
batch paths (:func:`runtime.decision.rules.plan_targets`); :func:`min_enclosing_circle`
is the circle alone (also the lower bounds' in :mod:`runtime.decision.formation`).

The file runs as Python and compiled (Cython's pure-Python mode, ``setup.py``).
Arrays are read through the buffer protocol as flat C-contiguous float64 (int64
for the support) items: compiled through a pointer, as Python through a builtin
``memoryview`` (whose items are Python floats and ints).
Distances are ``sqrt(x * x + y * y)``: IEEE multiplications, additions and a
square root, each correctly rounded in C and in Python alike, so both give the
same numbers bit for bit (``hypot`` differs between C libraries and CPython in
the last bit).
"""

from typing import Any, Final

import cython
import numpy as np
from cython.cimports.libc.math import ceil, sqrt

if cython.compiled:
    from cython.cimports.cpython.buffer import PyBuffer_IsContiguous
    from cython.cimports.cpython.memoryview import PyMemoryView_GET_BUFFER

__all__ = [
    "STEP_TOL",
    "SUPPORT_SLACK_M",
    "min_enclosing_circle",
    "plan_frame",
    "plan_frames",
    "steps_left",
]

_STEP_TOL = cython.declare(cython.double, 1e-9)
_SLACK = cython.declare(cython.double, 1e-4)

STEP_TOL: Final[float] = _STEP_TOL
"""Relative slack in ``ceil(distance / reach)``: a distance that is a whole number
of steps up to rounding counts as that many steps, not one more."""

SUPPORT_SLACK_M: Final[float] = _SLACK
"""How far outside the last support's circle a displacement may lie and the support
be kept (:func:`plan_frame`), metres: a team holding its pattern jitters by tens of
micrometres, which would otherwise re-solve every step; the frame then moves by at
most this slack (0.1 mm), far below the formed tolerance (25 mm)."""


# ------------------------------------------------------------------------- buffers


@cython.cfunc
def _items(mv: memoryview, kind: cython.char, writable: cython.bint, what: str
           ) -> cython.Py_ssize_t:
    """Compiled: the items of the buffer behind ``mv``, checked: C-contiguous, 8-byte
    float (``kind`` ord('d')) or integer (ord('q')), writable if asked. Raises otherwise."""
    fmt: cython.p_char = PyMemoryView_GET_BUFFER(mv).format
    if fmt == cython.NULL:
        fmt = b"B"
    if fmt[0] == ord("<") or fmt[0] == ord("=") or fmt[0] == ord("@"):
        fmt += 1
    ok: cython.bint = fmt[0] == kind or (kind == ord("q") and fmt[0] == ord("l"))
    if not ok or fmt[1] != 0 or PyMemoryView_GET_BUFFER(mv).itemsize != 8:
        raise TypeError(f"{what}: expected {'float64' if kind == ord('d') else 'int64'} items")
    if not PyBuffer_IsContiguous(PyMemoryView_GET_BUFFER(mv), ord('C')):
        raise ValueError(f"{what}: not C-contiguous")
    if writable and PyMemoryView_GET_BUFFER(mv).readonly:
        raise ValueError(f"{what}: read-only")
    return PyMemoryView_GET_BUFFER(mv).len // 8


def _py_items(mv: memoryview, kind: str, writable: bool, what: str) -> tuple[int, Any]:
    """As Python: :func:`_items`'s checks, and the buffer as a flat memoryview of Python
    floats (``kind`` 'd') or ints ('q')."""
    f = mv.format.lstrip("<=@")
    if not (f == kind or (kind == "q" and f == "l")) or mv.itemsize != 8:
        raise TypeError(f"{what}: expected {'float64' if kind == 'd' else 'int64'} items")
    if not mv.c_contiguous:
        raise ValueError(f"{what}: not C-contiguous")
    if writable and mv.readonly:
        raise ValueError(f"{what}: read-only")
    flat = mv.cast("B")
    return mv.nbytes // 8, flat.cast("d") if kind == "d" else flat.cast("q")


# ------------------------------------------------------------ the enclosing circle


@cython.cfunc
@cython.inline
@cython.exceptval(check=False)
def _norm(x: cython.double, y: cython.double) -> cython.double:
    return sqrt(x * x + y * y)


@cython.cfunc
@cython.inline
@cython.exceptval(check=False)
def _inside(cx: cython.double, cy: cython.double, r: cython.double,
            x: cython.double, y: cython.double) -> cython.bint:
    """Is (x, y) in the circle (cx, cy, r), up to a relative and an absolute 1e-12."""
    return _norm(x - cx, y - cy) <= r * (1 + 1e-12) + 1e-12


@cython.cfunc
@cython.exceptval(check=False)
def _circ2(ax: cython.double, ay: cython.double, bx: cython.double, by: cython.double
           ) -> tuple[cython.double, cython.double, cython.double]:
    """The circle on the diameter a-b."""
    cx: cython.double = (ax + bx) / 2
    cy: cython.double = (ay + by) / 2
    return cx, cy, _norm(ax - cx, ay - cy)


@cython.cfunc
@cython.exceptval(check=False)
def _circ3(ax: cython.double, ay: cython.double, px: cython.double, py: cython.double,
           qx: cython.double, qy: cython.double
           ) -> tuple[cython.double, cython.double, cython.double]:
    """The circle through a, p and q; for collinear points, the widest pair's (the first
    of equals, in the order a-p, a-q, p-q)."""
    bx: cython.double = px - ax
    by: cython.double = py - ay
    cx: cython.double = qx - ax
    cy: cython.double = qy - ay
    d: cython.double = 2 * (bx * cy - by * cx)
    ox: cython.double
    oy: cython.double
    r: cython.double
    kx: cython.double
    ky: cython.double
    kr: cython.double
    if abs(d) < 1e-18:  # collinear: the widest pair
        ox, oy, r = _circ2(ax, ay, px, py)
        kx, ky, kr = _circ2(ax, ay, qx, qy)
        if kr > r:
            ox, oy, r = kx, ky, kr
        kx, ky, kr = _circ2(px, py, qx, qy)
        if kr > r:
            ox, oy, r = kx, ky, kr
        return ox, oy, r
    ux: cython.double = (cy * (bx * bx + by * by) - by * (cx * cx + cy * cy)) / d
    uy: cython.double = (bx * (cx * cx + cy * cy) - cx * (bx * bx + by * by)) / d
    return ux + ax, uy + ay, _norm(ux, uy)


@cython.cfunc
@cython.inline
@cython.exceptval(check=False)
def _row(sup: cython.p_longlong, picked: cython.bint, i: cython.Py_ssize_t
         ) -> cython.Py_ssize_t:
    """Point i's index in D: the support's i-th (``picked``) or i itself, times 2."""
    if picked:
        return 2 * cython.cast(cython.Py_ssize_t, sup[1 + i])
    return 2 * i


@cython.cfunc
@cython.exceptval(check=False)
def _welzl(D: cython.p_double, sup: cython.p_longlong, picked: cython.bint,
           m: cython.Py_ssize_t) -> tuple[cython.double, cython.double, cython.double]:
    """The smallest circle (cx, cy, r) enclosing m points of D (x0, y0, x1, y1, ...):
    points 0..m-1, or the support's points ``sup[1:1 + m]`` (``picked``). Welzl's
    algorithm, iterative move-to-front, O(m) expected; m >= 1."""
    a: cython.Py_ssize_t = _row(sup, picked, 0)
    b: cython.Py_ssize_t
    c: cython.Py_ssize_t
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    k: cython.Py_ssize_t
    cx: cython.double = D[a]
    cy: cython.double = D[a + 1]
    r: cython.double = 0.0
    ax: cython.double
    ay: cython.double
    bx: cython.double
    by: cython.double
    for i in range(1, m):
        a = _row(sup, picked, i)
        ax = D[a]
        ay = D[a + 1]
        if _inside(cx, cy, r, ax, ay):
            continue
        cx, cy, r = ax, ay, 0.0
        for j in range(i):
            b = _row(sup, picked, j)
            bx = D[b]
            by = D[b + 1]
            if _inside(cx, cy, r, bx, by):
                continue
            cx, cy, r = _circ2(ax, ay, bx, by)
            for k in range(j):
                c = _row(sup, picked, k)
                if not _inside(cx, cy, r, D[c], D[c + 1]):
                    cx, cy, r = _circ3(ax, ay, bx, by, D[c], D[c + 1])
    return cx, cy, r


def min_enclosing_circle(pts: Any) -> tuple[float, float, float]:
    """The smallest circle enclosing ``pts`` (m, 2), m >= 1: (cx, cy, r), metres.

    Exact up to the 1e-12 (relative and absolute) by which a point counts as inside.
    """
    p: Any = np.ascontiguousarray(pts, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 1:
        raise ValueError(f"min_enclosing_circle: points of shape (m >= 1, 2), not {p.shape}")
    mv = memoryview(p)
    P: cython.p_double
    if cython.compiled:
        _items(mv, ord("d"), False, "pts")
        P = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mv).buf)
    else:
        P = _py_items(mv, "d", False, "pts")[1]
    cx: cython.double
    cy: cython.double
    r: cython.double
    cx, cy, r = _welzl(P, cython.NULL, False, p.shape[0])
    return cx, cy, r


# ------------------------------------------------------------------------ the plan


@cython.cfunc
@cython.exceptval(check=False)
def _solve(P: cython.p_double, Q: cython.p_double, D: cython.p_double, n: cython.Py_ssize_t,
           w: cython.double, reach: cython.double, sup: cython.p_longlong
           ) -> tuple[cython.double, cython.double, cython.double]:
    """One team: P, Q its n positions and pattern points (x0, y0, x1, y1, ...) -> (tx, ty,
    K). D (2n items) receives the displacements; sup = [count, j0, j1, j2] is tried first
    and then holds this step's support (count 0, or a stale support: solved afresh)."""
    j: cython.Py_ssize_t
    s: cython.Py_ssize_t
    x: cython.double
    y: cython.double
    mx: cython.double = 0.0
    my: cython.double = 0.0
    for j in range(n):
        x = P[2 * j] - Q[2 * j]
        y = P[2 * j + 1] - Q[2 * j + 1]
        D[2 * j] = x
        D[2 * j + 1] = y
        mx += x
        my += y
    tx: cython.double
    ty: cython.double
    cx: cython.double = 0.0
    cy: cython.double = 0.0
    r: cython.double
    lim: cython.double
    found: cython.bint = False
    cnt: cython.longlong
    top: cython.longlong
    if w >= 1.0:  # the centroid frame: no circle
        tx = mx / n
        ty = my / n
    else:
        cnt = sup[0]
        if 0 < cnt <= 3:  # the last step's support, if it still encloses every d_j
            top = -1
            for s in range(cnt):
                if sup[1 + s] < 0:
                    top = n
                elif sup[1 + s] > top:
                    top = sup[1 + s]
            if top < n:
                cx, cy, r = _welzl(D, sup, True, cnt)
                lim = r * (1 + 1e-12) + _SLACK
                found = True
                for j in range(n):
                    if _norm(D[2 * j] - cx, D[2 * j + 1] - cy) > lim:
                        found = False
                        break
        if not found:
            cx, cy, r = _welzl(D, sup, False, n)
            lim = r * (1 - 1e-9) - 1e-12
            s = 0
            for j in range(n):
                if s == 3:
                    break
                if _norm(D[2 * j] - cx, D[2 * j + 1] - cy) >= lim:
                    sup[1 + s] = j
                    s += 1
            sup[0] = s
        tx = cx + w * (mx / n - cx)
        ty = cy + w * (my / n - cy)
    far: cython.double = 0.0
    g: cython.double
    for j in range(n):
        g = _norm(tx - D[2 * j], ty - D[2 * j + 1])
        if g > far:
            far = g
    q: cython.double = far / reach - _STEP_TOL
    K: cython.double = 1.0
    if q > 1.0:  # (NaN: 1)
        K = float(ceil(q))
    return tx, ty, K


def plan_frame(pos: Any, pts: Any, d: Any, travel_weight: float, reach: float,
               support: Any) -> tuple[float, float, float]:
    """One team's frame, the robot's path: (tx, ty, K).

    ``pos``, ``pts`` (n, 2) float64 C-contiguous, n >= 1: positions and each robot's
    pattern point; ``d`` (>= n, 2) float64 scratch (the displacements); ``reach`` =
    v_max dt (m); ``support`` int64 (>= 4,) ``[count, j0, j1, j2]``, read and written:
    the last step's support, kept while its circle encloses every displacement up to
    :data:`SUPPORT_SLACK_M` (count 0: solve afresh). K >= 1 is a whole number. Bad
    arrays raise TypeError (dtype) or ValueError (size, layout, read-only).
    """
    mp, mq, md, ms = memoryview(pos), memoryview(pts), memoryview(d), memoryview(support)
    P: cython.p_double
    Q: cython.p_double
    D: cython.p_double
    S: cython.p_longlong
    n2: cython.Py_ssize_t
    nq: cython.Py_ssize_t
    nd: cython.Py_ssize_t
    ns: cython.Py_ssize_t
    if cython.compiled:
        n2 = _items(mp, ord("d"), False, "pos")
        nq = _items(mq, ord("d"), False, "pts")
        nd = _items(md, ord("d"), True, "d")
        ns = _items(ms, ord("q"), True, "support")
        P = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mp).buf)
        Q = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mq).buf)
        D = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(md).buf)
        S = cython.cast(cython.p_longlong, PyMemoryView_GET_BUFFER(ms).buf)
    else:
        n2, P = _py_items(mp, "d", False, "pos")
        nq, Q = _py_items(mq, "d", False, "pts")
        nd, D = _py_items(md, "d", True, "d")
        ns, S = _py_items(ms, "q", True, "support")
    w: cython.double = travel_weight
    rch: cython.double = reach
    if n2 < 2 or n2 % 2 != 0 or nq != n2 or nd < n2 or ns < 4:
        raise ValueError("plan_frame: pos, pts (n >= 1, 2), d (>= n, 2), support (>= 4,)")
    if not rch > 0.0:
        raise ValueError(f"plan_frame: reach must be > 0, not {reach}")
    tx: cython.double
    ty: cython.double
    K: cython.double
    tx, ty, K = _solve(P, Q, D, n2 // 2, w, rch, S)
    return tx, ty, K


def plan_frames(pos: Any, pts: Any, travel_weight: float, reach: float, t_out: Any,
                k_out: Any) -> None:
    """E teams' frames, each solved afresh: the batch path.

    ``pos``, ``pts`` (E, n, 2) positions and pattern points; fills ``t_out`` (E, 2)
    with the frames and ``k_out`` (E,) with the steps left (both float64,
    C-contiguous). As :func:`plan_frame` team by team, with no support kept.
    """
    p: Any = np.ascontiguousarray(pos, dtype=np.float64)
    q: Any = np.ascontiguousarray(pts, dtype=np.float64)
    if p.ndim != 3 or p.shape[2] != 2 or q.shape != p.shape or p.shape[1] < 1:
        raise ValueError(f"plan_frames: pos, pts (E, n >= 1, 2), not {p.shape}, {q.shape}")
    E: cython.Py_ssize_t = p.shape[0]
    n: cython.Py_ssize_t = p.shape[1]
    w: cython.double = travel_weight
    rch: cython.double = reach
    if not rch > 0.0:
        raise ValueError(f"plan_frames: reach must be > 0, not {reach}")
    d: Any = np.empty((n, 2))
    sup: Any = np.zeros(4, dtype=np.int64)
    mp, mq, md, ms = memoryview(p), memoryview(q), memoryview(d), memoryview(sup)
    mt, mk = memoryview(t_out), memoryview(k_out)
    P: cython.p_double
    Q: cython.p_double
    D: cython.p_double
    S: cython.p_longlong
    T: cython.p_double
    Kv: cython.p_double
    nt: cython.Py_ssize_t
    nk: cython.Py_ssize_t
    if cython.compiled:
        nt = _items(mt, ord("d"), True, "t_out")
        nk = _items(mk, ord("d"), True, "k_out")
        P = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mp).buf)
        Q = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mq).buf)
        D = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(md).buf)
        S = cython.cast(cython.p_longlong, PyMemoryView_GET_BUFFER(ms).buf)
        T = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mt).buf)
        Kv = cython.cast(cython.p_double, PyMemoryView_GET_BUFFER(mk).buf)
    else:
        P = _py_items(mp, "d", False, "pos")[1]
        Q = _py_items(mq, "d", False, "pts")[1]
        D = _py_items(md, "d", True, "d")[1]
        S = _py_items(ms, "q", True, "support")[1]
        nt, T = _py_items(mt, "d", True, "t_out")
        nk, Kv = _py_items(mk, "d", True, "k_out")
    if nt != 2 * E or nk != E:
        raise ValueError("plan_frames: t_out (E, 2) and k_out (E,)")
    e: cython.Py_ssize_t
    tx: cython.double
    ty: cython.double
    K: cython.double
    for e in range(E):
        S[0] = 0
        if cython.compiled:
            tx, ty, K = _solve(P + 2 * n * e, Q + 2 * n * e, D, n, w, rch, S)
        else:
            tx, ty, K = _solve(P[2 * n * e :], Q[2 * n * e :], D, n, w, rch, S)
        T[2 * e] = tx
        T[2 * e + 1] = ty
        Kv[e] = K


def steps_left(far_m: Any, reach: float) -> Any:
    """The steps ``K`` a plan has left when its farthest robot is ``far_m`` (m, a number or
    an array) from its slot at ``reach`` m a step, as :func:`plan_frame` counts them:
    ``max(1, ceil(far / reach - STEP_TOL))`` (a NaN way: 1)."""
    q = np.asarray(far_m, dtype=np.float64) / reach - STEP_TOL
    return np.where(q > 1.0, np.ceil(np.where(q > 1.0, q, 1.0)), 1.0)
