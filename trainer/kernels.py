"""Compiled kernels of the training world's step (numba), one loop over envs each.

At E = 64 envs x N = 10 robots the numpy step spends its time in call
overhead (dozens of numpy calls on small arrays, one scipy call per env whose
assignment is not proven). These kernels do the same IEEE operations in the
same order in one compiled loop over envs, so a world stepped with them gives
the numpy path's numbers bit for bit (tests/unit/test_kernels.py). The robot
keeps the numpy path: ``runtime/`` never imports numba.

Layouts are the training world's: positions robot-major (2, N, E), per-robot
values (N, E), per-env values (E,). Units: metres, seconds, m/s, m^2.

The assignment (:func:`assign_step`) is exact: an env keeps its previous
slots where a Bellman-Ford pass over the exchange graph proves them within
half the hysteresis margin of optimal (the proof of
:func:`runtime.assignment.certify_assignment`); elsewhere :func:`lsap`, the
shortest augmenting path algorithm (Crouse 2016) in scipy's scan order,
solves it, ties broken as ``scipy.optimize.linear_sum_assignment`` breaks
them, and the hysteresis rule (:func:`runtime.formation.keeps_previous`) is
applied to sums taken in numpy's order.

Compiled code is cached on disk (``cache=True``, in ``__pycache__`` or
``NUMBA_CACHE_DIR``); where none is writable numba compiles in memory, once
per process.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np
from numba import njit
from numba.core.errors import NumbaWarning

from runtime.assignment import CERTIFY_ROUNDS
from runtime.formation import HYSTERESIS_ABS_M2, HYSTERESIS_REL
from runtime.types import Array, BoolArray, F32Array, IntArray
from runtime.world_config import WorldConfig
from trainer import contacts

F = TypeVar("F", bound=Callable[..., Any])


def _jit(fn: F) -> F:
    """``njit(cache=True)``, or plain ``njit`` where no cache directory can be used
    (a read-only install without a writable user cache)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NumbaWarning)
            out = njit(cache=True)(fn)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        out = njit(fn)
    return cast(F, out)


# ------------------------------------------------------------------ helpers


@_jit
def pairwise_sum(a: Array) -> float:
    """Sum of a 1-d float64 array in numpy's order (``np.add.reduce`` along a
    contiguous axis: 8 interleaved partial sums, pairwise above 128 values)."""
    n = a.shape[0]
    if n < 8:
        res = -0.0
        for i in range(n):
            res += a[i]
        return res
    if n <= 128:
        r0, r1, r2, r3 = a[0], a[1], a[2], a[3]
        r4, r5, r6, r7 = a[4], a[5], a[6], a[7]
        i = 8
        while i < n - (n % 8):
            r0 += a[i]
            r1 += a[i + 1]
            r2 += a[i + 2]
            r3 += a[i + 3]
            r4 += a[i + 4]
            r5 += a[i + 5]
            r6 += a[i + 6]
            r7 += a[i + 7]
            i += 8
        acc: float = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            acc += a[i]
            i += 1
        return acc
    n2 = n // 2
    n2 -= n2 % 8
    total: float = pairwise_sum(a[:n2]) + pairwise_sum(a[n2:])
    return total


# --------------------------------------------------------------- assignment


