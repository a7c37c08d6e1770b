# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The general (and plan) observation row: written once, for one robot or E teams.

Layout per robot, dim = 6 + 5k (the ``general`` spec of :mod:`runtime.decision.observation`)::

    0:2   slot vector: own slot minus own position (m)
    2:4   slot vector / max(|slot vector|, v_max dt): the straight-line step, at most
          unit length; for the ``plan`` spec slot vector / (K v_max dt), the plan's
          step in units of v_max (K: the plan's steps left)
    4:6   own velocity estimate (m/s)
    6:    the k nearest others, nearest first (ties by id), each [dx, dy, dvx, dvy, 1]:
          relative position (m), relative velocity (m/s), present; zeros beyond n - 1

:class:`GeneralRows` builds them: :meth:`~GeneralRows.robot` one robot's row (the
robot's own step), :meth:`~GeneralRows.teams` every row of E teams (``eval``, the
training world), both through the same loop. Rows are float32 (what a brain reads) or
float64. Plain Python in Cython's pure-Python mode (see :mod:`runtime.core`).
"""

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.libc.math import INFINITY, sqrt
    from cython.cimports.runtime.core.neighbours import nearest
else:
    from math import inf as INFINITY
    from math import sqrt

    from runtime.core.neighbours import nearest

__all__ = ["FIXED", "PER_NEIGHBOUR", "GeneralRows"]

FIXED = 6
"""Columns before the neighbours."""
PER_NEIGHBOUR = 5
"""Columns per neighbour."""
_FIXED = cython.declare(cython.Py_ssize_t, 6)  # the same two, as C constants
_PER = cython.declare(cython.Py_ssize_t, 5)


@cython.cclass
class GeneralRows:
    """The row builder of one spec width: ``k`` neighbours, ``reach_m`` = v_max dt (m). Holds
    its scratch: one per robot or per batch, not shared between threads."""

    k: cython.Py_ssize_t
    reach: cython.double
    _ids: cython.Py_ssize_t[:, :, ::1]
    _d2: cython.double[:, :, ::1]
    _count: cython.Py_ssize_t[:, ::1]
    _slot1: cython.double[:, :, ::1]
    _pace1: cython.double[::1]

    def __init__(self, k: int, reach_m: float) -> None:
        if k < 0:
            raise ValueError(f"k must be >= 0, got {k}")
        self.k = k
        self.reach = reach_m
        self._ids = None  # the neighbour tables, made for the first batch's shape
        self._scratch(1, 1)
        self._slot1 = np.zeros((1, 1, 2))  # a robot's slot and pace, as a batch of one
        self._pace1 = np.zeros(1)

    def _scratch(self, E: int, n: int) -> None:
        if self._ids is None or self._ids.shape[0] != E or self._ids.shape[1] != n:
            self._ids = np.zeros((E, n, max(self.k, 1)), dtype=np.intp)
            self._d2 = np.zeros((E, n, max(self.k, 1)))
            self._count = np.zeros((E, n), dtype=np.intp)

    @property
    def dim(self) -> int:
        """The row's width, 6 + 5k."""
        return FIXED + PER_NEIGHBOUR * self.k

    @cython.cfunc
    def _rows(self, pos: cython.const[cython.double][:, :, ::1],
              vel: cython.const[cython.double][:, :, ::1],
              slots: cython.const[cython.double][:, :, ::1], pace: cython.const[cython.double][::1],
              e0: cython.Py_ssize_t, e1: cython.Py_ssize_t, i0: cython.Py_ssize_t,
              i1: cython.Py_ssize_t, out: cython.floating[:, :, ::1]) -> cython.void:
        """Rows of robots i0 <= i < i1 of teams e0 <= e < e1 into ``out[e - e0, i - i0]``;
        ``slots`` and ``pace`` indexed the same way, ``pos`` and ``vel`` by team and robot."""
        k: cython.Py_ssize_t = self.k
        reach: cython.double = self.reach
        ids = self._ids
        count = self._count
        e: cython.Py_ssize_t
        i: cython.Py_ssize_t
        a: cython.Py_ssize_t
        b: cython.Py_ssize_t
        c: cython.Py_ssize_t
        j: cython.Py_ssize_t
        o: cython.Py_ssize_t
        px: cython.double
        py: cython.double
        svx: cython.double
        svy: cython.double
        norm: cython.double
        vix: cython.double
        viy: cython.double
        nearest(pos, e0, e1, i0, i1, k, INFINITY, ids, self._d2, count)
        for e in range(e0, e1):
            a = e - e0
            for i in range(i0, i1):
                b = i - i0
                px = pos[e, i, 0]
                py = pos[e, i, 1]
                svx = slots[a, b, 0] - px
                svy = slots[a, b, 1] - py
                vix = vel[e, i, 0]
                viy = vel[e, i, 1]
                out[a, b, 0] = svx
                out[a, b, 1] = svy
                if pace[a] > 0.0:  # the plan's step
                    out[a, b, 2] = svx / pace[a]
                    out[a, b, 3] = svy / pace[a]
                else:  # the straight-line step, at most unit length
                    norm = sqrt(svx * svx + svy * svy)
                    if not norm > reach:
                        norm = reach
                    out[a, b, 2] = svx / norm
                    out[a, b, 3] = svy / norm
                out[a, b, 4] = vix
                out[a, b, 5] = viy
                for c in range(count[a, b]):
                    j = ids[a, b, c]
                    o = _FIXED + _PER * c
                    out[a, b, o] = pos[e, j, 0] - px
                    out[a, b, o + 1] = pos[e, j, 1] - py
                    out[a, b, o + 2] = vel[e, j, 0] - vix
                    out[a, b, o + 3] = vel[e, j, 1] - viy
                    out[a, b, o + 4] = 1.0
                for o in range(_FIXED + _PER * count[a, b], _FIXED + _PER * k):
                    out[a, b, o] = 0.0

    @cython.cfunc
    def _robot(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t,
               pos: cython.const[cython.double][:, :, ::1],
               vel: cython.const[cython.double][:, :, ::1], sx: cython.double,
               sy: cython.double, pace: cython.double, out: cython.floating[:, :, ::1]
               ) -> cython.void:
        if not (0 <= e < pos.shape[0] and 0 <= i < pos.shape[1]) \
                or vel.shape[0] != pos.shape[0] or vel.shape[1] != pos.shape[1] \
                or out.shape[0] < 1 or out.shape[1] < 1 \
                or out.shape[2] != _FIXED + _PER * self.k:
            raise ValueError("general row: robot index, velocities or row width do not fit")
        self._slot1[0, 0, 0] = sx
        self._slot1[0, 0, 1] = sy
        self._pace1[0] = pace
        self._rows(pos, vel, self._slot1, self._pace1, e, e + 1, i, i + 1, out)

    @cython.ccall
    def robot(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t,
              pos: cython.const[cython.double][:, :, ::1],
              vel: cython.const[cython.double][:, :, ::1], sx: cython.double,
              sy: cython.double, pace: cython.double, out: cython.float[:, :, ::1]
              ) -> cython.void:
        """Robot i of team e: its row into ``out`` (1, 1, 6 + 5k) float32, a batch of one
        row as a brain reads it (:meth:`robot_f64` for float64).

        ``pos``, ``vel`` (E, n, 2): the teams' positions (m) and velocity estimates (m/s),
        a robot passing its one team as E = 1; (sx, sy): robot i's slot (m); ``pace``:
        K v_max dt for the plan spec (m), 0 for the general one.
        """
        self._robot(e, i, pos, vel, sx, sy, pace, out)

    @cython.ccall
    def robot_f64(self, e: cython.Py_ssize_t, i: cython.Py_ssize_t,
                  pos: cython.const[cython.double][:, :, ::1],
                  vel: cython.const[cython.double][:, :, ::1], sx: cython.double,
                  sy: cython.double, pace: cython.double, out: cython.double[:, :, ::1]
                  ) -> cython.void:
        """:meth:`robot` into a float64 row."""
        self._robot(e, i, pos, vel, sx, sy, pace, out)

    def teams(self, pos: cython.const[cython.double][:, :, ::1],
              vel: cython.const[cython.double][:, :, ::1],
              slots: cython.const[cython.double][:, :, ::1], pace: cython.const[cython.double][::1],
              out: cython.floating[:, :, ::1]) -> None:
        """Every robot's row of E teams into ``out`` (E, n, 6 + 5k).

        ``pos``, ``vel``, ``slots`` (E, n, 2): positions (m), velocity estimates (m/s),
        each robot's slot (m); ``pace`` (E,): each team's K v_max dt (m), or 0 (general).
        """
        E: cython.Py_ssize_t = pos.shape[0]
        n: cython.Py_ssize_t = pos.shape[1]
        if vel.shape[0] != E or slots.shape[0] != E or out.shape[0] != E \
                or pace.shape[0] != E or vel.shape[1] != n or slots.shape[1] != n \
                or out.shape[1] != n or out.shape[2] != FIXED + PER_NEIGHBOUR * self.k:
            raise ValueError("general rows: the arrays' shapes do not fit")
        self._scratch(E, n)
        self._rows(pos, vel, slots, pace, 0, E, 0, n, out)
