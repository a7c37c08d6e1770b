# The compiled interface of neighbours.py (the function itself is written there, once).
cdef void nearest(const double[:, :, ::1] pos, Py_ssize_t e0, Py_ssize_t e1, Py_ssize_t i0,
                  Py_ssize_t i1, Py_ssize_t k, double range_sq, Py_ssize_t[:, :, ::1] ids,
                  double[:, :, ::1] d2, Py_ssize_t[:, ::1] count) noexcept
