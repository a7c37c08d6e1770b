# The compiled interface of lsap.py (the function itself is written there, once).
cdef Py_ssize_t solve(double* cost, Py_ssize_t n, long long* prev, bint warm, double* v,
                      double* u, double* spc, long long* path, long long* col4row,
                      long long* row4col, long long* remaining, long long* SR,
                      long long* SC) noexcept
