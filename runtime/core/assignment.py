# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
# mypy: disable-error-code="untyped-decorator"
"""The shared slot assignment: cost, solver (warm), hysteresis. One source for all.

Every robot computes the same assignment of robots to pattern slots from the same
poses: centre the team and the pattern, ``cost[i, j]`` = squared distance (m^2) of
centred robot i to centred slot j (:func:`team_cost`), a minimum-cost assignment
(what ``scipy.optimize.linear_sum_assignment`` returns, ties included), and the
hysteresis rule (:func:`runtime.decision.formation.keeps_previous`): the previous assignment
is kept unless the new one's summed cost is lower by more than
``HYSTERESIS_REL * old + HYSTERESIS_ABS_M2``. The robot calls :func:`assign_team`
for its team (through :class:`TeamAssignment`, which keeps its state), the training
world :func:`assign_teams` for a batch of teams, and
:mod:`runtime.decision.formation` :func:`assign_costs` for costs it built itself; all three
run the same per-team code.

The solver
    :func:`runtime.core.lsap.solve`: scipy's shortest augmenting path, cold (scipy's
    answer, ties included) or warm from the slot potentials of the last step (kept by
    the caller, ``potentials``), where only the robots whose previous slot is no longer
    tight are augmented; why warm, and its timings, are written there. When every
    robot's previous slot is still tight the potentials prove the previous assignment
    optimal and nothing is augmented: :func:`assign_team` returns 0. The hysteresis
    rule is then applied to the two assignments' summed costs, summed in numpy's order
    (:func:`path_cost`), so the result is the rule's on scipy's answer.

Layouts: a team's positions (n, 2), costs (n, n) C-contiguous, slots and
potentials (n,); a batch adds a leading team axis (E, ...), any strides (the
training world passes transposed views of its robot-major arrays). Slots are
int64, everything else float64, metres and m^2.

Plain Python in Cython's pure-Python mode (see :mod:`runtime.core`): compiled it
runs as C without a Python operation per team or robot, calling the compiled solver
(declared in ``lsap.pxd``); as Python the same operations give the same numbers,
slower.
"""

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.runtime.core.lsap import solve
else:
    from runtime.core.lsap import solve

__all__ = [
    "HYSTERESIS_ABS_M2",
    "HYSTERESIS_REL",
    "TeamAssignment",
    "assign_costs",
    "assign_team",
    "assign_teams",
    "path_cost",
    "team_cost",
]

HYSTERESIS_REL = 1e-3
"""Keep the previous assignment unless the new one lowers the summed squared distance
by more than this fraction of the previous one's (plus :data:`HYSTERESIS_ABS_M2`)."""
HYSTERESIS_ABS_M2 = 1e-6
"""The hysteresis margin's absolute floor (m^2)."""

# the rule's constants as C values, for the compiled loops
_REL = cython.declare(cython.double, HYSTERESIS_REL)
_ABS = cython.declare(cython.double, HYSTERESIS_ABS_M2)
# assign_team's scratch when compiled (grown to the largest team seen)
_FW = cython.declare(cython.double[:, ::1], np.empty((2, 0)))
_IW = cython.declare(cython.longlong[:, ::1], np.empty((6, 0), dtype=np.int64))


