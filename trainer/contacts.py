"""The training world's contact model: rigid discs that never interpenetrate.

Positions are robot-major, (2, N, E) (component, robot, env), as the training
world keeps them (see :mod:`trainer.training_world`).

Robots are rigid discs of radius R: a pair whose straight
swept paths come closer than 2R during the step (the closest approach of
:func:`runtime.formation.swept_pair_distance`, the definition behind
``count_collisions``, computed here in the layout above; a test holds
the two equal) is a *collision* and counted, one per pair per step, and
charged to both robots. Overlaps left at the end of the move
are resolved by a few vectorised Jacobi sweeps of pairwise projection:
each overlapping pair is pushed apart symmetrically along its centre
line to exactly 2R (sweeps after the first over-relax, so a jam of many
discs clears in a few sweeps and may end with gaps slightly above 2R);
a pair pushed apart in a later sweep (a robot shoved into a third one)
is a collision too. This is what the pymunk world
shows: discs that meet are pushed apart by the contact and never
interpenetrate, and a robot that drives into another one stops at
contact instead of passing. Should a jam not clear within
``CONTACT_SWEEPS`` sweeps, the robots still overlapping hold their
previous (valid) positions (counted in ``BatchWorld.contact_fallbacks``);
so after every step all centres are at least 2R apart (to 1e-6 m).
The projection needs ``v_max dt <= R`` (the default is exactly R):
then no centre can cross another's within a step, so a push never
swaps two robots; other worlds are refused. The plane has no walls:
the arena only bounds the starts.
"""

from __future__ import annotations

import numpy as np

from runtime.formation import overlaps, robot_pairs, swept_contacts
from runtime.types import Array, BoolArray, IntArray

CONTACT_TOL_M = 1e-6
"""Two centres closer than 2R - this are interpenetrating (count_collisions' default)."""

CONTACT_SWEEPS = 16
"""Jacobi projection sweeps before the hold-still fallback."""

CONTACT_OVER_RELAX = 1.7
"""Over-relaxation of the sweeps after the first. A jam of ten robots all driven at
their centroid needs a median of 19 plain Jacobi sweeps (99th percentile 31) but
6 (99th percentile 9, never more than 12) over-relaxed; an isolated pair is
resolved by the first, plain sweep to exactly 2R."""


def move(X0: Array, U: Array, two_r: float) -> tuple[Array, IntArray | None, IntArray | None, int]:
    """Move every robot by ``U`` from ``X0`` (both (2, N, E), m) and resolve contacts.

    Returns (positions (2, N, E), collisions each robot took part in (N, E),
    colliding pairs per env (E,), robots held still by the fallback); the two
    counts are None when no pair came closer than 2R anywhere.
    """
    X1 = X0 + U
    hit = swept_contacts(X0, U, two_r - CONTACT_TOL_M)  # (P, E)
    k = np.flatnonzero(hit.any(axis=0))
    if not len(k):
        return X1, None, None, 0
    n = X0.shape[1]
    pi, pj, _ = robot_pairs(n)
    pairs = np.zeros((n, n, len(k)), dtype=bool)
    pairs[pi, pj] = pairs[pj, pi] = hit[:, k]
    Xk, touched, fallbacks = resolve(X0[:, :, k], X1[:, :, k], pairs, two_r)
    X1[:, :, k] = Xk
    hits = np.zeros((n, X0.shape[2]), dtype=np.int64)
    hits[:, k] = touched.sum(axis=1)
    return X1, hits, hits.sum(axis=0) // 2, fallbacks


def resolve(X0: Array, X1: Array, hit: BoolArray, two_r: float) -> tuple[Array, BoolArray, int]:
    """Push overlapping discs apart; ``X0``, ``X1`` (2, N, k), ``hit`` (N, N, k).

    Returns the resolved positions, every pair that touched, and how many
    robots the fallback held still. Two centres exactly on top of each other
    have no centre line to push along; they are left to the hold-still
    fallback (it never happens with real-valued motion).
    """
    limit = two_r - CONTACT_TOL_M
    X = X1.copy()
    touched = hit.copy()
    half_push = 0.5
    for _ in range(CONTACT_SWEEPS):
        diff, d2, over = overlaps(X, limit)  # diff[:, i, j] = x_i - x_j
        if not over.any():
            return X, touched, 0
        touched |= over
        # each robot of an overlapping pair moves (2R - d) / 2 along the centre line
        push = over * (half_push * (two_r / np.sqrt(np.fmax(d2, 1e-24)) - 1.0))
        X += np.einsum("kije,ije->kie", diff, push)
        half_push = 0.5 * CONTACT_OVER_RELAX
    # jammed: robots still overlapping hold their previous (valid) positions
    fallbacks = 0
    for _ in range(X.shape[1] + 1):
        over = overlaps(X, limit)[2]
        stuck = over.any(axis=1)
        if not stuck.any():
            break
        fallbacks += int(stuck.sum())
        touched |= over
        X[:, stuck] = X0[:, stuck]
    return X, touched, fallbacks