@_jit
def lsap(cost: Array, col4row: IntArray) -> bool:
    """Minimum-cost assignment of a square float64 ``cost`` (n, n) into ``col4row`` (n,).

    The shortest augmenting path algorithm (Crouse 2016), scanning rows and
    columns in the order scipy's ``linear_sum_assignment`` does (free columns
    from the last down, ties to a column that ends the path), so it returns
    what scipy returns, ties included. False when ``cost`` holds NaN or -inf,
    or no finite assignment exists.
    """
    n = cost.shape[0]
    for i in range(n):
        for j in range(n):
            c = cost[i, j]
            if c != c or c == -np.inf:
                return False
    u = np.zeros(n)
    v = np.zeros(n)
    spc = np.empty(n)  # shortest path costs
    path = np.full(n, -1, np.int64)
    row4col = np.full(n, -1, np.int64)
    col4row[:] = -1
    SR = np.zeros(n, np.bool_)
    SC = np.zeros(n, np.bool_)
    remaining = np.empty(n, np.int64)
    for cur in range(n):
        # shortest augmenting path from row ``cur``
        min_val = 0.0
        for it in range(n):
            remaining[it] = n - it - 1  # reverse order: a constant cost gives the identity
        SR[:] = False
        SC[:] = False
        spc[:] = np.inf
        num = n
        sink = -1
        i = cur
        while sink == -1:
            index = -1
            lowest = np.inf
            SR[i] = True
            for it in range(num):
                j = remaining[it]
                r = min_val + cost[i, j] - u[i] - v[j]
                if r < spc[j]:
                    path[j] = i
                    spc[j] = r
                if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                    lowest = spc[j]
                    index = it
            min_val = lowest
            if min_val == np.inf:
                return False
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            SC[j] = True
            num -= 1
            remaining[index] = remaining[num]
        # dual update
        u[cur] += min_val
        for i in range(n):
            if SR[i] and i != cur:
                u[i] += min_val - spc[col4row[i]]
        for j in range(n):
            if SC[j]:
                v[j] -= min_val - spc[j]
        # augment
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == cur:
                break
    return True


@_jit
def _certify(
    cost: Array, prev: IntArray, d: Array, tol: float, rounds: int, w: Array, row: Array,
    cand: Array,
) -> bool:
    """Bellman-Ford over ``prev``'s exchange graph from potentials ``d`` (n,), updated
    in place: True proves no assignment beats ``prev`` by more than n * tol (see
    :func:`runtime.assignment.certify_assignment`, the same proof). ``w`` (n, n),
    ``row``, ``cand`` (n,) are scratch."""
    n = cost.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += cost[i, j]
        row[i] = s / n
    for i in range(n):  # w[i, k]: robot i takes k's slot, k gives it up (row-normalised)
        for k in range(n):
            w[i, k] = cost[i, prev[k]] - cost[k, prev[k]] - row[i] + row[k]
    settled = False
    for _ in range(max(1, rounds)):
        ok = True
        for k in range(n):
            best = np.inf
            for i in range(n):
                x = d[i] + w[i, k]
                if x < best:
                    best = x
            cand[k] = best
            if not best >= d[k] - tol:
                ok = False
        if ok:
            settled = True
            break
        for k in range(n):
            if cand[k] < d[k]:
                d[k] = cand[k]
    top = -np.inf
    for k in range(n):
        if d[k] > top:
            top = d[k]
    for k in range(n):
        d[k] -= top
    return settled


@_jit
def _is_permutation(p: IntArray) -> bool:
    n = p.shape[0]
    seen = np.zeros(n, np.bool_)
    for i in range(n):
        s = p[i]
        if s < 0 or s >= n or seen[s]:
            return False
        seen[s] = True
    return True


