"""Formation geometry: error, the shared slot assignment, lower bounds, collisions.

Shapes: ``P`` positions (n, 2) or a batch (E, n, 2); ``C`` a pattern (n, 2) or
(E, n, 2); metres throughout.

Formation error
    ``min over sigma, t of RMS ||p_i - c_sigma(i) - t||``. For a fixed sigma the
    best translation aligns the centroids, so centring both sets and solving one
    Hungarian assignment on squared distances gives the exact optimum.

Shared assignment
    Every robot computes the same assignment from the same poses: robots are
    ordered by id, the cost matrix is built in that order, and the solver
    (:mod:`runtime.core.assignment`: scipy's ``linear_sum_assignment``
    algorithm, step for step, warm-started from the last step's slot
    potentials) is deterministic on identical input, so ties are broken
    identically everywhere (by the solver's fixed scan order over robot ids,
    then slot index). A previous assignment is kept unless the new one is
    better by more than a hysteresis margin, so tiny differences between
    robots' frames (realtime mode) do not flip slots. :func:`assign_centred`,
    :func:`assign_slots`, :func:`assign_slots_batch` and
    :func:`assign_slots_env_last` are that module's one solver and one rule
    on costs built here (:func:`centred_cost`); :func:`keeps_previous` is the
    rule on numpy sums.

Collisions and contacts
    :func:`swept_pair_distance` (closest approach along straight moves) is the
    one definition; :func:`collision_pairs`, :func:`count_collisions`,
    :func:`min_swept_separation` and the training world's pair-major
    :func:`swept_contacts` all read it. :func:`min_separation` is the static
    closest pair (per row of any batch, e.g. a (T, n, 2) track).

The solver is loaded without the rest of scipy.optimize, and scipy.sparse only
where the lower bounds need it, so a robot process imports this module cheaply.
"""

from __future__ import annotations

import functools
import importlib.machinery
import importlib.util
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from runtime.core.assignment import HYSTERESIS_ABS_M2 as HYSTERESIS_ABS_M2
from runtime.core.assignment import HYSTERESIS_REL as HYSTERESIS_REL
from runtime.core.assignment import assign_costs, assign_team
from runtime.core.plan_frame import min_enclosing_circle
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig


def _load_lsap() -> Callable[..., Any]:
    """scipy's ``linear_sum_assignment`` without importing all of scipy.optimize.

    The solver is one C extension, ``scipy/optimize/_lsap``; loading it by file
    skips the package's ``__init__`` (linprog, linalg, sparse, ...: half a second
    and tens of MB at a robot's start). Falls back on the ordinary import if the
    file is not where it is expected. (scipy.sparse, which only the lower bounds
    need, is imported where they run.)
    """
    try:
        import scipy

        base = Path(scipy.__path__[0]) / "optimize"
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = base / f"_lsap{suffix}"
            if path.is_file():
                spec = importlib.util.spec_from_file_location("scipy.optimize._lsap", path)
                if spec is None or spec.loader is None:
                    break
                mod = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(mod)
                fn: Callable[..., Any] = mod.linear_sum_assignment
                return fn
    except (ImportError, OSError, AttributeError):
        pass
    from scipy.optimize import linear_sum_assignment as lsa

    fallback: Callable[..., Any] = lsa
    return fallback


linear_sum_assignment = _load_lsap()


def centred(points: Array) -> Array:
    """Points minus their centroid (over the robot axis, -2)."""
    p = np.asarray(points, dtype=np.float64)
    out: Array = p - p.mean(axis=-2, keepdims=True)
    return out


def centred_cost(Pc: Array, Cc: Array) -> Array:
    """Squared distances between already centred positions and pattern points.

    ``Pc`` (..., n, 2), ``Cc`` (..., n, 2) -> (..., n, n), ``[i, j]`` robot i to point j.
    """
    d = Pc[..., None, :] - Cc[..., None, :, :]
    d *= d
    out: Array = d[..., 0] + d[..., 1]
    return out


def _sq_cost(P: Array, C: Array) -> Array:
    return centred_cost(centred(P), centred(C))


def keeps_previous(new_cost: Array | float, old_cost: Array | float) -> BoolArray:
    """The hysteresis rule: keep the previous assignment unless the new one is better
    by more than the margin. Summed squared costs (m^2), scalars or arrays alike."""
    keep: BoolArray = np.logical_not(
        new_cost < old_cost - (HYSTERESIS_REL * old_cost + HYSTERESIS_ABS_M2)
    )
    return keep


