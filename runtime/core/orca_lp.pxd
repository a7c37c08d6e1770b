# The compiled interface of orca_lp.py (the code itself is written there, once).
cdef (double, double) clamp(double vx, double vy, double v_max) noexcept


cdef class LinearProgram:
    cdef double[:, ::1] lines
    cdef double[::1] out
    cdef double[:, ::1] _proj
    cdef double[::1] _found

    cdef void solve(self, Py_ssize_t m, double radius, double ox, double oy) noexcept