@_jit
def assign_step(
    X: Array,
    Cc: Array,
    C: Array,
    previous: IntArray,
    potentials: Array,
    rel: float,
    abs_m2: float,
    rounds: int,
) -> tuple[IntArray, Array, Array, int]:
    """The shared assignment of every env at positions ``X`` (2, N, E).

    ``Cc``, ``C`` (2, N, E): each env's pattern centred twice and once (the
    training world's ``_Cc``, ``_C``); ``previous`` (N, E) the last slots;
    ``potentials`` (N, E) the proof's warm start, updated in place. Returns
    (slots (N, E), slot positions (2, N, E), squared slot distances (N, E),
    envs solved): what ``BatchWorld._assign``'s numpy path gives, bit for bit.
    A ``previous`` that is not a permutation is replaced by the solver's.
    """
    _, n, E = X.shape
    slots = np.empty((n, E), np.int64)
    G = np.empty((2, n, E))
    dist2 = np.empty((n, E))
    inv_n = 1.0 / n
    cost = np.empty((n, n))
    prev = np.empty(n, np.int64)
    fresh = np.empty(n, np.int64)
    d = np.empty(n)
    vals = np.empty(n)
    w = np.empty((n, n))
    row = np.empty(n)
    cand = np.empty(n)
    solved = 0
    for e in range(E):
        if E == 1:  # numpy reduces a lone env's robots along its inner loop: pairwise
            tx = pairwise_sum(X[0, :, 0])
            ty = pairwise_sum(X[1, :, 0])
        else:  # and several envs' robots one row after another
            tx = X[0, 0, e]
            ty = X[1, 0, e]
            for i in range(1, n):
                tx += X[0, i, e]
                ty += X[1, i, e]
        mx = tx / n
        my = ty / n
        for i in range(n):
            xi = X[0, i, e] - mx
            yi = X[1, i, e] - my
            for j in range(n):
                dx = xi - Cc[0, j, e]
                dy = yi - Cc[1, j, e]
                dx *= dx
                dy *= dy
                cost[i, j] = dx + dy
        for i in range(n):
            prev[i] = previous[i, e]
        keep = False
        if _is_permutation(prev):
            old = cost[0, prev[0]]  # numpy sums the proof's bound over robots in order
            for i in range(1, n):
                old += cost[i, prev[i]]
            tol = (rel * old + abs_m2) * (0.5 / n)
            for i in range(n):
                d[i] = potentials[i, e]
            keep = _certify(cost, prev, d, tol, rounds, w, row, cand)
            if keep:
                for i in range(n):
                    potentials[i, e] = d[i]
        if keep:
            for i in range(n):
                slots[i, e] = prev[i]
        else:
            solved += 1
            if not lsap(cost, fresh):  # non-finite costs: no solution to take
                for i in range(n):
                    fresh[i] = prev[i]
            for i in range(n):
                vals[i] = cost[i, fresh[i]]
            new = pairwise_sum(vals)
            kept_after = False
            if _is_permutation(prev):
                for i in range(n):
                    vals[i] = cost[i, prev[i]]
                old = pairwise_sum(vals)
                kept_after = not (new < old - (rel * old + abs_m2))
            for i in range(n):
                slots[i, e] = prev[i] if kept_after else fresh[i]
            if kept_after:
                for i in range(n):
                    potentials[i, e] = d[i]
            else:  # a new assignment is a new exchange graph
                for i in range(n):
                    potentials[i, e] = 0.0
        cx = tx * inv_n
        cy = ty * inv_n
        for i in range(n):
            s = slots[i, e]
            gx = C[0, s, e] + cx
            gy = C[1, s, e] + cy
            G[0, i, e] = gx
            G[1, i, e] = gy
            ax = X[0, i, e] - gx
            ay = X[1, i, e] - gy
            dist2[i, e] = ax * ax + ay * ay
    return slots, G, dist2, solved


def assign_env_last(
    X: Array, Cc: Array, C: Array, previous: IntArray, potentials: Array
) -> tuple[IntArray, Array, Array, int]:
    """:func:`assign_step` with the world's hysteresis constants and proof rounds."""
    rel, floor = HYSTERESIS_REL, HYSTERESIS_ABS_M2
    out: tuple[IntArray, Array, Array, int]
    out = assign_step(X, Cc, C, previous, potentials, rel, floor, CERTIFY_ROUNDS)
    return out


# ----------------------------------------------------------------- contacts