def assign_centred(Pc: Array, Cc: Array, previous: IntArray | None = None) -> IntArray:
    """:func:`assign_slots` of an already centred team ``Pc`` (n, 2) and pattern ``Cc`` (n, 2).

    The robot's path: it caches the centred pattern and needs the team's centroid
    anyway, so nothing is centred twice.
    """
    cost = np.ascontiguousarray(centred_cost(Pc, Cc))
    n = cost.shape[0]
    slots: IntArray = np.empty(n, dtype=np.int64)
    has_prev = previous is not None and len(previous) == n
    prev = np.ascontiguousarray(previous, dtype=np.int64) if has_prev else slots
    assign_team(cost, prev, has_prev, np.zeros(n), slots)
    return slots


def assign_slots(P: Array, C: Array, previous: IntArray | None = None) -> IntArray:
    """The shared optimal assignment: ``slots[i]`` is the pattern index of robot i.

    Minimises the summed squared distance between centred positions and the
    centred pattern. With ``previous`` (a permutation from the last step) the
    old assignment is kept unless the new one is better by the hysteresis margin.
    """
    return assign_centred(centred(P), centred(C), previous)


def assign_slots_batch(P: Array, C: Array, previous: IntArray | None = None) -> IntArray:
    """:func:`assign_slots` over a batch: P (E, n, 2), C (n, 2) or (E, n, 2) -> (E, n).

    With ``previous`` (E, n) each env keeps it under the hysteresis rule (an env
    whose ``previous`` is not a permutation takes the solver's assignment).
    """
    cost = np.ascontiguousarray(_sq_cost(P, np.broadcast_to(C, P.shape)))
    E, n = cost.shape[0], cost.shape[-1]
    slots: IntArray = np.empty((E, n), dtype=np.int64)
    has_prev = previous is not None
    prev = np.asarray(previous, dtype=np.int64) if has_prev else slots
    assign_costs(cost, prev, has_prev, np.zeros((E, n)), slots)
    return slots


def assign_slots_env_last(
    cost: Array, previous: IntArray, potentials: Array | None = None
) -> IntArray:
    """The shared assignment with hysteresis, env-last: ``cost`` (n, n, E), ``previous`` (n, E).

    ``cost[i, j, e]``: squared distance (m^2) of centred robot i to centred
    slot j (:func:`centred_cost`'s values). Returns slots (n, E): what solving
    every env with scipy's solver and applying :func:`keeps_previous` gives
    (ties aside). A ``previous`` that is not a permutation is replaced by the
    solver's assignment.

    ``potentials`` (n, E), optional, is the solver's slot potentials carried
    from call to call (zeros at first); updated in place, it lets the solver
    keep, unsolved, the previous slots still proven optimal
    (:func:`runtime.core.assignment.assign_team`).
    """
    n, E = previous.shape
    c = np.ascontiguousarray(np.asarray(cost, dtype=np.float64).transpose(2, 0, 1))
    prev = np.asarray(previous, dtype=np.int64)
    pot = np.zeros((n, E)) if potentials is None else potentials
    slots: IntArray = np.empty((n, E), dtype=np.int64)
    assign_costs(c, prev.T, True, pot.T, slots.T)
    return slots


def slot_positions(P: Array, C: Array, slots: IntArray) -> Array:
    """World position of each robot's slot: the centred pattern placed on the team's centroid."""
    Cc = centred(np.broadcast_to(C, P.shape))
    target = np.take_along_axis(Cc, slots[..., None], axis=-2)
    out: Array = target + P.mean(axis=-2, keepdims=True)
    return out


def formation_error(P: Array, C: Array) -> float:
    """RMS distance to the pattern under the best assignment and translation (metres)."""
    cost = _sq_cost(P, C)
    r, c = linear_sum_assignment(cost)
    return float(math.sqrt(cost[r, c].mean()))


def formation_error_batch(P: Array, C: Array, slots: IntArray | None = None) -> Array:
    """Formation error per env, (E,). Pass ``slots`` to reuse an assignment already solved."""
    cost = _sq_cost(P, np.broadcast_to(C, P.shape))
    if slots is None:
        slots = assign_slots_batch(P, C)
    per = np.take_along_axis(cost, slots[..., None], -1)[..., 0]
    out: Array = np.sqrt(per.mean(-1))
    return out


def slot_distances(P: Array, C: Array, slots: IntArray) -> Array:
    """Distance of every robot to its slot, (..., n)."""
    out: Array = np.linalg.norm(P - slot_positions(P, C, slots), axis=-1)
    return out


