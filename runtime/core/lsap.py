# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# mypy: disable-error-code="untyped-decorator"
"""The minimum-cost assignment of n robots to n slots, cold or warm: the shared
assignment's solver (:mod:`runtime.core.assignment` calls :func:`solve` for each team).

The solver
    The shortest augmenting path algorithm (Crouse 2016) as scipy's
    ``rectangular_lsap.cpp`` runs it: rows in order, free columns scanned from
    the last down, a tie to a column that ends the path. Cold (no previous
    assignment), it is scipy's solver step for step: the same answer, ties
    included. Warm, it starts from the slot potentials ``v`` of the last step
    (kept by the caller, ``potentials``): ``u[i] = min_j cost[i, j] - v[j]``
    makes them feasible duals, each robot whose previous slot is still tight
    (``cost[i, prev[i]] - v[prev[i]] == u[i]``) keeps it, and only the others
    are augmented. The answer is an optimal assignment, scipy's unless several
    are optimal (exact ties). When every robot's previous slot is still tight
    the duals prove the previous assignment optimal and nothing is augmented:
    :func:`solve` returns 0 (and :func:`runtime.core.assignment.assign_team` 0).

Why the warm solver, and not a proof of the previous assignment then a solve
    The alternative kept the previous assignment where Bellman-Ford over its
    exchange graph (in slot-potential form, up to 3 relaxation rounds) proved
    it within half the hysteresis margin, and solved cold where the proof
    failed. Both were compiled from this source and timed on a loaded 2-core
    machine (per-call medians of :func:`runtime.core.assignment.assign_team`, warm
    from the last step; forming: 40 steps of a circle from random starts at 0.1 m
    a step, formed: the circle with 4 mm of noise a step)::

        n     forming: warm solver / proof + solve   formed: warm / proof
        10         4.8 / 4.4 us                      4.3 / 4.2 us
        50          23 / 37 us                        10 / 8.5 us
        100         85 / 161 us                       24 / 21 us

    A formed team costs both about one pass over the cost (the duals' row
    minima, or one relaxation round): a wash. A forming team's proof fails
    from about 50 robots (its slots' potentials move more per step than a few
    rounds follow) and the whole assignment is then solved again, while the
    warm solver augments only the robots whose slot is no longer their best:
    1.6-1.9x faster. The warm solver is kept.

Layout: the cost (n, n) row by row, float64 (m^2); the potentials and the scratch
(n,) each; slots int64. Plain Python in Cython's pure-Python mode (see
:mod:`runtime.core`); ``lsap.pxd`` declares :func:`solve` for the compiled caller.
"""

import cython

__all__ = ["solve"]

_INF = cython.declare(cython.double, float("inf"))


@cython.cfunc
@cython.exceptval(check=False)
def _augment(
    cost: cython.p_double, n: cython.Py_ssize_t, v: cython.p_double, u: cython.p_double,
    spc: cython.p_double, path: cython.p_longlong, col4row: cython.p_longlong,
    row4col: cython.p_longlong, remaining: cython.p_longlong, SR: cython.p_longlong,
    SC: cython.p_longlong, cur: cython.Py_ssize_t,
) -> cython.Py_ssize_t:
    """One shortest augmenting path from the free row ``cur``, as scipy's solver finds
    it, then the duals' update and the augmentation; -1 if none (infeasible)."""
    it: cython.Py_ssize_t
    j: cython.Py_ssize_t
    t: cython.Py_ssize_t
    index: cython.Py_ssize_t
    num: cython.Py_ssize_t = n
    sink: cython.Py_ssize_t = -1
    i: cython.Py_ssize_t = cur
    min_val: cython.double = 0.0
    lowest: cython.double
    r: cython.double
    for it in range(n):
        remaining[it] = n - it - 1  # reversed: a constant cost gives the identity
        SR[it] = 0
        SC[it] = 0
        spc[it] = _INF
    while sink == -1:
        index = -1
        lowest = _INF
        SR[i] = 1
        for it in range(num):
            j = remaining[it]
            r = min_val + cost[i * n + j] - u[i] - v[j]
            if r < spc[j]:
                path[j] = i
                spc[j] = r
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest = spc[j]
                index = it
        min_val = lowest
        if min_val == _INF or index < 0:
            return -1
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
        SC[j] = 1
        num -= 1
        remaining[index] = remaining[num]
    # the duals' update
    u[cur] += min_val
    for i in range(n):
        if SR[i] != 0 and i != cur:
            u[i] += min_val - spc[col4row[i]]
    for j in range(n):
        if SC[j] != 0:
            v[j] -= min_val - spc[j]
    # the augmentation along the path
    j = sink
    while True:
        i = path[j]
        row4col[j] = i
        t = col4row[i]
        col4row[i] = j
        j = t
        if i == cur:
            break
    return sink


@cython.cfunc
@cython.exceptval(check=False)
def solve(
    cost: cython.p_double, n: cython.Py_ssize_t, prev: cython.p_longlong, warm: cython.bint,
    v: cython.p_double, u: cython.p_double, spc: cython.p_double, path: cython.p_longlong,
    col4row: cython.p_longlong, row4col: cython.p_longlong, remaining: cython.p_longlong,
    SR: cython.p_longlong, SC: cython.p_longlong,
) -> cython.Py_ssize_t:
    """A minimum-cost assignment into ``col4row``: cold (scipy's solver, ``v`` zeroed)
    or warm from the slot potentials ``v`` and the previous slots ``prev`` (a
    permutation). Returns the rows augmented (0: ``prev`` is proven optimal), -1 when
    the cost holds NaN or -inf or has no finite assignment. ``v`` is updated.

    ``cost`` the (n, n) costs row by row (``cost[i * n + j]``, m^2); the rest (n,)
    each. Pointers when compiled (no view passed from module to module), flat arrays
    as Python."""
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    c: cython.double
    m: cython.double
    r: cython.double
    top: cython.double
    solved: cython.Py_ssize_t = 0
    for i in range(n):
        col4row[i] = -1
        row4col[i] = -1
        u[i] = 0.0
    if warm:
        for j in range(n):
            if not (v[j] - v[j] == 0.0):  # a non-finite potential: start cold
                warm = False
    if warm:  # u: the potentials v made feasible; the previous slots still tight kept
        for i in range(n):
            m = _INF
            for j in range(n):
                c = cost[i * n + j]
                if c != c or c == -_INF:
                    return -1
                r = c - v[j]
                if r < m:
                    m = r
            if m == _INF:  # a robot without a finite cost
                return -1
            u[i] = m
            j = prev[i]
            if row4col[j] == -1 and cost[i * n + j] - v[j] == m:
                col4row[i] = j
                row4col[j] = i
    else:
        for i in range(n):
            for j in range(n):
                c = cost[i * n + j]
                if c != c or c == -_INF:
                    return -1
        for j in range(n):
            v[j] = 0.0
    for i in range(n):
        if col4row[i] != -1:
            continue
        if _augment(cost, n, v, u, spc, path, col4row, row4col, remaining, SR, SC, i) < 0:
            return -1
        solved += 1
    if solved > 0:  # only differences count: keep the numbers small
        top = v[0]
        for j in range(1, n):
            if v[j] > top:
                top = v[j]
        for j in range(n):
            v[j] -= top
    return solved