@_jit
def _resolve_env(
    X0: Array, X: Array, touched: BoolArray, e: int, two_r: float, limit: float,
    sweeps: int, relax: float,
) -> int:
    """:func:`trainer.contacts.resolve` for env ``e`` of ``X`` (2, N, E), in place;
    ``touched`` (N, N) in/out. Returns the robots the fallback held still."""
    n = X.shape[1]
    lim2 = limit * limit
    px = np.empty(n)
    py = np.empty(n)
    half = 0.5
    for _ in range(sweeps):
        anyover = False
        for i in range(n):
            ax = 0.0
            ay = 0.0
            for j in range(n):
                if i == j:
                    continue
                dx = X[0, i, e] - X[0, j, e]
                dy = X[1, i, e] - X[1, j, e]
                d2 = dx * dx + dy * dy
                if d2 < lim2:
                    anyover = True
                    touched[i, j] = True
                    push = half * (two_r / math.sqrt(max(d2, 1e-24)) - 1.0)
                    ax += dx * push
                    ay += dy * push
            px[i] = ax
            py[i] = ay
        if not anyover:
            return 0
        for i in range(n):
            X[0, i, e] += px[i]
            X[1, i, e] += py[i]
        half = 0.5 * relax
    # jammed: robots still overlapping hold their previous (valid) positions
    fallbacks = 0
    stuck = np.zeros(n, np.bool_)
    for _ in range(n + 1):
        found = False
        for i in range(n):
            stuck[i] = False
            for j in range(n):
                if i == j:
                    continue
                dx = X[0, i, e] - X[0, j, e]
                dy = X[1, i, e] - X[1, j, e]
                if dx * dx + dy * dy < lim2:
                    touched[i, j] = True
                    stuck[i] = True
                    found = True
        if not found:
            break
        for i in range(n):
            if stuck[i]:
                fallbacks += 1
                X[0, i, e] = X0[0, i, e]
                X[1, i, e] = X0[1, i, e]
    return fallbacks


@_jit
def move_step(
    actions: Array, X0: Array, travel: Array, v_max: float, dt: float, two_r: float,
    tol: float, sweeps: int, relax: float,
) -> tuple[Array, IntArray, IntArray, int]:
    """Actions to positions, with contacts: ``BatchWorld._velocities`` and ``_move``.

    ``actions`` (E, N, 2) m/s (a non-finite one holds still, a faster one is
    scaled to ``v_max``); ``X0`` (2, N, E) positions; ``travel`` (N, E) m,
    added to in place. Returns (positions (2, N, E), collisions per robot
    (N, E), colliding pairs per env (E,), robots held still by the fallback),
    as :func:`trainer.contacts.move` computes them.
    """
    E, n, _ = actions.shape
    X1 = np.empty((2, n, E))
    U = np.empty((2, n, E))
    hits = np.zeros((n, E), np.int64)
    pairs = np.zeros(E, np.int64)
    touched = np.zeros((n, n), np.bool_)
    limit = two_r - tol
    lim2 = limit * limit
    fallbacks = 0
    for e in range(E):
        for i in range(n):
            vx = actions[e, i, 0]
            vy = actions[e, i, 1]
            s2 = vx * vx + vy * vy
            if not np.isfinite(s2):
                vx = 0.0
                vy = 0.0
                s2 = 0.0
            f = v_max / max(math.sqrt(s2), v_max)
            ux = vx * f * dt
            uy = vy * f * dt
            U[0, i, e] = ux
            U[1, i, e] = uy
            X1[0, i, e] = X0[0, i, e] + ux
            X1[1, i, e] = X0[1, i, e] + uy
        anyhit = False
        for i in range(n):
            for j in range(i + 1, n):
                d0x = X0[0, j, e] - X0[0, i, e]
                d0y = X0[1, j, e] - X0[1, i, e]
                ddx = U[0, j, e] - U[0, i, e]
                ddy = U[1, j, e] - U[1, i, e]
                a = d0x * d0x + d0y * d0y
                b = d0x * ddx + d0y * ddy
                c = ddx * ddx + ddy * ddy
                s = -b / c if c > 0.0 else 0.0
                s = min(max(s, 0.0), 1.0)
                hit = a + s * (2.0 * b + s * c) < lim2
                touched[i, j] = hit
                touched[j, i] = hit
                anyhit |= hit
        if anyhit:
            for i in range(n):
                touched[i, i] = False
            fallbacks += _resolve_env(X0, X1, touched, e, two_r, limit, sweeps, relax)
            total = 0
            for i in range(n):
                h = 0
                for j in range(n):
                    h += touched[i, j]
                hits[i, e] = h
                total += h
            pairs[e] = total // 2
        for i in range(n):
            mx = X1[0, i, e] - X0[0, i, e]
            my = X1[1, i, e] - X0[1, i, e]
            travel[i, e] += math.sqrt(mx * mx + my * my)
    return X1, hits, pairs, fallbacks