def is_formed(P: Array, C: Array, tol: float = DEFAULT_WORLD.formed_tol_m) -> bool:
    """True when every robot is within ``tol`` of its slot under the best alignment.

    Uses the error-optimal (squared-distance) assignment and centroid alignment,
    the same rule the robots follow; with tol at a quarter radius this is the
    world's definition of "formed".
    """
    slots = assign_slots(P, C)
    return bool(slot_distances(P, C, slots).max() <= tol)


# ---------------------------------------------------------------- lower bounds


def _bottleneck_assignment(dist: Array) -> IntArray:
    """Assignment minimising the largest distance (binary search over thresholds)."""
    from scipy.sparse import csr_matrix  # the lower bounds only: not at a robot's start
    from scipy.sparse.csgraph import maximum_bipartite_matching

    n = dist.shape[0]
    values = np.unique(dist)
    lo, hi = 0, len(values) - 1
    best = None
    while lo <= hi:
        mid = (lo + hi) // 2
        m = maximum_bipartite_matching(csr_matrix(dist <= values[mid]), perm_type="column")
        if (m >= 0).all():
            best, hi = m, mid - 1
        else:
            lo = mid + 1
    assert best is not None
    # Among bottleneck-optimal assignments prefer the one with least total distance.
    thr = values[lo] if lo < len(values) else values[-1]
    cost = np.where(dist <= thr, dist, dist.max() * n + 1.0)
    _, cols = linear_sum_assignment(cost)
    out: IntArray = cols.astype(np.int64)
    return out


def _weiszfeld(d: Array, t: Array, iters: int = 200) -> Array:
    """Translation t minimising sum ||d_i - t|| (geometric median of d).

    Weiszfeld's iteration converges slowly when the median sits on a data point
    (common for small n), so the data points are candidates too.
    """
    t = np.asarray(t, dtype=np.float64)
    for _ in range(iters):
        r = np.linalg.norm(d - t, axis=1)
        r = np.maximum(r, 1e-12)
        w = 1.0 / r
        t_new: Array = (d * w[:, None]).sum(0) / w.sum()
        if np.linalg.norm(t_new - t) < 1e-9:
            t = t_new
            break
        t = t_new
    cands = np.vstack([t[None, :], d])
    cost = np.linalg.norm(d[None, :, :] - cands[:, None, :], axis=-1).sum(1)
    out: Array = cands[int(np.argmin(cost))]
    return out


def lower_bound_travel(P: Array, C: Array) -> float:
    """Minimal total travel: min over sigma, t of sum ||p_i - c_sigma(i) - t|| (metres).

    Exact for the assignment it settles on (the best translation for a fixed
    assignment is a geometric median, found by Weiszfeld's iteration); the
    outer minimum over assignments is an estimate: alternating assignment and
    translation from several starts (the centroid alignment and the
    displacements of up to 8 robots under the squared-error assignment). The
    value is attained by a real assignment and translation, so it never lies
    below the true minimum; tests bound it within 1 % of brute force (n <= 7).
    """
    Pc = np.asarray(P, np.float64)
    Cc = np.asarray(C, np.float64)
    d0 = Pc - Cc[assign_slots(Pc, Cc)]
    starts = [Pc.mean(0) - Cc.mean(0), *d0[: min(len(d0), 8)]]
    best = math.inf
    seen: dict[bytes, float] = {}  # assignment -> its optimal travel: starts often converge
    for t in starts:
        prev = math.inf
        for _ in range(20):
            dist = np.linalg.norm(Pc[:, None, :] - Cc[None, :, :] - t, axis=-1)
            _, cols = linear_sum_assignment(dist)
            key = cols.tobytes()
            if key in seen:
                prev = min(prev, seen[key])
                break
            d = Pc - Cc[cols]
            t = _weiszfeld(d, t)
            val = float(np.linalg.norm(d - t, axis=1).sum())
            seen[key] = val
            if val >= prev - 1e-12:
                prev = min(prev, val)
                break
            prev = val
        best = min(best, prev)
    return best


