/* runtime._kernel: one robot's decision, compiled (see runtime/kernel.py).
 *
 * The same IEEE operations, in the same order, as the Python reference they
 * stand for: runtime.rules.PlanFrame._solve_lists (and
 * runtime.formation._min_enclosing_circle), runtime.observation.neighbour_order
 * and general_row, runtime.decision._near_in_order and runtime.safety's ORCA
 * filter (RVO2's computeNewVelocity, agent-agent part). Built with
 * -ffp-contract=off so no multiply-add is fused. Tests hold the two paths
 * equal (tests/unit/test_kernel.py).
 *
 * Arrays arrive through the buffer protocol (numpy arrays, C-contiguous):
 * float64 positions, int64 ('q' or 'l') orders and supports, a float32 or float64 row.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define KERNEL_VERSION 2
#define MAX_NEAR 64          /* ORCA neighbours at most (OrcaParams.max_neighbours) */
#define RVO_EPS 1e-5
#define CHANGE_TOL 1e-9
#define STEP_TOL 1e-9
#define SUPPORT_SLACK_M 1e-4

/* ------------------------------------------------------------ buffers */

typedef struct {
    Py_buffer view;
    int held;
} Buf;

static int get_buf(PyObject *obj, Buf *b, const char *fmt, Py_ssize_t min_items,
                   int writable, const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) != 0)
        return -1;
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (f[0] == '<' || f[0] == '=' || f[0] == '@')
        f++;
    int ok = 0;
    for (const char *c = fmt; *c; c++)
        if (f[0] == *c && f[1] == '\0')
            ok = 1;
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "%s: expected format '%s', got '%s'", what, fmt, f);
        return -1;
    }
    if ((f[0] == 'q' || f[0] == 'l') && b->view.itemsize != 8) {
        PyErr_Format(PyExc_TypeError, "%s: expected 64-bit integers", what);
        return -1;
    }
    if (b->view.len / b->view.itemsize < min_items) {
        PyErr_Format(PyExc_ValueError, "%s: %zd items, need %zd", what,
                     b->view.len / b->view.itemsize, min_items);
        return -1;
    }
    return 0;
}

static void release(Buf *b)
{
    if (b->held) {
        PyBuffer_Release(&b->view);
        b->held = 0;
    }
}

static Py_ssize_t items(const Buf *b) { return b->view.len / b->view.itemsize; }

