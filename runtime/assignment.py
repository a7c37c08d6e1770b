"""A batched optimality certificate for slot assignments, numpy only.

Layout: env-last, as the training world keeps its arrays. ``cost`` is
(n, n, E) with ``cost[i, j, e]`` robot i to slot j in env e (m^2); an
assignment ``slots`` is (n, E), ``slots[i, e]`` robot i's slot.

Why a certificate and not a solver
    From one step to the next every robot moves at most one radius, so the
    shared assignment almost never changes: what a step needs is a proof that
    the previous assignment is still optimal, for all envs at once, and a
    real solve only where it is not. A permutation sigma is optimal exactly
    when the *exchange graph* has no negative cycle: nodes are robots, the
    edge i -> k costs ``w[i, k] = c[i, sigma(k)] - c[k, sigma(k)]`` (robot i
    takes k's slot, k gives it up), and the cost of any other assignment is
    sigma's plus the weights of the cycles that turn sigma into it.
    :func:`certify_assignment` runs Bellman-Ford from a virtual source over
    that graph, vectorised over envs (each round is one (n, n, E) add and a
    min over robots). An env whose distances settle has no cycle lighter than
    ``-n * tol_m2``: its assignment is optimal to within that bound. An env
    that still relaxes after ``max_rounds`` rounds is left uncertified (it
    may or may not have a better assignment) and is solved exactly by the
    caller. A certificate is therefore never wrong, only sometimes absent;
    :func:`runtime.formation.assign_slots_batch` uses it so that its result
    is exactly what scipy's Hungarian solver with the hysteresis rule gives
    (see there).

Rounding: distances are sums of at most n edge weights of magnitude
``max(cost)``, so their rounding error is about ``n * max(cost) * 1e-16``; for
the world's 10 m arena that is below 1e-12 m^2, far below the bound.

Cost (E = 64, n = 10, this 2-core machine): scipy's Hungarian costs ~3-5 us
an env (~200-350 us a step, with the Python loop); one Bellman-Ford round is
~10-20 us for all envs, and with the last step's potentials as a start (kept
by the training world) most envs settle within ``CERTIFY_ROUNDS`` rounds, so
scipy runs for a few envs a step. This module is the robot's and the
reference's numpy path; the training world runs the same proof compiled,
with an exact shortest-augmenting-path solver that breaks ties as scipy does
(``trainer/kernels.py``, numba: ~40 us a step for all envs in all).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from runtime.types import Array, BoolArray, IntArray

CERTIFY_ROUNDS = 3
"""Bellman-Ford rounds before an env is left to the exact solver. Two rounds
settle a world whose assignment did not change (measured: > 99 % of steps);
more rounds would only ever certify what the solver then confirms."""


def taken_index(slots: IntArray) -> IntArray:
    """Flat indices into a (n, n*E) view of an env-last cost: ``[k, e] -> slots[k, e] * E + e``."""
    E = slots.shape[1]
    out: IntArray = slots * E + np.arange(E)
    return out


def exchange_weights(cost: Array, slots: IntArray) -> Array:
    """The exchange graph of ``slots``: ``w[i, k, e] = c[i, slots[k], e] - c[k, slots[k], e]``.

    ``cost`` (n, n, E), ``slots`` (n, E) -> (n, n, E); the diagonal is 0.
    """
    n, E = slots.shape
    idx = taken_index(slots)
    taken = np.ascontiguousarray(cost).reshape(n, n * E)[:, idx]  # [i, k, e]: c[i, slots[k]]
    own = taken[np.arange(n), np.arange(n)]  # (n, E): c[k, slots[k]]
    w: Array = taken - own[None, :, :]
    return w


class Certificate(NamedTuple):
    """What :func:`certify_assignment` proves, per env."""

    settled: BoolArray
    """(E,) True: the assignment is optimal to within ``n * tol_m2``."""
    potentials: Array
    """(n, E) the robots' potentials in the exchange graph (m^2, up to a constant
    per env): a warm start for the next call on nearby costs."""


def certify_assignment(
    cost: Array,
    slots: IntArray,
    tol_m2: Array | float,
    potentials: Array | None = None,
    max_rounds: int = CERTIFY_ROUNDS,
) -> Certificate:
    """Which envs' ``slots`` are optimal to within ``n * tol_m2`` (plus rounding).

    ``cost`` (n, n, E) m^2; ``slots`` (n, E), a permutation of 0..n-1 in every
    env (not checked); ``tol_m2`` a scalar or one per env, (E,);
    ``potentials`` (n, E) a start for the Bellman-Ford distances (zeros by
    default), e.g. the last step's: any start gives a valid proof, a close one
    settles in one round. ``settled`` True is a proof: no assignment of that
    env costs less than ``sum_i cost[i, slots[i]] - n * tol_m2``, because at
    some round the distances satisfied ``d[k] <= d[i] + w[i, k] + tol`` on
    every edge, so every exchange cycle weighs at least ``-len * tol``. False
    means "not proven" within ``max_rounds`` rounds.
    """
    n, E = slots.shape
    # Row constants change no cycle's weight. For centred squared distances
    # |p_i|^2 + |q_j|^2 - 2 p_i.q_j, removing each robot's mean cost leaves
    # -2 p_i.q_j plus a slot constant: weights that move by ~|dp| |q| a step
    # instead of ~|dp| |p|, so the last step's potentials still (nearly) hold.
    w = exchange_weights(cost, slots)
    row = cost.mean(axis=1)  # (n, E)
    w -= row[:, None, :]
    w += row[None, :, :]
    tol = np.asarray(tol_m2, dtype=np.float64)
    d = np.zeros((n, E)) if potentials is None else np.array(potentials, dtype=np.float64)
    settled = np.zeros(E, dtype=bool)
    for _ in range(max(1, max_rounds)):
        cand = (d[:, None, :] + w).min(axis=0)  # (n, E): shortest walks one edge longer
        settled |= (cand >= d - tol).all(axis=0)  # the proof, at this round's d
        if settled.all():
            break
        np.minimum(d, cand, out=d)  # plain relaxation; the proof is only ever the check
    d -= d.max(axis=0)  # only differences count: keep the numbers small
    return Certificate(settled, d)


def certify_team(
    cost: Array,
    slots: IntArray,
    tol_m2: float,
    duals: Array,
    max_rounds: int = CERTIFY_ROUNDS,
    work: Array | None = None,
) -> bool:
    """:func:`certify_assignment` for one team, in its dual form: the robot's proof.

    ``cost`` (n, n) m^2, ``[i, j]`` robot i to slot j; ``slots`` (n,) a
    permutation (not checked); ``duals`` (n,) one potential per *slot* (m^2),
    kept by the caller from step to step and updated in place (zeros at first).
    True proves that no assignment costs less than ``sum_i cost[i, slots[i]] -
    n * tol_m2`` (plus rounding, as above). ``work``: an (n, n) scratch array to
    use instead of allocating one per round.

    The same Bellman-Ford proof as :func:`certify_assignment`, with the
    potential of robot k written as that of the slot it holds,
    ``v[slots[k]] = c[k, slots[k]] + d[k]``: then ``d[k] <= d[i] + w[i, k] + tol``
    on every exchange edge reads ``cost[i, j] - u[i] - v[j] >= -tol`` for every
    robot i and slot j, with ``u[i] = cost[i, slots[i]] - v[slots[i]]`` (LP duals
    within ``tol`` of feasible), and a relaxation round is ``v[j] <- min(v[j],
    min_i cost[i, j] - u[i])``. Why this form for one team: it needs no exchange
    graph (no gather of (n, n)), a row constant of the cost cancels in ``u`` by
    itself, and a slot's potential stays valid while robots move (they are the
    pattern's, not the robots'), so one round proves most steps: about five numpy
    calls on (n, n) where scipy's solver costs 60-110 us at n = 100.
    """
    n = slots.shape[0]
    if n == 0:
        return True
    rows = np.arange(n)
    for _ in range(max(1, max_rounds)):
        u = cost[rows, slots] - duals[slots]  # (n,) the robots' potentials
        reduced = np.subtract(cost, u[:, None], out=work)
        lowest = reduced.min(axis=0)  # (n,) per slot: min_i cost[i, j] - u[i]
        if bool((lowest >= duals - tol_m2).all()):
            return True
        np.minimum(duals, lowest, out=duals)  # one relaxation; the check above is the proof
        if not np.isfinite(duals).all():  # a non-finite cost: start again next time
            duals[:] = 0.0
            return False
        duals -= duals.max()  # only differences count: keep the numbers small
    return False


def is_permutation(slots: IntArray) -> BoolArray:
    """Whether each column of ``slots`` (n, E) is a permutation of 0..n-1, (E,)."""
    n = slots.shape[0]
    s = np.sort(slots, axis=0)
    ok: BoolArray = (s == np.arange(n)[:, None]).all(axis=0)
    return ok


__all__ = [
    "CERTIFY_ROUNDS",
    "Certificate",
    "certify_assignment",
    "certify_team",
    "exchange_weights",
    "is_permutation",
    "taken_index",
]
