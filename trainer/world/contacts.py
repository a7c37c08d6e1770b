# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The training world's move: actions to positions, with rigid discs that never interpenetrate.

One source, in Cython's pure-Python mode: ``setup.py`` compiles this file at
install (or ``cythonize -i -3 trainer/world/contacts.py`` in place), and without a
build the very same file runs as Python (the same numbers, slower). One call
of :func:`move` is the whole move of a step of the training world, env by env:

1. **Actions** ``(E, N, 2)`` m/s to velocities: a robot whose action is not
   finite (or so large that its square overflows) holds still; a faster one is
   scaled down to ``v_max`` (direction kept). Displacement = velocity * dt.
2. **Collisions.** Robots are rigid discs of radius R: a pair whose straight
   swept paths come closer than 2R during the step (the closest approach of
   :func:`runtime.decision.formation.swept_pair_distance`, the definition behind
   ``count_collisions``; a test holds the two equal) is a *collision*, counted
   once per pair per step and charged to both robots.
3. **Projection.** Overlaps left at the end of the move are resolved by Jacobi
   sweeps of pairwise projection: each overlapping pair is pushed apart
   symmetrically along its centre line to exactly 2R (sweeps after the first
   over-relax, so a jam of many discs clears in a few sweeps and may end with
   gaps slightly above 2R); a pair pushed apart in a later sweep (a robot
   shoved into a third one) is a collision too. This is what the pymunk world
   shows: discs that meet are pushed apart by the contact and never
   interpenetrate, and a robot that drives into another one stops at contact
   instead of passing.
4. **Fallback.** Should a jam not clear within ``CONTACT_SWEEPS`` sweeps, the
   robots still overlapping hold their previous (valid) positions (counted in
   ``BatchWorld.contact_fallbacks``); so after every step all centres are at
   least 2R apart (to ``CONTACT_TOL_M``).
5. **Travel**: each robot's distance moved is added to the caller's array.

