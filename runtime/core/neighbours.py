# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Which others a robot looks at: its nearest, nearest first, ties by robot id.

The one neighbour choice of the decision: the general observation's k nearest
(:mod:`runtime.core.general_row`) and the ORCA filter's nearest in range
(:mod:`runtime.core.orca`) both call :func:`nearest`. Plain Python in Cython's
pure-Python mode (see :mod:`runtime.core`); ``neighbours.pxd`` declares it for the
compiled callers.
"""

import cython

__all__ = ["nearest"]


@cython.cfunc
@cython.exceptval(check=False)
def nearest(
    pos: cython.const[cython.double][:, :, ::1],
    e0: cython.Py_ssize_t,
    e1: cython.Py_ssize_t,
    i0: cython.Py_ssize_t,
    i1: cython.Py_ssize_t,
    k: cython.Py_ssize_t,
    range_sq: cython.double,
    ids: cython.Py_ssize_t[:, :, ::1],
    d2: cython.double[:, :, ::1],
    count: cython.Py_ssize_t[:, ::1],
) -> cython.void:
    """For robots i0 <= i < i1 of teams e0 <= e < e1: the at most ``k`` nearest others
    closer than ``sqrt(range_sq)`` (m).

    ``pos`` (E, n, 2) positions (m). Writes, at ``[e - e0, i - i0]``, their ids to
    ``ids[..., :m]`` and squared distances (m^2) to ``d2[..., :m]``, nearest first, ties
    by id (a stable sort of the ids by squared distance), and m to ``count``. A
    non-finite distance is never near. O(n k) a robot: one pass over its team, each
    other inserted into the sorted first k.
    """
    n: cython.Py_ssize_t = pos.shape[1]
    e: cython.Py_ssize_t
    i: cython.Py_ssize_t
    a: cython.Py_ssize_t
    b: cython.Py_ssize_t
    m: cython.Py_ssize_t
    j: cython.Py_ssize_t
    p: cython.Py_ssize_t
    px: cython.double
    py: cython.double
    dx: cython.double
    dy: cython.double
    dj: cython.double
    dk: cython.double[::1]
    ik: cython.Py_ssize_t[::1]
    for e in range(e0, e1):
        a = e - e0
        for i in range(i0, i1):
            b = i - i0
            px = pos[e, i, 0]
            py = pos[e, i, 1]
            dk = d2[a, b]  # this robot's rows of the tables: (k,) each
            ik = ids[a, b]
            m = 0
            for j in range(n if k > 0 else 0):
                if j == i:
                    continue
                dx = pos[e, j, 0] - px
                dy = pos[e, j, 1] - py
                dj = dx * dx + dy * dy
                if not dj < range_sq:  # out of range, or not finite
                    continue
                if m == k and not dj < dk[k - 1]:
                    continue
                p = m if m < k else k - 1
                while p > 0 and dj < dk[p - 1]:  # never past an equal distance
                    dk[p] = dk[p - 1]
                    ik[p] = ik[p - 1]
                    p -= 1
                dk[p] = dj
                ik[p] = j
                if m < k:
                    m += 1
            count[a, b] = m
