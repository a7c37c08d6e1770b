"""The world's last-resort guard for stale commands: no applied motion brings two discs together.

In realtime a command may be applied a few steps after the poses it was decided from
(:mod:`sim_bridge.world.world_link`, ``max_age_steps``): its robot's ORCA filter
kept it clear of where the others *were*, not of where they are, nor of what they do
now. So before the physics moves anyone, the world checks the step it is about to
take as the physics will take it (every robot in a straight line at its applied
velocity for ``dt``) and, for every pair whose centres would come closer than
``2R`` during the step (and closer than they already are), slows down the older
command of the two -- halving it, and stopping it below a twentieth of ``v_max`` --
then the fresher one if the pair still closes in. The check is repeated until no
pair closes in below ``2R``. It ends, and its result is safe, whatever the inputs:
each round slows at least one moving robot, a robot is stopped after a bounded
number of halvings, and robots that all stand still keep their distances. So with
stale commands, fresh ones and robots held still side by side, no new collision
(:func:`runtime.decision.formation.collision_pairs`, the world's own measure) comes
from the commands applied: by construction, not by luck.

Fresh commands (age 0) that their ORCA filters already made safe are left alone
unless a pair of them would really collide (a robot they expected to move stood
still), so in a swarm that is never late the guard does nothing.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from runtime.types import Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

TOL_M = 1e-6
"""The collision measure's tolerance (:func:`runtime.decision.formation.collision_pairs`)."""
STOP_FRACTION = 0.05
"""A command halved below this fraction of ``v_max`` is stopped."""


class Guarded(NamedTuple):
    """What the guard applied."""

    v: Array
    """(n, 2) velocities to apply, m/s, in the input's order."""
    scaled: IntArray
    """Rows whose velocity the guard slowed down or stopped."""


def _closest(p0: Array, dv: Array, dt: float) -> Array:
    """Closest centre distance over the step of pairs at offset ``p0`` closing at ``dv``."""
    d = dv * dt
    den = np.einsum("ij,ij->i", d, d)
    s = -np.einsum("ij,ij->i", p0, d) / np.where(den > 0, den, 1.0)
    s = np.clip(np.where(den > 0, s, 0.0), 0.0, 1.0)
    out: Array = np.linalg.norm(p0 + s[:, None] * d, axis=1)
    return out


def guard_stale(pos: Array, v: Array, age: IntArray, world: WorldConfig = DEFAULT_WORLD,
                arena_m: float | None = None) -> Guarded:
    """Slow the applied velocities ``v`` ((n, 2) m/s) of robots at ``pos`` ((n, 2) m) until
    no pair's straight motion over ``world.dt_s`` closes in below ``2R``; ``age`` (n,) says how
    many steps old each command is (0 fresh; a robot held still has velocity 0).

    With ``arena_m`` (the square arena's side, lower-left corner at the origin) a motion
    into a wall is first cut to the wall, as the physics' frictionless walls would slide
    it: so the straight motions checked are the ones the physics will make."""
    pos = np.asarray(pos, np.float64).reshape(-1, 2)
    n = len(pos)
    v = np.array(v, np.float64).reshape(n, 2)
    v = np.where(np.isfinite(v), v, 0.0)
    vmax, dt, sep = world.v_max_mps, world.dt_s, world.min_separation_m
    speed = np.hypot(v[:, 0], v[:, 1])
    v *= np.minimum(1.0, vmax / np.maximum(speed, 1e-300))[:, None]  # the physics' clamp
    if arena_m is not None:  # the wall takes the normal part of a motion into it
        r = world.radius_m
        lo, hi = (np.minimum(pos, r) - pos) / dt, (np.maximum(pos, arena_m - r) - pos) / dt
        v = np.clip(v, lo, hi)
    if n < 2:
        return Guarded(v, np.zeros(0, np.intp))
    # only pairs within reach of each other in one step can close in below 2R
    iu, ju = np.triu_indices(n, 1)
    p0 = pos[ju] - pos[iu]
    d0 = np.hypot(p0[:, 0], p0[:, 1])
    near = d0 < sep + 2.0 * vmax * dt + 1e-9
    iu, ju, p0, d0 = iu[near], ju[near], p0[near], d0[near]
    limit = np.minimum(sep, d0) - TOL_M
    age = np.asarray(age, np.int64).reshape(n)
    scaled = np.zeros(n, bool)
    while len(iu):
        closest = _closest(p0, v[ju] - v[iu], dt)
        bad = np.nonzero(closest < limit)[0]
        if not len(bad):
            break
        bi, bj = iu[bad], ju[bad]
        moving_i = np.any(v[bi] != 0.0, axis=1)
        moving_j = np.any(v[bj] != 0.0, axis=1)
        # the older command of each pair gives way first; the fresher one only when the
        # older has stopped (or both are as old)
        ai = np.where(moving_i, age[bi], -1)
        aj = np.where(moving_j, age[bj], -1)
        slow = np.unique(np.concatenate([bi[ai >= aj], bj[aj >= ai]]))
        slow = slow[np.any(v[slow] != 0.0, axis=1)]
        if not len(slow):  # cannot happen: a closing pair has a moving member
            break
        v[slow] *= 0.5
        sp = np.hypot(v[slow, 0], v[slow, 1])
        v[slow[sp < STOP_FRACTION * vmax]] = 0.0
        scaled[slow] = True
    return Guarded(v, np.nonzero(scaled)[0])