Positions are robot-major, (2, N, E) (component, robot, env), as the training
world keeps them (see :mod:`trainer.world.training_world`). The projection needs
``v_max dt <= R`` (the default is exactly R): then no centre can cross
another's within a step, so a push never swaps two robots; other worlds are
refused. The plane has no walls: the arena only bounds the starts.
"""

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.libc.math import sqrt
else:
    from math import sqrt

from runtime.types import Array, IntArray
from runtime.world_config import WorldConfig

CONTACT_TOL_M = 1e-6
"""Two centres closer than 2R - this are interpenetrating (count_collisions' default)."""

CONTACT_SWEEPS = 16
"""Jacobi projection sweeps before the hold-still fallback."""

CONTACT_OVER_RELAX = 1.7
"""Over-relaxation of the sweeps after the first. A jam of ten robots all driven at
their centroid needs a median of 19 plain Jacobi sweeps (99th percentile 31) but
6 (99th percentile 9, never more than 12) over-relaxed; an isolated pair is
resolved by the first, plain sweep to exactly 2R."""


@cython.cfunc
@cython.exceptval(check=False)
def _resolve(
    x0: cython.double[:, ::1],
    x: cython.double[:, ::1],
    touched: cython.uchar[:, ::1],
    push: cython.double[:, ::1],
    stuck: cython.uchar[::1],
    n: cython.Py_ssize_t,
    two_r: cython.double,
    limit: cython.double,
    sweeps: cython.Py_ssize_t,
    relax: cython.double,
) -> cython.Py_ssize_t:
    """Push overlapping discs of one env apart, in place.

    ``x0``, ``x`` (2, n): positions before and after the move; ``touched``
    (n, n) in/out, every pair that touched; ``push`` (2, n) and ``stuck`` (n,)
    are scratch. Returns how many robots the fallback held still. Two centres
    exactly on top of each other have no centre line to push along; they are
    left to the fallback (it never happens with real-valued motion).
    """
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    _sweep: cython.Py_ssize_t
    dx: cython.double
    dy: cython.double
    d2: cython.double
    ax: cython.double
    ay: cython.double
    p: cython.double
    xi: cython.double
    yi: cython.double
    lim2: cython.double = limit * limit
    half: cython.double = 0.5
    anyover: cython.bint
    for _sweep in range(sweeps):
        anyover = False
        for i in range(n):
            push[0, i] = 0.0
            push[1, i] = 0.0
        # each pair once: robot i's pushes add up over its partners in ascending order, and
        # x_j - x_i is exactly -(x_i - x_j), so j's share is exactly the negated one
        for i in range(n):
            xi = x[0, i]
            yi = x[1, i]
            for j in range(i + 1, n):
                dx = xi - x[0, j]
                dy = yi - x[1, j]
                d2 = dx * dx + dy * dy
                if d2 < lim2:
                    anyover = True
                    touched[i, j] = 1
                    touched[j, i] = 1
                    # each robot of an overlapping pair moves (2R - d) / 2 along the centre line
                    p = half * (two_r / sqrt(max(d2, 1e-24)) - 1.0)
                    ax = dx * p
                    ay = dy * p
                    push[0, i] += ax
                    push[1, i] += ay
                    push[0, j] -= ax
                    push[1, j] -= ay
        if not anyover:
            return 0
        for i in range(n):
            x[0, i] += push[0, i]
            x[1, i] += push[1, i]
        half = 0.5 * relax
    # jammed: robots still overlapping hold their previous (valid) positions
    fallbacks: cython.Py_ssize_t = 0
    found: cython.bint
    for _sweep in range(n + 1):
        found = False
        for i in range(n):
            stuck[i] = 0
        for i in range(n):
            xi = x[0, i]
            yi = x[1, i]
            for j in range(i + 1, n):
                dx = xi - x[0, j]
                dy = yi - x[1, j]
                if dx * dx + dy * dy < lim2:
                    touched[i, j] = 1
                    touched[j, i] = 1
                    stuck[i] = 1
                    stuck[j] = 1
                    found = True
        if not found:
            break
        for i in range(n):
            if stuck[i]:
                fallbacks += 1
                x[0, i] = x0[0, i]
                x[1, i] = x0[1, i]
    return fallbacks


@cython.cfunc
@cython.exceptval(check=False)
def _move_envs(
    actions: cython.double[:, :, ::1],
    X0: cython.double[:, :, ::1],
    X1: cython.double[:, :, ::1],
    travel: cython.double[:, ::1],
    hits: cython.longlong[:, ::1],
    pairs: cython.longlong[::1],
    v_max: cython.double,
    dt: cython.double,
    two_r: cython.double,
    tol: cython.double,
    sweeps: cython.Py_ssize_t,
    relax: cython.double,
    x0: cython.double[:, ::1],
    x: cython.double[:, ::1],
    u: cython.double[:, ::1],
    push: cython.double[:, ::1],
    touched: cython.uchar[:, ::1],
    stuck: cython.uchar[::1],
) -> cython.Py_ssize_t:
    """The move of every env (see :func:`move`); ``x0`` .. ``stuck`` are one env's scratch."""
    E: cython.Py_ssize_t = actions.shape[0]
    n: cython.Py_ssize_t = actions.shape[1]
    e: cython.Py_ssize_t
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    vx: cython.double
    vy: cython.double
    s2: cython.double
    f: cython.double
    a: cython.double
    b: cython.double
    c: cython.double
    s: cython.double
    d0x: cython.double
    d0y: cython.double
    ddx: cython.double
    ddy: cython.double
    mx: cython.double
    my: cython.double
    hit: cython.bint
    anyhit: cython.bint
    h: cython.longlong
    total: cython.longlong
    limit: cython.double = two_r - tol
    lim2: cython.double = limit * limit
    # two robots start more than ``far`` apart: their closest approach is above ``limit``
    # by a margin far beyond rounding (each moves at most v_max dt), so the test is skipped
    far: cython.double = (limit + 2.0 * v_max * dt) * (1.0 + 1e-6)
    far2: cython.double = far * far
    xi: cython.double
    yi: cython.double
    uxi: cython.double
    uyi: cython.double
    finite_max: cython.double = 1.7976931348623157e308  # the largest double
    fallbacks: cython.Py_ssize_t = 0
    for e in range(E):
        # 1. actions -> displacements, held still where not finite, clamped to v_max
        for i in range(n):
            vx = actions[e, i, 0]
            vy = actions[e, i, 1]
            s2 = vx * vx + vy * vy
            if not s2 <= finite_max:  # NaN, or a square that overflowed
                vx = 0.0
                vy = 0.0
                s2 = 0.0
            f = v_max / max(sqrt(s2), v_max)  # min(1, v_max / |a|): direction kept
            u[0, i] = vx * f * dt
            u[1, i] = vy * f * dt
            x0[0, i] = X0[0, i, e]
            x0[1, i] = X0[1, i, e]
            x[0, i] = x0[0, i] + u[0, i]
            x[1, i] = x0[1, i] + u[1, i]
        # 2. swept collision test per pair: closest approach of d(s) = d0 + s dd, s in [0, 1]
        anyhit = False
        for i in range(n):
            touched[i, i] = 0
            xi = x0[0, i]
            yi = x0[1, i]
            uxi = u[0, i]
            uyi = u[1, i]
            for j in range(i + 1, n):
                d0x = x0[0, j] - xi
                d0y = x0[1, j] - yi
                a = d0x * d0x + d0y * d0y
                if a > far2:  # too far apart to meet within the step: no collision
                    touched[i, j] = 0
                    touched[j, i] = 0
                    continue
                ddx = u[0, j] - uxi
                ddy = u[1, j] - uyi
                b = d0x * ddx + d0y * ddy
                c = ddx * ddx + ddy * ddy
                s = -b / c if c > 0.0 else 0.0
                s = min(max(s, 0.0), 1.0)
                hit = a + s * (2.0 * b + s * c) < lim2
                touched[i, j] = hit
                touched[j, i] = hit
                if hit:
                    anyhit = True
        # 3-4. projection sweeps and fallback; hits per robot, colliding pairs
        if anyhit:
            fallbacks += _resolve(x0, x, touched, push, stuck, n, two_r, limit, sweeps, relax)
            total = 0
            for i in range(n):
                h = 0
                for j in range(n):
                    if touched[i, j]:
                        h += 1
                hits[i, e] = h
                total += h
            pairs[e] = total // 2
        # 5. positions out, travel
        for i in range(n):
            X1[0, i, e] = x[0, i]
            X1[1, i, e] = x[1, i]
            mx = x[0, i] - x0[0, i]
            my = x[1, i] - x0[1, i]
            travel[i, e] += sqrt(mx * mx + my * my)
    return fallbacks


def move(
    actions: object, X0: Array, travel: Array, world: WorldConfig
) -> tuple[Array, IntArray, IntArray, int]:
    """One step's move of every env: actions to positions, contacts resolved.

    ``actions`` (E, N, 2) m/s, any float dtype (widened exactly to float64; a
    non-finite one holds still, a faster one is scaled to ``v_max``); ``X0``
    (2, N, E) positions (m); ``travel`` (N, E) m,
    float64 C-contiguous, each robot's distance moved added in place. Returns
    (positions (2, N, E), collisions each robot took part in (N, E), colliding
    pairs per env (E,), robots held still by the fallback).
    """
    E = X0.shape[2]
    n = X0.shape[1]
    shape = (E, n, 2)
    a = np.asarray(actions)
    if a.shape != shape:
        raise ValueError(f"actions must be {shape}, got {a.shape}")
    if travel.shape != (n, E):
        raise ValueError(f"travel must be {(n, E)}, got {travel.shape}")
    a = np.ascontiguousarray(a, dtype=np.float64)  # float32 actions widened exactly
    X0 = np.ascontiguousarray(X0, dtype=np.float64)
    X1 = np.empty((2, n, E))
    hits = np.zeros((n, E), dtype=np.int64)
    pairs = np.zeros(E, dtype=np.int64)
    falls = _move_envs(
        a, X0, X1, travel, hits, pairs,
        world.v_max_mps, world.dt_s, world.min_separation_m,
        CONTACT_TOL_M, CONTACT_SWEEPS, CONTACT_OVER_RELAX,
        np.empty((2, n)), np.empty((2, n)), np.empty((2, n)), np.empty((2, n)),
        np.zeros((n, n), dtype=np.uint8), np.zeros(n, dtype=np.uint8),
    )
    return X1, hits, pairs, int(falls)


__all__ = ["CONTACT_OVER_RELAX", "CONTACT_SWEEPS", "CONTACT_TOL_M", "move"]