@cython.cfunc
@cython.exceptval(check=False)
def _pairwise(a: cython.double[::1], lo: cython.Py_ssize_t, n: cython.Py_ssize_t) -> cython.double:
    """``a[lo:lo + n]`` summed in numpy's order (``np.add.reduce`` along a contiguous
    axis: one by one below 8 values, 8 interleaved partial sums up to 128, halves above)."""
    i: cython.Py_ssize_t
    res: cython.double
    r0: cython.double
    r1: cython.double
    r2: cython.double
    r3: cython.double
    r4: cython.double
    r5: cython.double
    r6: cython.double
    r7: cython.double
    n2: cython.Py_ssize_t
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    if n <= 128:
        r0 = a[lo]
        r1 = a[lo + 1]
        r2 = a[lo + 2]
        r3 = a[lo + 3]
        r4 = a[lo + 4]
        r5 = a[lo + 5]
        r6 = a[lo + 6]
        r7 = a[lo + 7]
        i = 8
        while i < n - (n % 8):
            r0 += a[lo + i]
            r1 += a[lo + i + 1]
            r2 += a[lo + i + 2]
            r3 += a[lo + i + 3]
            r4 += a[lo + i + 4]
            r5 += a[lo + i + 5]
            r6 += a[lo + i + 6]
            r7 += a[lo + i + 7]
            i += 8
        res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while i < n:
            res += a[lo + i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise(a, lo, n2) + _pairwise(a, lo + n2, n - n2)


@cython.cfunc
@cython.exceptval(check=False)
def _sum_taken(cost: cython.double[:, ::1], slots: cython.longlong[::1],
               work: cython.double[::1]) -> cython.double:
    """``sum_i cost[i, slots[i]]`` in numpy's order (``work`` (n,) the scratch)."""
    n: cython.Py_ssize_t = cost.shape[0]
    i: cython.Py_ssize_t
    for i in range(n):
        work[i] = cost[i, slots[i]]
    return _pairwise(work, 0, n)


@cython.cfunc
@cython.exceptval(check=False)
def _is_permutation(p: cython.longlong[::1], seen: cython.longlong[::1]) -> cython.bint:
    """Whether ``p`` (n,) is a permutation of 0..n-1 (``seen`` (n,) the scratch)."""
    n: cython.Py_ssize_t = p.shape[0]
    i: cython.Py_ssize_t
    s: cython.longlong
    for i in range(n):
        seen[i] = 0
    for i in range(n):
        s = p[i]
        if s < 0 or s >= n or seen[s] != 0:
            return False
        seen[s] = 1
    return True


@cython.cfunc
@cython.exceptval(check=False)
def _centred_cost(pos: cython.double[:, :], ccx: cython.double[::1], ccy: cython.double[::1],
                  cost: cython.double[:, ::1]) -> tuple[cython.double, cython.double]:
    """The team's centroid (pos summed robot by robot, / n) and
    ``cost[i, j] = |pos[i] - centroid - cc[j]|^2`` (m^2)."""
    n: cython.Py_ssize_t = pos.shape[0]
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    sx: cython.double = 0.0
    sy: cython.double = 0.0
    cx: cython.double
    cy: cython.double
    px: cython.double
    py: cython.double
    dx: cython.double
    dy: cython.double
    for i in range(n):
        sx += pos[i, 0]
        sy += pos[i, 1]
    cx = sx / n
    cy = sy / n
    for i in range(n):
        px = pos[i, 0] - cx
        py = pos[i, 1] - cy
        for j in range(n):
            dx = px - ccx[j]
            dy = py - ccy[j]
            cost[i, j] = dx * dx + dy * dy
    return cx, cy


@cython.cfunc
@cython.exceptval(check=False)
def _assign_one(
    cost: cython.double[:, ::1], prev: cython.longlong[::1], has_prev: cython.bint,
    v: cython.double[::1], slots: cython.longlong[::1], fw: cython.double[:, ::1],
    iw: cython.longlong[:, ::1],
) -> cython.int:
    """:func:`assign_team` with its scratch: ``fw`` (2, n), ``iw`` (6, n)."""
    n: cython.Py_ssize_t = cost.shape[0]
    i: cython.Py_ssize_t
    u: cython.double[::1] = fw[0]
    spc: cython.double[::1] = fw[1]
    col4row: cython.longlong[::1] = iw[1]
    SR: cython.longlong[::1] = iw[4]
    valid: cython.bint = has_prev and _is_permutation(prev, SR)
    got: cython.Py_ssize_t
    if cython.compiled:  # the rows by pointer: no view copied into the solver's module
        got = solve(cython.address(cost[0, 0]), n, cython.address(prev[0]), valid,
                    cython.address(v[0]), cython.address(u[0]), cython.address(spc[0]),
                    cython.address(iw[0, 0]), cython.address(col4row[0]),
                    cython.address(iw[2, 0]), cython.address(iw[3, 0]), cython.address(SR[0]),
                    cython.address(iw[5, 0]))
    else:  # as Python, the cost flat
        got = solve(np.ravel(cost), n, prev, valid, v, u, spc, iw[0], col4row, iw[2], iw[3],
                    SR, iw[5])
    same: cython.bint
    new: cython.double
    old: cython.double
    if got < 0:  # no finite assignment: the previous slots, or the identity
        for i in range(n):
            v[i] = 0.0
            slots[i] = prev[i] if valid else i
        return -1
    if valid and got == 0:  # every previous slot still tight: proven optimal
        for i in range(n):
            slots[i] = prev[i]
        return 0
    if valid:
        same = True
        for i in range(n):
            if col4row[i] != prev[i]:
                same = False
                break
        if not same:  # the hysteresis rule (runtime.decision.formation.keeps_previous)
            new = _sum_taken(cost, col4row, spc)
            old = _sum_taken(cost, prev, spc)
            if not (new < old - (_REL * old + _ABS)):
                for i in range(n):
                    slots[i] = prev[i]
                return 1
    for i in range(n):
        slots[i] = col4row[i]
    return 1


@cython.cfunc
def _teams(
    pos: cython.double[:, :, :], pattern: cython.double[:, :, :],
    given: cython.double[:, :, ::1], prev: cython.longlong[:, :], has_prev: cython.bint,
    potentials: cython.double[:, :], slots: cython.longlong[:, :],
) -> cython.Py_ssize_t:
    """The loop over teams of :func:`assign_teams` (``pos``, ``pattern``) and
    :func:`assign_costs` (``given``: the costs; ``pos`` and ``pattern`` then unused).
    Each team's rows are copied into contiguous scratch and back: no view per team."""
    E: cython.Py_ssize_t = prev.shape[0]
    n: cython.Py_ssize_t = prev.shape[1]
    use_given: cython.bint = given.shape[0] == E
    cost: cython.double[:, ::1] = np.empty((n, n))
    fw: cython.double[:, ::1] = np.empty((2, n))
    iw: cython.longlong[:, ::1] = np.empty((6, n), dtype=np.int64)
    tp: cython.double[:, ::1] = np.empty((n, 2))  # one team's positions
    tf: cython.double[:, ::1] = np.empty((3, n))  # its pattern's columns, its potentials
    ti: cython.longlong[:, ::1] = np.empty((2, n), dtype=np.int64)  # its prev, its slots
    ccx: cython.double[::1] = tf[0]
    ccy: cython.double[::1] = tf[1]
    tv: cython.double[::1] = tf[2]
    tprev: cython.longlong[::1] = ti[0]
    tslots: cython.longlong[::1] = ti[1]
    e: cython.Py_ssize_t
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    solved: cython.Py_ssize_t = 0
    for e in range(E):
        if use_given:
            for i in range(n):
                for j in range(n):
                    cost[i, j] = given[e, i, j]
        else:
            for i in range(n):
                tp[i, 0] = pos[e, i, 0]
                tp[i, 1] = pos[e, i, 1]
                ccx[i] = pattern[e, i, 0]
                ccy[i] = pattern[e, i, 1]
            _centred_cost(tp, ccx, ccy, cost)
        for i in range(n):
            tprev[i] = prev[e, i]
            tv[i] = potentials[e, i]
        if _assign_one(cost, tprev, has_prev, tv, tslots, fw, iw) != 0:
            solved += 1
        for i in range(n):
            slots[e, i] = tslots[i]
            potentials[e, i] = tv[i]
    return solved


@cython.cclass
class TeamAssignment:
    """One robot's assignment from step to step: the centred pattern's columns, the cost,
    the last slots and their potentials (the solver's warm start), and the scratch.

    The robot's path of :func:`team_cost` then :func:`assign_team` with nothing but the
    positions passed in a step. Not shared between threads.
    """

    _ccx: cython.double[::1]
    _ccy: cython.double[::1]
    _cost: cython.double[:, ::1]
    _v: cython.double[::1]
    _prev: cython.longlong[::1]
    _fw: cython.double[:, ::1]
    _iw: cython.longlong[:, ::1]
    _has_prev: cython.bint

    def __init__(self, pattern_centred: np.ndarray) -> None:
        """``pattern_centred`` (n, 2): the team's pattern minus its centroid (m)."""
        cc = np.asarray(pattern_centred, dtype=np.float64)
        if cc.ndim != 2 or cc.shape[1] != 2:
            raise ValueError(f"pattern must have shape (n, 2), got {cc.shape}")
        n = cc.shape[0]
        self._ccx = np.ascontiguousarray(cc[:, 0])
        self._ccy = np.ascontiguousarray(cc[:, 1])
        self._cost = np.empty((n, n))
        self._v = np.zeros(n)
        self._prev = np.zeros(n, dtype=np.int64)
        self._fw = np.empty((2, n))
        self._iw = np.empty((6, n), dtype=np.int64)
        self._has_prev = False

    def step(self, pos: cython.double[:, ::1], slots: cython.longlong[::1]
             ) -> tuple[cython.double, cython.double]:
        """This step's slots into ``slots`` (n,), with the hysteresis rule against the last
        step's; returns the team's centroid (cx, cy) (m). ``pos`` (n, 2) positions (m)."""
        n: cython.Py_ssize_t = self._ccx.shape[0]
        i: cython.Py_ssize_t
        if pos.shape[0] != n or pos.shape[1] != 2 or slots.shape[0] != n:
            raise ValueError("team assignment: the team and the pattern differ in size")
        cx: cython.double
        cy: cython.double
        cx, cy = _centred_cost(pos, self._ccx, self._ccy, self._cost)
        _assign_one(self._cost, self._prev, self._has_prev, self._v, slots, self._fw, self._iw)
        for i in range(n):
            self._prev[i] = slots[i]
        self._has_prev = True
        return cx, cy


def team_cost(
    pos: cython.double[:, ::1],
    ccx: cython.double[::1],
    ccy: cython.double[::1],
    cost: cython.double[:, ::1],
) -> tuple[float, float]:
    """The assignment's cost of one team, and its centroid.

    ``pos`` (n, 2) positions (m); ``ccx``, ``ccy`` (n,) the centred pattern's
    columns; ``cost`` (n, n) out: ``cost[i, j] = |pos[i] - c - cc[j]|^2`` (m^2) with
    ``c`` the team's centroid, returned as (cx, cy): ``np.add.reduce(pos, 0) / n``
    (the positions summed robot by robot).
    """
    n: cython.Py_ssize_t = pos.shape[0]
    if ccx.shape[0] != n or ccy.shape[0] != n or cost.shape[0] != n or cost.shape[1] != n:
        raise ValueError("team_cost: the team, the pattern and the cost differ in size")
    if pos.shape[1] != 2:
        raise ValueError("team_cost: positions must be (n, 2)")
    cx: cython.double
    cy: cython.double
    cx, cy = _centred_cost(pos, ccx, ccy, cost)
    return cx, cy


def assign_team(
    cost: cython.double[:, ::1],
    prev: cython.longlong[::1],
    has_prev: cython.bint,
    potentials: cython.double[::1],
    slots: cython.longlong[::1],
) -> int:
    """One team's shared assignment, with the hysteresis rule.

    ``cost`` (n, n) m^2, ``[i, j]`` robot i to slot j (:func:`team_cost`);
    ``prev`` (n,) the last step's slots, ignored when ``has_prev`` is False or it is
    not a permutation of 0..n-1; ``potentials`` (n,) the solver's slot potentials
    (m^2), kept by the caller from step to step and updated here (zeros at first,
    or after the team's size changes); ``slots`` (n,) out, ``slots[i]`` robot i's
    slot (it may be ``prev`` itself). The result is scipy's assignment with the
    rule applied (ties aside).

    Returns 1 when the solver augmented (the rule then chose between its answer
    and ``prev``), 0 when ``prev`` was proven optimal by the potentials alone
    (kept, nothing solved), -1 when the cost holds NaN or -inf or has no finite
    assignment (then ``slots`` is ``prev`` if valid, else the identity, and the
    potentials are zeroed).
    """
    n: cython.Py_ssize_t = cost.shape[0]
    if (cost.shape[1] != n or prev.shape[0] != n or potentials.shape[0] != n
            or slots.shape[0] != n):
        raise ValueError("assign_team: cost, prev, potentials and slots differ in size")
    global _FW, _IW
    fw: cython.double[:, ::1]
    iw: cython.longlong[:, ::1]
    if cython.compiled:  # the GIL is held throughout: one scratch serves every call
        if _FW.shape[1] < n:
            _FW = np.empty((2, n))
            _IW = np.empty((6, n), dtype=np.int64)
        fw, iw = _FW, _IW
    else:  # as Python, threads may interleave: a scratch per call
        fw, iw = np.empty((2, n)), np.empty((6, n), dtype=np.int64)
    res: cython.int = _assign_one(cost, prev, has_prev, potentials, slots, fw, iw)
    return int(res)


def assign_teams(
    pos: cython.double[:, :, :],
    pattern_centred: cython.double[:, :, :],
    prev: cython.longlong[:, :],
    has_prev: cython.bint,
    potentials: cython.double[:, :],
    slots: cython.longlong[:, :],
) -> int:
    """:func:`team_cost` then :func:`assign_team` for each of E teams of n robots.

    ``pos`` (E, n, 2) m; ``pattern_centred`` (E, n, 2) each team's pattern,
    centred; ``prev`` (E, n) (``has_prev`` for all teams); ``potentials`` (E, n)
    in/out; ``slots`` (E, n) out (it may be ``prev`` itself). Any strides: the
    training world passes views of its robot-major arrays. Returns the teams the
    solver ran for (those whose previous slots were not proven optimal).
    """
    E: cython.Py_ssize_t = pos.shape[0]
    n: cython.Py_ssize_t = pos.shape[1]
    if (pos.shape[2] != 2 or pattern_centred.shape[0] != E or pattern_centred.shape[1] != n
            or pattern_centred.shape[2] != 2 or prev.shape[0] != E or prev.shape[1] != n
            or potentials.shape[0] != E or potentials.shape[1] != n
            or slots.shape[0] != E or slots.shape[1] != n):
        raise ValueError("assign_teams: positions, pattern, prev, potentials, slots differ")
    none: cython.double[:, :, ::1] = np.empty((0, 0, 0))
    return int(_teams(pos, pattern_centred, none, prev, has_prev, potentials, slots))


def assign_costs(
    cost: cython.double[:, :, ::1],
    prev: cython.longlong[:, :],
    has_prev: cython.bint,
    potentials: cython.double[:, :],
    slots: cython.longlong[:, :],
) -> int:
    """:func:`assign_team` for each of E teams whose costs are given: ``cost`` (E, n, n)
    m^2; ``prev``, ``potentials`` (in/out), ``slots`` (out) (E, n), any strides.
    Returns the teams the solver ran for."""
    E: cython.Py_ssize_t = cost.shape[0]
    n: cython.Py_ssize_t = cost.shape[1]
    if (cost.shape[2] != n or prev.shape[0] != E or prev.shape[1] != n
            or potentials.shape[0] != E or potentials.shape[1] != n
            or slots.shape[0] != E or slots.shape[1] != n):
        raise ValueError("assign_costs: cost, prev, potentials and slots differ in size")
    if E == 0:
        return 0
    none: cython.double[:, :, :] = np.empty((0, 0, 2))
    return int(_teams(none, none, cost, prev, has_prev, potentials, slots))


def path_cost(cost: cython.double[:, ::1], slots: cython.longlong[::1]) -> float:
    """``sum_i cost[i, slots[i]]`` (m^2) as ``cost[arange(n), slots].sum()`` sums it
    (numpy's pairwise order): the sums the hysteresis rule compares."""
    n: cython.Py_ssize_t = cost.shape[0]
    if cost.shape[1] != n or slots.shape[0] != n:
        raise ValueError("path_cost: cost and slots differ in size")
    i: cython.Py_ssize_t
    for i in range(n):
        if slots[i] < 0 or slots[i] >= n:
            raise ValueError("path_cost: a slot out of range")
    work: cython.double[::1] = np.empty(n)
    res: cython.double = _sum_taken(cost, slots, work)
    return float(res)
