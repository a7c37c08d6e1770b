"""Slot agreement: robots that tell each other their slots settle who goes where.

Every robot solves the team's assignment on its own view (:mod:`runtime.core.assignment`).
In the perfect world every view is the same and so is every assignment. Under noise each
view differs, and where the cost has near or exact ties (from a formed circle to the cross
the two shapes share their symmetry) the noise breaks them a different way for each robot:
two robots then head for one slot and the filter holds them apart until their views agree.
That cost short transitions most: circle -> cross took 3.87x its steps bound under the
realistic preset (10 robots, 20 episodes), 2 to 4 robots of 10 holding a slot another also
held for the first 6 steps.

The agreement (:class:`SlotAgreement`, one per robot): every step each robot tells its slot
(its claim), and the team's leader, the robot with the lowest id (row 0 of a team ordered by
id), also tells its whole assignment. A robot that hears a peer claim the slot it holds itself
(two robots going for one slot: they disagree)
takes the leader's assignment as last heard for the whole team, its own plan included; a
robot that hears no such claim keeps its own. The leader keeps its own: it is the
reference. A claim is a step old at the soonest, so a robot compares it with its slot now:
compared with its slot at the step the peer told it, a robot that has just moved onto a
peer's slot would hear of it a step later, and circle -> cross took 2.62x, against 2.34x.
In the perfect world every robot's assignment is the same, and the agreement is off there
(it would only hold a swap back a step).

What a robot hears is a message, which the sensing conditions delay and lose as they do a
peer's pose (:class:`Hearing`: told at step ``s``, heard at ``s + max(1, latency_steps)``,
since robots decide a step at once and a message told at it is heard at the next at the
soonest; lost with chance ``loss``, the last heard kept). A robot process tells and hears
over Zenoh (``patternrl robot --agree``, :mod:`runtime.robot.slot_talk`) through the same
:class:`Hearing`. A peer heard to claim another slot than the robot's does not contest its
landing (:meth:`runtime.decision.controller.Controller._contested`).

Measured (``benchmarks/agreement.py``, ``benchmarks/results/agreement.txt``;
``rule:frame-balanced`` + the tracker, 10 robots, from a formed circle to the cross, 200
episodes): the realistic preset 3.78x -> 2.45x the steps bound, 5 cm of noise 2.68x -> 1.59x,
0 collisions both ways; from random starts n = 50 realistic 1.325x -> 1.312x. Taking the
leader's assignment always, conflict or not, cost n = 50 0.027x: its assignment is a step late
and solved on the leader's view of each robot, where the robot's own is exact. Each robot hears
n - 1 messages a step: on one 2-core machine simulating a whole swarm of 50 a launch took 3.8x
as long, so robots agree only when asked (``--agree``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from runtime.conditions import MAX_LATENCY_STEPS, Conditions
from runtime.types import IntArray

__all__ = ["HEARD_STEPS", "Heard", "Hearing", "SlotAgreement", "is_permutation"]

HEARD_STEPS = MAX_LATENCY_STEPS + 12
"""A claim told longer ago than this (steps) is too old to say anything and is not compared."""


def is_permutation(slots: IntArray, n: int) -> bool:
    """Whether ``slots`` gives each of n robots its own slot in 0..n-1."""
    a = np.asarray(slots)
    if a.shape != (n,) or not np.issubdtype(a.dtype, np.integer):
        return False
    if n == 0:
        return True
    if int(a.min()) < 0 or int(a.max()) >= n:
        return False
    return bool(np.bincount(a, minlength=n).max() == 1)


@dataclass(frozen=True)
class Heard:
    """What one robot has heard of its team's slots (n robots, ordered by id)."""

    claims: IntArray
    """(n,) each robot's slot as it last told it (-1: nothing heard)."""
    claim_steps: IntArray
    """(n,) the step each claim was told at (-1: nothing heard)."""
    leader: IntArray | None = None
    """(n,) the leader's whole assignment as last heard (None: nothing heard)."""