def lower_bound_distance(P: Array, C: Array) -> float:
    """Minimal bottleneck distance: min over sigma, t of max ||p_i - c_sigma(i) - t|| (metres).

    Exact for the assignment it settles on (the best translation is the centre
    of the smallest circle enclosing the displacements); the minimum over
    assignments is an estimate: alternating bottleneck assignment and
    translation from several starts (centroid alignment, the enclosing circle
    of the squared-error assignment, and the displacements of up to 8 robots).
    The value is attained by a real assignment and translation, so it never
    lies below the true minimum; tests bound it within 3 % of brute force.
    """
    Pc = np.asarray(P, np.float64)
    Cc = np.asarray(C, np.float64)
    d0 = Pc - Cc[assign_slots(Pc, Cc)]
    cx, cy, _ = min_enclosing_circle(d0)
    starts = [Pc.mean(0) - Cc.mean(0), np.array([cx, cy]), *d0[: min(len(d0), 8)]]
    best = math.inf
    seen: dict[bytes, float] = {}  # assignment -> its enclosing radius: starts often converge
    for t in starts:
        prev = math.inf
        for _ in range(20):
            dist = np.linalg.norm(Pc[:, None, :] - Cc[None, :, :] - t, axis=-1)
            cols = _bottleneck_assignment(dist)
            key = cols.tobytes()
            if key in seen:
                prev = min(prev, seen[key])
                break
            cx, cy, r = min_enclosing_circle(Pc - Cc[cols])
            t = np.array([cx, cy])
            seen[key] = r
            if r >= prev - 1e-12:
                prev = min(prev, r)
                break
            prev = r
        best = min(best, prev)
    return best


def lower_bounds(
    P: Array,
    C: Array,
    v_max: float = DEFAULT_WORLD.v_max_mps,
    dt: float = DEFAULT_WORLD.dt_s,
) -> tuple[float, int]:
    """(minimal total travel in metres, minimal steps) to form C from P.

    steps = ceil(bottleneck distance / (v_max * dt)): the farthest robot must
    cover its distance at one step's reach at a time. Both ignore collisions,
    so they are true lower bounds when the outer minimum is exact; see
    :func:`lower_bound_travel` and :func:`lower_bound_distance` for which parts
    are exact and which are an estimate.
    """
    travel = lower_bound_travel(P, C)
    steps = math.ceil(lower_bound_distance(P, C) / (v_max * dt) - 1e-9)
    return travel, max(steps, 0)


# ------------------------------------------------------------------- collisions


def min_separation(P: Array) -> float | Array:
    """Smallest centre-to-centre distance: a float for (n, 2), an (E,) array for a batch."""
    p = np.asarray(P, dtype=np.float64)
    d = np.linalg.norm(p[..., :, None, :] - p[..., None, :, :], axis=-1)
    n = p.shape[-2]
    d[..., np.arange(n), np.arange(n)] = np.inf
    m = d.min(axis=(-1, -2))
    return float(m) if p.ndim == 2 else m


def swept_pair_distance(P0: Array, P1: Array) -> Array:
    """Closest approach of every pair while all robots move in straight lines from P0 to P1.

    Shapes (..., n, 2) -> (..., n, n) with inf on the diagonal. Catches two
    robots that pass through each other within one step, which checking only
    the end positions would miss.
    """
    d0 = P0[..., None, :, :] - P0[..., :, None, :]
    d1 = P1[..., None, :, :] - P1[..., :, None, :]
    dd = d1 - d0
    denom = np.einsum("...k,...k->...", dd, dd)
    s = -np.einsum("...k,...k->...", d0, dd) / np.where(denom > 0, denom, 1.0)
    s = np.clip(np.where(denom > 0, s, 0.0), 0.0, 1.0)
    closest = d0 + s[..., None] * dd
    out: Array = np.linalg.norm(closest, axis=-1)
    n = P0.shape[-2]
    out[..., np.arange(n), np.arange(n)] = np.inf
    return out


def collision_pairs(
    P0: Array, P1: Array, world: WorldConfig = DEFAULT_WORLD, tol_m: float = 1e-6
) -> list[tuple[int, int]]:
    """Pairs (i < j) whose discs overlap at any time during the step from P0 to P1."""
    d = swept_pair_distance(np.asarray(P0, np.float64), np.asarray(P1, np.float64))
    i, j = np.nonzero(np.triu(d < world.min_separation_m - tol_m, 1))
    return list(zip(i.tolist(), j.tolist(), strict=True))


def count_collisions(
    P0: Array, P1: Array, world: WorldConfig = DEFAULT_WORLD, tol_m: float = 1e-6
) -> Array:
    """Number of colliding pairs per env during one step, (...,) int."""
    d = swept_pair_distance(np.asarray(P0, np.float64), np.asarray(P1, np.float64))
    n = d.shape[-1]
    iu = np.triu_indices(n, 1)
    out: Array = (d[..., iu[0], iu[1]] < world.min_separation_m - tol_m).sum(-1)
    return out