static int args_n(Py_ssize_t nargs, Py_ssize_t want, const char *name)
{
    if (nargs != want) {
        PyErr_Format(PyExc_TypeError, "%s() takes %zd arguments (%zd given)", name, want, nargs);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------- speed clamp (safety.clamp_speed) */

static void clamp_speed(double *vx, double *vy, double v_max)
{
    double sp = hypot(*vx, *vy);
    if (sp > v_max) {
        double s = v_max / sp;
        *vx = *vx * s;
        *vy = *vy * s;
        for (;;) {
            double a = hypot(*vx, *vy), b = sqrt(*vx * *vx + *vy * *vy);
            if (!((a > b ? a : b) > v_max))
                break;
            *vx = *vx * (1.0 - 1e-15);
            *vy = *vy * (1.0 - 1e-15);
        }
    }
}

/* ---------------------------------------- smallest enclosing circle (formation.py) */

typedef struct { double x, y, r; } Circle;

static Circle circ2(const double *a, const double *b)
{
    Circle c;
    c.x = (a[0] + b[0]) / 2;
    c.y = (a[1] + b[1]) / 2;
    c.r = hypot(a[0] - c.x, a[1] - c.y);
    return c;
}

static Circle circ3(const double *a, const double *b, const double *c)
{
    double ax = a[0], ay = a[1];
    double bx = b[0] - ax, by = b[1] - ay;
    double cx = c[0] - ax, cy = c[1] - ay;
    double d = 2 * (bx * cy - by * cx);
    if (fabs(d) < 1e-18) { /* collinear: the widest pair (the first of equals) */
        Circle k[3] = {circ2(a, b), circ2(a, c), circ2(b, c)};
        Circle best = k[0];
        for (int i = 1; i < 3; i++)
            if (k[i].r > best.r)
                best = k[i];
        return best;
    }
    double ux = (cy * (bx * bx + by * by) - by * (cx * cx + cy * cy)) / d;
    double uy = (bx * (cx * cx + cy * cy) - cx * (bx * bx + by * by)) / d;
    Circle out = {ux + ax, uy + ay, hypot(ux, uy)};
    return out;
}

static int inside(Circle c, const double *q)
{
    return hypot(q[0] - c.x, q[1] - c.y) <= c.r * (1 + 1e-12) + 1e-12;
}

/* p: m points (x, y) */
static Circle min_circle(const double *p, Py_ssize_t m)
{
    Circle c = {p[0], p[1], 0.0};
    for (Py_ssize_t i = 1; i < m; i++) {
        if (inside(c, p + 2 * i))
            continue;
        c.x = p[2 * i];
        c.y = p[2 * i + 1];
        c.r = 0.0;
        for (Py_ssize_t j = 0; j < i; j++) {
            if (inside(c, p + 2 * j))
                continue;
            c = circ2(p + 2 * i, p + 2 * j);
            for (Py_ssize_t k = 0; k < j; k++)
                if (!inside(c, p + 2 * k))
                    c = circ3(p + 2 * i, p + 2 * j, p + 2 * k);
        }
    }
    return c;
}

/* plan_frame(pos, pts, d, travel_weight, reach, support) -> (tx, ty, K)
 *
 * pos, pts: (n, 2) float64; d: (n, 2) float64 scratch; support: int64 [count, j0, j1, j2],
 * read and updated (PlanFrame's kept support). */
static PyObject *plan_frame(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Buf bp = {0}, bq = {0}, bd = {0}, bs = {0};
    PyObject *res = NULL;
    if (args_n(nargs, 6, "plan_frame") < 0)
        return NULL;
    double w = PyFloat_AsDouble(args[3]);
    double reach = PyFloat_AsDouble(args[4]);
    if (PyErr_Occurred())
        return NULL;
    if (get_buf(args[0], &bp, "d", 2, 0, "pos") < 0 || get_buf(args[1], &bq, "d", 2, 0, "pts") < 0
        || get_buf(args[2], &bd, "d", 2, 1, "d") < 0 || get_buf(args[5], &bs, "ql", 4, 1, "support") < 0)
        goto done;
    Py_ssize_t n = items(&bp) / 2;
    if (items(&bq) / 2 != n || items(&bd) / 2 < n) {
        PyErr_SetString(PyExc_ValueError, "plan_frame: pos, pts and d differ in size");
        goto done;
    }
    const double *P = bp.view.buf, *Q = bq.view.buf;
    double *D = bd.view.buf;
    int64_t *sup = bs.view.buf;
    double mx = 0.0, my = 0.0;
    for (Py_ssize_t j = 0; j < n; j++) {
        double x = P[2 * j] - Q[2 * j], y = P[2 * j + 1] - Q[2 * j + 1];
        D[2 * j] = x;
        D[2 * j + 1] = y;
        mx += x;
        my += y;
    }
    int found = 0;
    Circle c = {0.0, 0.0, 0.0};
    int64_t cnt = sup[0];
    if (cnt > 0 && cnt <= 3) {
        int64_t top = -1;
        int valid = 1;
        for (int64_t s = 0; s < cnt; s++) {
            if (sup[1 + s] < 0)
                valid = 0;
            if (sup[1 + s] > top)
                top = sup[1 + s];
        }
        if (valid && top < n) {
            double pts[6];
            for (int64_t s = 0; s < cnt; s++) {
                pts[2 * s] = D[2 * sup[1 + s]];
                pts[2 * s + 1] = D[2 * sup[1 + s] + 1];
            }
            c = min_circle(pts, cnt);
            double lim = c.r * (1 + 1e-12) + SUPPORT_SLACK_M;
            found = 1;
            for (Py_ssize_t j = 0; j < n; j++)
                if (hypot(D[2 * j] - c.x, D[2 * j + 1] - c.y) > lim) {
                    found = 0;
                    break;
                }
        }
    }
    if (!found) {
        c = min_circle(D, n);
        double lim = c.r * (1 - 1e-9) - 1e-12;
        int64_t k = 0;
        for (Py_ssize_t j = 0; j < n && k < 3; j++)
            if (hypot(D[2 * j] - c.x, D[2 * j + 1] - c.y) >= lim)
                sup[1 + k++] = j;
        sup[0] = k;
    }
    double tx = c.x + w * (mx / n - c.x);
    double ty = c.y + w * (my / n - c.y);
    double far = 0.0;
    for (Py_ssize_t j = 0; j < n; j++) {
        double g = hypot(tx - D[2 * j], ty - D[2 * j + 1]);
        if (g > far)
            far = g;
    }
    double K = ceil(far / reach - STEP_TOL);
    if (!(K >= 1.0))
        K = 1.0;
    res = Py_BuildValue("(ddd)", tx, ty, K);
done:
    release(&bp);
    release(&bq);
    release(&bd);
    release(&bs);
    return res;
}

/* ------------------------------------------ the assignment's cost (decision.py) */

/* centred_cost(pos, ccx, ccy, cost) -> (cx, cy)
 *
 * The team's centroid c (pos summed row by row, / n) and cost[r, j] = |pos[r] - c - cc[j]|^2
 * (m^2), cc the centred pattern's columns: Controller._assign's cost. */
static PyObject *centred_cost(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Buf bp = {0}, bx = {0}, by = {0}, bc = {0};
    PyObject *res = NULL;
    if (args_n(nargs, 4, "centred_cost") < 0)
        return NULL;
    if (get_buf(args[0], &bp, "d", 2, 0, "pos") < 0)
        goto done;
    Py_ssize_t n = items(&bp) / 2;
    if (get_buf(args[1], &bx, "d", n, 0, "ccx") < 0 || get_buf(args[2], &by, "d", n, 0, "ccy") < 0
        || get_buf(args[3], &bc, "d", n * n, 1, "cost") < 0)
        goto done;
    if (items(&bx) != n || items(&by) != n || items(&bc) != n * n) {
        PyErr_SetString(PyExc_ValueError, "centred_cost: pattern and team differ in size");
        goto done;
    }
    const double *P = bp.view.buf, *CX = bx.view.buf, *CY = by.view.buf;
    double *cost = bc.view.buf;
    double sx = 0.0, sy = 0.0;
    for (Py_ssize_t r = 0; r < n; r++) {
        sx += P[2 * r];
        sy += P[2 * r + 1];
    }
    double cx = sx / n, cy = sy / n;
    for (Py_ssize_t r = 0; r < n; r++) {
        double px = P[2 * r] - cx, py = P[2 * r + 1] - cy;
        double *row = cost + r * n;
        for (Py_ssize_t j = 0; j < n; j++) {
            double dx = px - CX[j], dy = py - CY[j];
            row[j] = dx * dx + dy * dy;
        }
    }
    res = Py_BuildValue("(dd)", cx, cy);
done:
    release(&bp);
    release(&bx);
    release(&by);
    release(&bc);
    return res;
}

/* --------------------------------------- the assignment (scipy's solver, warm) */

/* One shortest augmenting path from free row i (Crouse 2016, as scipy's
 * rectangular_lsap.cpp): returns the sink column, -1 if none (infeasible). */
static Py_ssize_t augmenting_path(Py_ssize_t n, const double *cost, const double *u,
                                  const double *v, Py_ssize_t *path, const Py_ssize_t *row4col,
                                  double *spc, Py_ssize_t i, char *SR, char *SC,
                                  Py_ssize_t *remaining, double *p_min)
{
    double min_val = 0.0;
    Py_ssize_t num_remaining = n;
    for (Py_ssize_t it = 0; it < n; it++)
        remaining[it] = n - it - 1; /* reversed: a constant cost gives the identity */
    memset(SR, 0, (size_t)n);
    memset(SC, 0, (size_t)n);
    for (Py_ssize_t j = 0; j < n; j++)
        spc[j] = INFINITY;
    Py_ssize_t sink = -1;
    while (sink == -1) {
        Py_ssize_t index = -1;
        double lowest = INFINITY;
        SR[i] = 1;
        for (Py_ssize_t it = 0; it < num_remaining; it++) {
            Py_ssize_t j = remaining[it];
            double r = min_val + cost[i * n + j] - u[i] - v[j];
            if (r < spc[j]) {
                path[j] = i;
                spc[j] = r;
            }
            if (spc[j] < lowest || (spc[j] == lowest && row4col[j] == -1)) {
                lowest = spc[j];
                index = it;
            }
        }
        min_val = lowest;
        if (min_val == INFINITY || index < 0)
            return -1;
        Py_ssize_t j = remaining[index];
        if (row4col[j] == -1)
            sink = j;
        else
            i = row4col[j];
        SC[j] = 1;
        remaining[index] = remaining[--num_remaining];
    }
    *p_min = min_val;
    return sink;
}

/* assign(cost, prev, v, warm, out) -> rows solved (-1: infeasible)
 *
 * A minimum-cost assignment of the (n, n) float64 cost: out[i] = robot i's slot. Cold
 * (warm false): scipy's linear_sum_assignment, step for step (the same answer, ties
 * included). Warm: the slot potentials v (n,) of the last solve start it; u_i = min_j
 * (cost_ij - v_j) makes them feasible, each robot whose previous slot prev[i] is still
 * tight keeps it, and only the others are augmented. Any optimal assignment is what the
 * solver may return; it is the same one as cold but for exact ties. v is updated. */
static PyObject *assign(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Buf bc = {0}, bp = {0}, bv = {0}, bo = {0};
    PyObject *res = NULL;
    void *mem = NULL;
    if (args_n(nargs, 5, "assign") < 0)
        return NULL;
    int warm = PyObject_IsTrue(args[3]);
    if (warm < 0)
        return NULL;
    if (get_buf(args[2], &bv, "d", 1, 1, "v") < 0)
        goto done;
    Py_ssize_t n = items(&bv);
    if (get_buf(args[0], &bc, "d", n * n, 0, "cost") < 0
        || get_buf(args[1], &bp, "ql", n, 0, "prev") < 0
        || get_buf(args[4], &bo, "ql", n, 1, "out") < 0)
        goto done;
    if (items(&bc) != n * n || items(&bp) != n || items(&bo) != n) {
        PyErr_SetString(PyExc_ValueError, "assign: cost, prev, v and out differ in size");
        goto done;
    }
    const double *C = bc.view.buf;
    const int64_t *prev = bp.view.buf;
    double *v = bv.view.buf;
    int64_t *out = bo.view.buf;
    for (Py_ssize_t k = 0; k < n * n; k++)
        if (!isfinite(C[k])) {
            PyErr_SetString(PyExc_ValueError, "assign: the cost must be finite");
            goto done;
        }
    mem = PyMem_Malloc((size_t)n * (2 * sizeof(double) + 4 * sizeof(Py_ssize_t) + 2));
    if (mem == NULL) {
        PyErr_NoMemory();
        goto done;
    }
    double *u = mem, *spc = u + n;
    Py_ssize_t *path = (Py_ssize_t *)(spc + n), *col4row = path + n, *row4col = col4row + n,
               *remaining = row4col + n;
    char *SR = (char *)(remaining + n), *SC = SR + n;
    for (Py_ssize_t k = 0; k < n; k++) {
        path[k] = col4row[k] = row4col[k] = -1;
        u[k] = 0.0;
    }
    if (warm) {
        for (Py_ssize_t k = 0; k < n; k++)
            if (!isfinite(v[k]) || prev[k] < -1 || prev[k] >= n)
                warm = 0;
    }
    if (warm) {
        for (Py_ssize_t i = 0; i < n; i++) {
            const double *row = C + i * n;
            double m = INFINITY;
            for (Py_ssize_t j = 0; j < n; j++) {
                double r = row[j] - v[j];
                if (r < m)
                    m = r;
            }
            u[i] = m;
            Py_ssize_t j = prev[i];
            if (j >= 0 && row4col[j] == -1 && row[j] - v[j] == m) {
                col4row[i] = j;
                row4col[j] = i;
            }
        }
    } else {
        for (Py_ssize_t k = 0; k < n; k++)
            v[k] = 0.0;
    }
    long solved = 0;
    for (Py_ssize_t cur = 0; cur < n; cur++) {
        if (col4row[cur] != -1)
            continue;
        double min_val;
        Py_ssize_t sink = augmenting_path(n, C, u, v, path, row4col, spc, cur, SR, SC,
                                          remaining, &min_val);
        if (sink < 0) {
            solved = -1;
            break;
        }
        solved++;
        u[cur] += min_val;
        for (Py_ssize_t i = 0; i < n; i++)
            if (SR[i] && i != cur)
                u[i] += min_val - spc[col4row[i]];
        for (Py_ssize_t j = 0; j < n; j++)
            if (SC[j])
                v[j] -= min_val - spc[j];
        Py_ssize_t j = sink;
        for (;;) {
            Py_ssize_t i = path[j];
            row4col[j] = i;
            Py_ssize_t t = col4row[i];
            col4row[i] = j;
            j = t;
            if (i == cur)
                break;
        }
    }
    if (solved >= 0)
        for (Py_ssize_t i = 0; i < n; i++)
            out[i] = col4row[i];
    res = PyLong_FromLong(solved);
done:
    PyMem_Free(mem);
    release(&bc);
    release(&bp);
    release(&bv);
    release(&bo);
    return res;
}

/* ----------------------------------- the observation row (observation.py, decision.py) */

typedef struct { double d; int64_t j; } Key;

static int key_less(const Key *a, const Key *b)
{
    return a->d < b->d || (a->d == b->d && a->j < b->j);
}

static int key_cmp(const void *pa, const void *pb)
{
    const Key *a = pa, *b = pb;
    return key_less(a, b) ? -1 : (key_less(b, a) ? 1 : 0);
}

/* row(pos, prev, i, sx, sy, k, reach, dt, pace, vel, order, d2, keys, out)
 *
 * pos, prev: (n, 2) float64 positions at t and t-1. Writes vel (n, 2) = (pos - prev) / dt,
 * d2 (n,) squared distances to robot i (d2[i] = inf), order (n,) int64 robot ids nearest
 * first (ties by id, i last), and out (6 + 5k) float32 or float64: robot i's general row
 * toward the slot (sx, sy); pace > 0 makes columns 2:4 the plan's step (the row's first
 * two columns / pace). keys: (n, 2) float64 scratch. */
static PyObject *row(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Buf bp = {0}, bv0 = {0}, bv = {0}, bo = {0}, bd = {0}, bk = {0}, bout = {0};
    PyObject *res = NULL;
    if (args_n(nargs, 14, "row") < 0)
        return NULL;
    Py_ssize_t i = PyNumber_AsSsize_t(args[2], PyExc_OverflowError);
    double sx = PyFloat_AsDouble(args[3]), sy = PyFloat_AsDouble(args[4]);
    Py_ssize_t k = PyNumber_AsSsize_t(args[5], PyExc_OverflowError);
    double reach = PyFloat_AsDouble(args[6]), dt = PyFloat_AsDouble(args[7]);
    double pace = PyFloat_AsDouble(args[8]);
    if (PyErr_Occurred())
        return NULL;
    if (get_buf(args[0], &bp, "d", 2, 0, "pos") < 0)
        goto done;
    Py_ssize_t n = items(&bp) / 2;
    if (i < 0 || i >= n || k < 0 || k > 1000) {
        PyErr_SetString(PyExc_ValueError, "row: robot index or k out of range");
        goto done;
    }
    if (get_buf(args[1], &bv0, "d", 2 * n, 0, "prev") < 0
        || get_buf(args[9], &bv, "d", 2 * n, 1, "vel") < 0
        || get_buf(args[10], &bo, "ql", n, 1, "order") < 0
        || get_buf(args[11], &bd, "d", n, 1, "d2") < 0
        || get_buf(args[12], &bk, "d", 2 * n, 1, "keys") < 0
        || get_buf(args[13], &bout, "fd", 6 + 5 * k, 1, "out") < 0)
        goto done;
    const double *P = bp.view.buf, *P1 = bv0.view.buf;
    double *V = bv.view.buf, *D2 = bd.view.buf;
    int64_t *order = bo.view.buf;
    Key *keys = bk.view.buf;
    for (Py_ssize_t j = 0; j < 2 * n; j++)
        V[j] = (P[j] - P1[j]) / dt;
    double px = P[2 * i], py = P[2 * i + 1];
    for (Py_ssize_t j = 0; j < n; j++) {
        double x = P[2 * j] - px, y = P[2 * j + 1] - py;
        D2[j] = x * x + y * y;
    }
    D2[i] = INFINITY;
    for (Py_ssize_t j = 0; j < n; j++) {
        keys[j].d = D2[j];
        keys[j].j = j;
    }
    if (n <= 32) { /* insertion sort: stable, by (d2, id) */
        for (Py_ssize_t a = 1; a < n; a++) {
            Key x = keys[a];
            Py_ssize_t b = a - 1;
            while (b >= 0 && key_less(&x, &keys[b])) {
                keys[b + 1] = keys[b];
                b--;
            }
            keys[b + 1] = x;
        }
    } else {
        qsort(keys, (size_t)n, sizeof(Key), key_cmp);
    }
    for (Py_ssize_t j = 0; j < n; j++)
        order[j] = keys[j].j;
    double r[6];
    double svx = sx - px, svy = sy - py;
    double norm = sqrt(svx * svx + svy * svy);
    double d = norm > reach ? norm : reach;
    double vix = V[2 * i], viy = V[2 * i + 1];
    r[0] = svx;
    r[1] = svy;
    r[2] = svx / d;
    r[3] = svy / d;
    r[4] = vix;
    r[5] = viy;
    if (pace > 0.0) {
        r[2] = r[0] / pace;
        r[3] = r[1] / pace;
    }
    Py_ssize_t m = k < n - 1 ? k : n - 1;
    int f32 = bout.view.itemsize == 4;
    float *of = bout.view.buf;
    double *od = bout.view.buf;
#define PUT(idx, val) do { if (f32) of[idx] = (float)(val); else od[idx] = (val); } while (0)
    for (int c = 0; c < 6; c++)
        PUT(c, r[c]);
    for (Py_ssize_t a = 0; a < m; a++) {
        int64_t j = order[a];
        Py_ssize_t o = 6 + 5 * a;
        PUT(o, P[2 * j] - px);
        PUT(o + 1, P[2 * j + 1] - py);
        PUT(o + 2, V[2 * j] - vix);
        PUT(o + 3, V[2 * j + 1] - viy);
        PUT(o + 4, 1.0);
    }
    for (Py_ssize_t o = 6 + 5 * m; o < 6 + 5 * k; o++)
        PUT(o, 0.0);
#undef PUT
    res = Py_None;
    Py_INCREF(res);
done:
    release(&bp);
    release(&bv0);
    release(&bv);
    release(&bo);
    release(&bd);
    release(&bk);
    release(&bout);
    return res;
}

/* ------------------------------------------------------------ ORCA (safety.py) */

typedef struct { double px, py, dx, dy; } Line;
typedef struct { double d2, rx, ry; int64_t j; } Near;

static int near_less(const Near *a, const Near *b)
{
    if (a->d2 != b->d2) return a->d2 < b->d2;
    if (a->rx != b->rx) return a->rx < b->rx;
    if (a->ry != b->ry) return a->ry < b->ry;
    return a->j < b->j;
}

/* linearProgram1: the best point on line `no` within the circle and the lines before it */
static int lp1(const Line *lines, int no, double radius, double ox, double oy, int dir_opt,
               double *outx, double *outy)
{
    double px = lines[no].px, py = lines[no].py, dx = lines[no].dx, dy = lines[no].dy;
    double dot = px * dx + py * dy;
    double disc = dot * dot + radius * radius - (px * px + py * py);
    if (disc < 0.0)
        return 0;
    double sq = sqrt(disc);
    double tl = -dot - sq, tr = -dot + sq;
    for (int i = 0; i < no; i++) {
        double qx = lines[i].px, qy = lines[i].py, ex = lines[i].dx, ey = lines[i].dy;
        double den = dx * ey - dy * ex;
        double num = ex * (py - qy) - ey * (px - qx);
        if (fabs(den) <= RVO_EPS) {
            if (num < 0.0)
                return 0;
            continue;
        }
        double t = num / den;
        if (den >= 0.0) {
            if (t < tr)
                tr = t;
        } else if (t > tl) {
            tl = t;
        }
        if (tl > tr)
            return 0;
    }
    double t;
    if (dir_opt) {
        t = ox * dx + oy * dy > 0.0 ? tr : tl;
    } else {
        t = dx * (ox - px) + dy * (oy - py);
        if (t < tl)
            t = tl;
        else if (t > tr)
            t = tr;
    }
    *outx = px + t * dx;
    *outy = py + t * dy;
    return 1;
}

/* linearProgram2: returns the failed line (m on success) */
static int lp2(const Line *lines, int m, double radius, double ox, double oy, int dir_opt,
               double *rx, double *ry)
{
    if (dir_opt) {
        *rx = ox * radius;
        *ry = oy * radius;
    } else {
        double n2 = ox * ox + oy * oy;
        if (n2 > radius * radius) {
            double s = radius / sqrt(n2);
            *rx = ox * s;
            *ry = oy * s;
        } else {
            *rx = ox;
            *ry = oy;
        }
    }
    for (int i = 0; i < m; i++) {
        const Line *l = &lines[i];
        if (l->dx * (l->py - *ry) - l->dy * (l->px - *rx) > 0.0) {
            double fx, fy;
            if (!lp1(lines, i, radius, ox, oy, dir_opt, &fx, &fy))
                return i;
            *rx = fx;
            *ry = fy;
        }
    }
    return m;
}

/* linearProgram3: the infeasible case, the least largest violation */
static void lp3(const Line *lines, int m, int begin, double radius, double *rx, double *ry)
{
    double distance = 0.0;
    Line proj[MAX_NEAR];
    for (int i = begin; i < m; i++) {
        double px = lines[i].px, py = lines[i].py, dx = lines[i].dx, dy = lines[i].dy;
        if (dx * (py - *ry) - dy * (px - *rx) > distance) {
            int np_ = 0;
            for (int j = 0; j < i; j++) {
                double qx = lines[j].px, qy = lines[j].py, ex = lines[j].dx, ey = lines[j].dy;
                double det = dx * ey - dy * ex;
                double lx, ly;
                if (fabs(det) <= RVO_EPS) {
                    if (dx * ex + dy * ey > 0.0)
                        continue;
                    lx = 0.5 * (px + qx);
                    ly = 0.5 * (py + qy);
                } else {
                    double t = (ex * (py - qy) - ey * (px - qx)) / det;
                    lx = px + t * dx;
                    ly = py + t * dy;
                }
                double ux = ex - dx, uy = ey - dy;
                double un = sqrt(ux * ux + uy * uy);
                proj[np_].px = lx;
                proj[np_].py = ly;
                proj[np_].dx = ux / un;
                proj[np_].dy = uy / un;
                np_++;
            }
            double nx, ny;
            int fail = lp2(proj, np_, radius, -dy, dx, 1, &nx, &ny);
            if (fail >= np_) {
                *rx = nx;
                *ry = ny;
            }
            distance = dx * (py - *ry) - dy * (px - *rx);
        }
    }
}

/* orca(vx, vy, pos, vel, i, order, d2, keep, range_sq, combined, tau, dt, keep_right_rad,
 *      v_max) -> (rx, ry, changed, change)
 *
 * (vx, vy): the preferred velocity, finite and clamped to v_max; pos, vel (n, 2); order,
 * d2 as row() leaves them. The neighbours are runtime.decision._near_in_order's, the
 * velocity runtime.safety.orca_velocity's. */
static PyObject *orca(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    Buf bp = {0}, bv = {0}, bo = {0}, bd = {0};
    PyObject *res = NULL;
    if (args_n(nargs, 14, "orca") < 0)
        return NULL;
    double vx = PyFloat_AsDouble(args[0]), vy = PyFloat_AsDouble(args[1]);
    Py_ssize_t i = PyNumber_AsSsize_t(args[4], PyExc_OverflowError);
    Py_ssize_t keep = PyNumber_AsSsize_t(args[7], PyExc_OverflowError);
    double range_sq = PyFloat_AsDouble(args[8]), combined = PyFloat_AsDouble(args[9]);
    double tau = PyFloat_AsDouble(args[10]), dt = PyFloat_AsDouble(args[11]);
    double keep_right = PyFloat_AsDouble(args[12]), v_max = PyFloat_AsDouble(args[13]);
    if (PyErr_Occurred())
        return NULL;
    if (keep < 0 || keep > MAX_NEAR) {
        PyErr_Format(PyExc_ValueError, "orca: at most %d neighbours", MAX_NEAR);
        return NULL;
    }
    if (get_buf(args[2], &bp, "d", 2, 0, "pos") < 0)
        goto done;
    Py_ssize_t n = items(&bp) / 2;
    if (i < 0 || i >= n) {
        PyErr_SetString(PyExc_ValueError, "orca: robot index out of range");
        goto done;
    }
    if (get_buf(args[3], &bv, "d", 2 * n, 0, "vel") < 0
        || get_buf(args[5], &bo, "ql", n, 0, "order") < 0
        || get_buf(args[6], &bd, "d", n, 0, "d2") < 0)
        goto done;
    const double *P = bp.view.buf, *V = bv.view.buf, *D2 = bd.view.buf;
    const int64_t *order = bo.view.buf;
    for (Py_ssize_t a = 0; a < n; a++)
        if (order[a] < 0 || order[a] >= n) {
            PyErr_SetString(PyExc_ValueError, "orca: order out of range");
            goto done;
        }
    /* the neighbours: _near_in_order */
    Near near[MAX_NEAR + 1];
    int m = 0;
    Py_ssize_t end = keep < n ? keep : n;
    if (end > 0) {
        double last = D2[order[end - 1]];
        while (end < n && D2[order[end]] == last)
            end++;
        double px = P[2 * i], py = P[2 * i + 1];
        for (Py_ssize_t a = 0; a < end; a++) {
            int64_t j = order[a];
            double dj = D2[j];
            if (dj < range_sq) {
                Near x = {dj, P[2 * j] - px, P[2 * j + 1] - py, j};
                /* insertion into the sorted first `keep` */
                int b = m < keep ? m : (int)keep;
                if (b == keep && (b == 0 || !near_less(&x, &near[b - 1])))
                    continue;
                while (b > 0 && near_less(&x, &near[b - 1])) {
                    if (b < keep)
                        near[b] = near[b - 1];
                    b--;
                }
                near[b] = x;
                if (m < keep)
                    m++;
            }
        }
    }
    double prefx = vx, prefy = vy, rx, ry;
    if (m == 0) {
        rx = prefx;
        ry = prefy;
        clamp_speed(&rx, &ry, v_max);
    } else {
        double ox = V[2 * i], oy = V[2 * i + 1];
        if (!(isfinite(ox) && isfinite(oy)))
            ox = oy = 0.0;
        double combined_sq = combined * combined;
        double inv_tau = 1.0 / tau, inv_dt = 1.0 / dt;
        Line lines[MAX_NEAR];
        for (int a = 0; a < m; a++) {
            double dist_sq = near[a].d2, rpx = near[a].rx, rpy = near[a].ry;
            double nvx = V[2 * near[a].j], nvy = V[2 * near[a].j + 1];
            if (!(isfinite(nvx) && isfinite(nvy)))
                nvx = nvy = 0.0;
            double rvx = ox - nvx, rvy = oy - nvy;
            double dx, dy, ux, uy;
            if (dist_sq > combined_sq) {
                double wx = rvx - inv_tau * rpx, wy = rvy - inv_tau * rpy;
                double w_len_sq = wx * wx + wy * wy;
                double dot1 = wx * rpx + wy * rpy;
                if (dot1 < 0.0 && dot1 * dot1 > combined_sq * w_len_sq) {
                    double w_len = sqrt(w_len_sq);
                    double ux_ = wx / w_len, uy_ = wy / w_len;
                    dx = uy_;
                    dy = -ux_;
                    double s = combined * inv_tau - w_len;
                    ux = s * ux_;
                    uy = s * uy_;
                } else {
                    double leg = sqrt(dist_sq - combined_sq);
                    if (rpx * wy - rpy * wx > 0.0) {
                        dx = (rpx * leg - rpy * combined) / dist_sq;
                        dy = (rpx * combined + rpy * leg) / dist_sq;
                    } else {
                        dx = -(rpx * leg + rpy * combined) / dist_sq;
                        dy = -(-rpx * combined + rpy * leg) / dist_sq;
                    }
                    double dot2 = rvx * dx + rvy * dy;
                    ux = dot2 * dx - rvx;
                    uy = dot2 * dy - rvy;
                }
            } else {
                double wx = rvx - inv_dt * rpx, wy = rvy - inv_dt * rpy;
                double w_len = sqrt(wx * wx + wy * wy);
                double ux_, uy_;
                if (w_len > 1e-12) {
                    ux_ = wx / w_len;
                    uy_ = wy / w_len;
                } else {
                    double d = sqrt(dist_sq);
                    if (d > 1e-12) {
                        ux_ = -rpx / d;
                        uy_ = -rpy / d;
                    } else {
                        ux_ = 0.0;
                        uy_ = -1.0;
                    }
                }
                dx = uy_;
                dy = -ux_;
                double s = combined * inv_dt - w_len;
                ux = s * ux_;
                uy = s * uy_;
            }
            lines[a].px = ox + 0.5 * ux;
            lines[a].py = oy + 0.5 * uy;
            lines[a].dx = dx;
            lines[a].dy = dy;
        }
        double n2 = prefx * prefx + prefy * prefy;
        double cx = prefx, cy = prefy;
        if (n2 > v_max * v_max) {
            double s = v_max / sqrt(n2);
            cx = cx * s;
            cy = cy * s;
        }
        double optx = prefx, opty = prefy;
        if (keep_right != 0.0) {
            for (int a = 0; a < m; a++)
                if (lines[a].dx * (lines[a].py - cy) - lines[a].dy * (lines[a].px - cx) > 0.0) {
                    double c = cos(keep_right), s = sin(keep_right);
                    double nx = c * optx + s * opty, ny = -s * optx + c * opty;
                    optx = nx;
                    opty = ny;
                    break;
                }
        }
        int fail = lp2(lines, m, v_max, optx, opty, 0, &rx, &ry);
        if (fail < m)
            lp3(lines, m, fail, v_max, &rx, &ry);
        clamp_speed(&rx, &ry, v_max);
    }
    double change = hypot(rx - prefx, ry - prefy);
    res = Py_BuildValue("(ddOd)", rx, ry, change > CHANGE_TOL ? Py_True : Py_False, change);
done:
    release(&bp);
    release(&bv);
    release(&bo);
    release(&bd);
    return res;
}

/* ------------------------------------------------------------ module */

static PyMethodDef methods[] = {
    {"assign", (PyCFunction)(void (*)(void))assign, METH_FASTCALL,
     "assign(cost, prev, v, warm, out) -> rows solved (-1: infeasible)"},
    {"centred_cost", (PyCFunction)(void (*)(void))centred_cost, METH_FASTCALL,
     "centred_cost(pos, ccx, ccy, cost) -> (cx, cy)"},
    {"plan_frame", (PyCFunction)(void (*)(void))plan_frame, METH_FASTCALL,
     "plan_frame(pos, pts, d, travel_weight, reach, support) -> (tx, ty, K)"},
    {"row", (PyCFunction)(void (*)(void))row, METH_FASTCALL,
     "row(pos, prev, i, sx, sy, k, reach, dt, pace, vel, order, d2, keys, out) -> None"},
    {"orca", (PyCFunction)(void (*)(void))orca, METH_FASTCALL,
     "orca(vx, vy, pos, vel, i, order, d2, keep, range_sq, combined, tau, dt, keep_right_rad,"
     " v_max) -> (vx, vy, changed, change)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "runtime._kernel",
    "One robot's decision, compiled: see runtime/kernel.py.", -1, methods,
};

PyMODINIT_FUNC PyInit__kernel(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m != NULL && PyModule_AddIntConstant(m, "VERSION", KERNEL_VERSION) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