def move(
    actions: Any, X0: Array, travel: Array, world: WorldConfig
) -> tuple[Array, IntArray, IntArray, int]:
    """:func:`move_step` with the world's constants; ``actions`` must be (E, N, 2)."""
    shape = (X0.shape[2], X0.shape[1], 2)
    a = np.asarray(actions)
    if a.shape != shape:
        raise ValueError(f"actions must be {shape}, got {a.shape}")
    a = a.astype(np.float64, copy=False)  # as the numpy path: float32 actions widened exactly
    out: tuple[Array, IntArray, IntArray, int] = move_step(
        a, X0, travel, world.v_max_mps, world.dt_s, world.min_separation_m, contacts.CONTACT_TOL_M,
        contacts.CONTACT_SWEEPS, contacts.CONTACT_OVER_RELAX,
    )
    return out


# -------------------------------------------------------------- observation


def observe_general(X: Array, X_prev: Array, G: Array, k: int, world: WorldConfig) -> F32Array:
    """:func:`general_observation` with the world's constants, (E, N, 6 + 5k) float32."""
    reach = world.v_max_mps * world.dt_s  # as the runtime builder computes it
    Xp = np.ascontiguousarray(X_prev)  # a contiguous copy pays for itself in the loop
    return general_observation(X, Xp, G, k, world.dt_s, reach)



@_jit
def general_observation(
    X: Array, X_prev: Array, G: Array, k: int, dt: float, reach: float
) -> F32Array:
    """:func:`runtime.observation.general_observation_env_last` as float32, the same numbers.

    ``X``, ``X_prev``, ``G`` (2, N, E) m; ``reach`` = v_max * dt (m), the
    saturation length of the unit slot step. Returns (E, N, 6 + 5k) float32.
    """
    _, n, E = X.shape
    D = 6 + 5 * k
    out = np.zeros((E, n, D), np.float32)
    m = min(k, n - 1)
    vx = np.empty(n)
    vy = np.empty(n)
    best_d = np.empty(max(m, 1))
    best_j = np.empty(max(m, 1), np.int64)
    px = np.empty(n)
    py = np.empty(n)
    for e in range(E):
        for i in range(n):
            px[i] = X[0, i, e]
            py[i] = X[1, i, e]
            vx[i] = (px[i] - X_prev[0, i, e]) / dt
            vy[i] = (py[i] - X_prev[1, i, e]) / dt
        for i in range(n):
            xi = px[i]
            yi = py[i]
            sx = G[0, i, e] - xi
            sy = G[1, i, e] - yi
            norm = math.sqrt(sx * sx + sy * sy)
            norm = max(norm, reach) if norm == norm else norm
            out[e, i, 0] = sx
            out[e, i, 1] = sy
            out[e, i, 2] = sx / norm
            out[e, i, 3] = sy / norm
            out[e, i, 4] = vx[i]
            out[e, i, 5] = vy[i]
            if m == 0:
                continue
            # the m nearest others, nearest first, ties by robot index (a stable sort)
            filled = 0
            for j in range(n):
                if j == i:
                    continue
                dx = px[j] - xi
                dy = py[j] - yi
                dj = dx * dx + dy * dy
                if filled == m and not dj < best_d[m - 1]:
                    continue
                p = filled if filled < m else m - 1
                while p > 0 and dj < best_d[p - 1]:
                    if p < m:
                        best_d[p] = best_d[p - 1]
                        best_j[p] = best_j[p - 1]
                    p -= 1
                best_d[p] = dj
                best_j[p] = j
                if filled < m:
                    filled += 1
            for r in range(m):
                j = best_j[r]
                base = 6 + 5 * r
                out[e, i, base] = px[j] - xi
                out[e, i, base + 1] = py[j] - yi
                out[e, i, base + 2] = vx[j] - vx[i]
                out[e, i, base + 3] = vy[j] - vy[i]
                out[e, i, base + 4] = 1.0
    return out


__all__ = [
    "assign_env_last",
    "assign_step",
    "general_observation",
    "lsap",
    "move",
    "move_step",
    "observe_general",
    "pairwise_sum",
]