class SlotAgreement:
    """One robot's side of the agreement (see the module docstring)."""

    def __init__(self) -> None:
        self.adopted = False
        """Whether the last step took the leader's assignment."""

    def reset(self) -> None:
        """A new team or pattern."""
        self.adopted = False

    def agree(self, i: int, own: IntArray, step: int, heard: Heard | None) -> IntArray:
        """The team's slots robot ``i`` goes by at ``step``: ``own`` (its assignment,
        (n,)) or, where a peer's claim heard within :data:`HEARD_STEPS` is its own slot,
        the leader's (a copy)."""
        n = len(own)
        self.adopted = False
        if (heard is None or i == 0 or heard.leader is None or len(heard.claims) != n
                or not is_permutation(heard.leader, n)):
            return own
        c, s = heard.claims, heard.claim_steps
        clash = (c == own[i]) & (s >= 0) & (step - s <= HEARD_STEPS)
        clash[i] = False
        if not clash.any():
            return own
        self.adopted = True
        return np.array(heard.leader, dtype=np.int64)


class Hearing:
    """What B robots, in E teams of n, hear of what their teams tell, under ``conditions``:
    what each robot told at step ``s`` (its slot; the leader, row 0, its assignment) is
    heard at ``s + max(1, latency_steps)``, each peer's message lost with chance ``loss`` and the
    last heard kept. Robot ``b = e * n + i`` is row i of team e. Seeded (an int or a sequence
    of them): the same seed, the same losses."""

    def __init__(self, conditions: Conditions, n_envs: int, n_robots: int,
                 seed: int | Sequence[int]) -> None:
        E, n = n_envs, n_robots
        self.n_envs, self.n_robots = E, n
        self.delay = max(1, conditions.latency_steps)
        self.loss = float(conditions.loss)
        key = [seed] if isinstance(seed, int) else list(seed)
        self._rng = np.random.default_rng(np.random.SeedSequence([*key, 0x5107]))
        self._told: dict[int, tuple[IntArray, IntArray]] = {}  # step -> (claims, leaders)
        self.claims = np.full((E * n, n), -1, dtype=np.int64)
        self.claim_steps = np.full((E * n, n), -1, dtype=np.int64)
        self.leader = np.full((E * n, n), -1, dtype=np.int64)
        self._has_leader = np.zeros(E * n, dtype=bool)

    def restart(self, envs: IntArray) -> None:
        """These teams start again: nothing heard."""
        n = self.n_robots
        rows = (np.asarray(envs, dtype=np.int64)[:, None] * n + np.arange(n)).ravel()
        self.claims[rows] = -1
        self.claim_steps[rows] = -1
        self._has_leader[rows] = False

    def tell(self, step: int, slots: IntArray, leaders: IntArray) -> None:
        """After :meth:`hear` of ``step``: what every robot told at it: its slot (E, n) (-1:
        none), and each team's leader its assignment (E, n)."""
        self._told[step] = (np.array(slots, dtype=np.int64), np.array(leaders, dtype=np.int64))
        for s in [s for s in self._told if s <= step - self.delay]:  # heard at s + delay
            del self._told[s]

    def hear(self, step: int) -> None:
        """Take in what arrives at ``step`` (what was told ``delay`` steps before)."""
        src = step - self.delay
        got = self._told.get(src)
        if got is None:
            return
        E, n = self.n_envs, self.n_robots
        slots, leaders = got
        arrive = self._rng.random((E * n, n)) >= self.loss if self.loss > 0 else np.ones(
            (E * n, n), dtype=bool)
        told = np.repeat(slots, n, axis=0)  # (E n, n): row b hears its team's claims
        arrive &= told >= 0
        self.claims[arrive] = told[arrive]
        self.claim_steps[arrive] = src
        lead = arrive[:, 0] & (np.repeat(leaders, n, axis=0) >= 0).all(axis=1)
        self.leader[lead] = np.repeat(leaders, n, axis=0)[lead]
        self._has_leader |= lead

    def heard(self, b: int) -> Heard:
        """What robot ``b`` has heard."""
        return Heard(self.claims[b], self.claim_steps[b],
                     self.leader[b] if self._has_leader[b] else None)
