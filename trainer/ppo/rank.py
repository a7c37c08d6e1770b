"""Ranks along the team axis: the order in which a paper brain tells its robots apart.

The paper's observation lists the other robots nearest first, so the same
robot appears at a different place in the input as the team moves, and two
robots at equal distance swap half the input between steps: a brain cannot
learn "which slot is mine" from it (brains trained on it formed their
pattern in 0 % of episodes). A robot's **rank** is a label that every robot of the
team agrees on and that changes only when two robots pass each other along a
fixed direction ``u`` (the *team axis*): the number of others whose
projection on ``u`` is below its own,

    rank_i = #{ j != i : u . (p_j - p_i) < 0 }     in 0 .. n-1.

It is computed from the paper's observation alone (the others' relative
positions at frame t), needs no message and no shared frame beyond the axes
the observation already uses. Matching the k-th robot along ``u`` to the k-th
slot along ``u`` is a permutation, so a team in which every robot reaches
"its" slot forms the pattern; when two robots pass each other they swap
labels and goals, which keeps the matching a permutation at every step.

``TEAM_AXIS_DEG`` is the direction that keeps the slots of the five built-in
10-robot patterns farthest apart along ``u`` (smallest gap 4.8 cm, the circle
and the heart, nearly twice the formed tolerance of 2.5 cm, so the labels of a
team about to form hardly ever swap): :func:`axis_gap` finds it with a sweep
over 0.01 degree.
"""

from __future__ import annotations

import math

import numpy as np

from runtime.types import Array, IntArray

TEAM_AXIS_DEG = 75.62
TEAM_AXIS: Array = np.array(
    [math.cos(math.radians(TEAM_AXIS_DEG)), math.sin(math.radians(TEAM_AXIS_DEG))]
)


def ranks(X: Array, axis: Array = TEAM_AXIS) -> IntArray:
    """Each robot's rank along ``axis``: (2, N, E) robot-major positions -> (N, E).

    Ties (equal projections, a set of measure zero) are broken by robot index,
    as a stable sort does.
    """
    s = axis[0] * X[0] + axis[1] * X[1]  # (N, E)
    order = np.argsort(s, axis=0, kind="stable")
    out = np.empty_like(order)
    np.put_along_axis(out, order, np.arange(s.shape[0])[:, None], axis=0)
    return out


def rank_goals(X: Array, C: Array, axis: Array = TEAM_AXIS) -> tuple[Array, Array]:
    """Each robot's slot under the rank matching, and its distance to it.

    ``X`` (2, N, E) positions (m); ``C`` (2, N, E) each env's pattern, centred.
    The k-th robot along ``axis`` goes to the k-th slot along ``axis``, placed
    about the team's centroid. Returns goals (2, N, E) in world coordinates and
    distances (N, E) (m).
    """
    slot_rank = ranks(C, axis)  # (N, E): slot s is the slot_rank[s]-th along the axis
    by_rank = np.empty_like(slot_rank)
    np.put_along_axis(by_rank, slot_rank, np.arange(C.shape[1])[:, None], axis=0)
    mine = np.take_along_axis(by_rank, ranks(X, axis), axis=0)  # (N, E) slot index
    goals = np.take_along_axis(C, mine[None], axis=1) + X.mean(axis=1, keepdims=True)
    d = X - goals
    return goals, np.sqrt(d[0] * d[0] + d[1] * d[1])


def axis_gap(patterns: list[Array], steps: int = 18000) -> tuple[float, float]:
    """The axis angle (degrees, in [0, 180)) whose smallest gap between two slots'
    projections, over all ``patterns`` ((n, 2) each), is largest; and that gap (m)."""
    best_gap, best_deg = -1.0, 0.0
    for deg in np.linspace(0.0, 180.0, steps, endpoint=False):
        u = np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])
        gap = min(float(np.diff(np.sort(np.asarray(C) @ u)).min()) for C in patterns)
        if gap > best_gap:
            best_gap, best_deg = gap, float(deg)
    return best_deg, best_gap