def min_swept_separation(P0: Array, P1: Array) -> Array:
    """Closest approach of any two robots during the straight moves P0 -> P1, (...,) metres.

    ``P0``, ``P1``: (..., n, 2). The minimum of :func:`swept_pair_distance` over
    the pairs: what a step's moves, as commanded, bring two centres down to.
    """
    out: Array = swept_pair_distance(np.asarray(P0, np.float64), np.asarray(P1, np.float64)).min(
        axis=(-1, -2)
    )
    return out


def formation_measure(P: Array, C: Array) -> tuple[Array, Array]:
    """(formation error, farthest robot from its slot) per team, metres, in one assignment.

    ``P`` (..., n, 2), ``C`` (n, 2) or (..., n, 2) -> two arrays (...,). The centred
    optimal assignment without hysteresis: the error is the RMS slot distance,
    and "formed" is the second value within ``formed_tol_m``.
    """
    p = np.asarray(P, dtype=np.float64)
    flat = p.reshape(-1, *p.shape[-2:])
    c = np.broadcast_to(np.asarray(C, dtype=np.float64), p.shape).reshape(flat.shape)
    d = slot_distances(flat, c, assign_slots_batch(flat, c))
    err: Array = np.sqrt(np.mean(d * d, axis=-1)).reshape(p.shape[:-2])
    far: Array = d.max(axis=-1).reshape(p.shape[:-2])
    return err, far


# ----------------------------------------------------- contacts, pair-major layout
#
# The training world keeps positions robot-major, (2, N, E) (component, robot,
# env), and pair arrays as (P, E) over the N(N-1)/2 pairs: with the env axis
# innermost numpy's inner loops are long. These are the same geometry as
# swept_pair_distance in that layout.


@functools.lru_cache(maxsize=8)
def robot_pairs(n: int) -> tuple[IntArray, IntArray, Array]:
    """The n(n-1)/2 pairs i < j in ``np.triu_indices(n, 1)`` order: (i, j, D) with
    ``D`` (P, n) the difference operator, ``(D @ x)[p] = x[j_p] - x[i_p]`` exactly
    (each row holds one +1 and one -1, so the product rounds once, like ``-``)."""
    i, j = np.triu_indices(n, 1)
    D = np.zeros((len(i), n))
    D[np.arange(len(i)), j] = 1.0
    D[np.arange(len(i)), i] = -1.0
    D.flags.writeable = False
    return i.astype(np.int64), j.astype(np.int64), D


def swept_contacts(X0: Array, U: Array, limit_m: float) -> BoolArray:
    """Pairs whose closest approach during the straight moves X0 -> X0 + U is below ``limit_m``.

    ``X0``, ``U``: (2, N, E) positions and displacements. Returns (P, E) over
    the pairs of :func:`robot_pairs`. The closest approach is that of
    :func:`swept_pair_distance` (relative motion ``d(s) = d0 + s dd``, ``s`` in
    [0, 1]), computed pair-major.
    """
    D = robot_pairs(X0.shape[1])[2]
    d0 = D @ X0  # (2, P, E): x_j - x_i
    dd = D @ U
    a = d0[0] * d0[0] + d0[1] * d0[1]
    b = d0[0] * dd[0] + d0[1] * dd[1]
    c = dd[0] * dd[0] + dd[1] * dd[1]
    s = np.divide(-b, c, out=np.zeros_like(b), where=c > 0.0)  # the time of closest approach
    np.clip(s, 0.0, 1.0, out=s)
    hit: BoolArray = a + s * (2.0 * b + s * c) < limit_m * limit_m
    return hit


def overlaps(X: Array, limit_m: float) -> tuple[Array, Array, BoolArray]:
    """Every ordered pair's offset, squared distance and overlap, robot-major.

    ``X`` (2, N, k) -> (diff (2, N, N, k) with ``diff[:, i, j] = x_i - x_j``,
    squared distance (N, N, k) with a huge diagonal, overlap (N, N, k): closer
    than ``limit_m``).
    """
    diff = X[:, :, None, :] - X[:, None, :, :]
    d2 = diff[0] * diff[0] + diff[1] * diff[1]
    n = X.shape[1]
    d2[np.arange(n), np.arange(n)] = 1e18  # no robot overlaps itself
    over: BoolArray = d2 < limit_m * limit_m
    return diff, d2, over
