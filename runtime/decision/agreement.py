"""Agreement: robots that tell each other their plan's frame and their slots.

What robots tell each other is a mode of :data:`AGREE_MODES` (``--agree``): ``frame``, the
default, under noise the leader its plan's frame and every robot plans in it ("The plan's
frame" below); ``slots`` every robot its slot too, and the leader its assignment (the slot
agreement); ``off`` nothing.

Every robot solves the team's assignment on its own view (:mod:`runtime.core.assignment`).
In the perfect world every view is the same and so is every assignment. Under noise each
view differs, and where the cost has near or exact ties (from a formed circle to the cross
the two shapes share their symmetry) the noise breaks them a different way for each robot:
two robots then head for one slot and the filter holds them apart until their views agree.
That cost short transitions most: circle -> cross took 3.87x its steps bound under the
realistic preset (10 robots, 20 episodes), 2 to 4 robots of 10 holding a slot another also
held for the first 6 steps.

The slot agreement (:class:`SlotAgreement`, one per robot): every step each robot tells its slot
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

**The plan's frame.** Under noise each robot's plan goes in the team's centroid frame as it
sees it (:mod:`runtime.decision.settle`, "The centroid frame from the start"): the one frame
robots agree on without telling each other anything, since the centroid averages every
robot's noise, where ``rule:frame-balanced``'s frame rests on the two or three farthest robots
and carries their noise whole. Its geometry costs: from the same starts at n = 50 the
synchronised plan takes 1.202x the steps lower bound in the centroid frame, 1.112x in
``rule:frame-balanced``'s. Under the agreement the leader solves its plan's frame on its own
view each step and tells the mean of those so far (:meth:`SlotAgreement.lead_frame`; the
frame a team heading for its slots in it keeps still, so the mean settles as the noise
averages out), and every other robot's plan goes in the leader's frame as last heard
(:meth:`SlotAgreement.follow_frame`), in its own until it hears one: one frame for the team,
the balanced one. A heard frame farther from the robot's own than any plan of its team could
put it (:meth:`runtime.decision.controller.Controller._frame_reach`) is not taken.

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
0 collisions both ways (both without the leader's frame). Taking the leader's assignment always,
conflict or not, cost n = 50 0.027x: its assignment is a step late and solved on the leader's
view of each robot, where the robot's own is exact. With slots each robot hears n - 1
messages a step: on one 2-core machine simulating a whole swarm of 50 a launch took 3.8x as
long, so robots tell their slots only when asked (``--agree slots``); the leader's frame alone
is one message a step and on by default under noise (``--agree frame``): from random starts,
``benchmarks/conditions.py``'s seeds, n = 50 realistic 1.325x (``--agree off``) -> 1.293x
(``frame``) -> 1.268x (``slots``), n = 10 1.188x -> 1.145x
(``benchmarks/results/conditions_leader_frame.txt``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from runtime.conditions import MAX_LATENCY_STEPS, Conditions
from runtime.types import Array, IntArray

__all__ = ["AGREE_MODES", "DEFAULT_AGREE", "FRAME_MIN_STEPS", "HEARD_STEPS", "LEAD_SLACK_STEPS",
           "Heard", "Hearing", "SlotAgreement", "add_agree_argument", "agree_mode", "hears",
           "is_permutation", "local_and_imperfect", "local_views"]

AGREE_MODES = ("off", "frame", "slots", "auto")
"""What robots tell each other (``--agree MODE``): nothing; under noise the leader its plan's
frame, which the others plan in (one message a step, the leader's); under imperfect
sensing every robot its slot and the leader its assignment and frame too (n (n - 1)
deliveries a step); or ``auto``: ``slots`` where a robot's views are local (its k nearest
peers, or those within a range) and imperfect in any other way too, else ``frame``
(:func:`agree_mode`)."""
DEFAULT_AGREE = "auto"
"""What robots tell each other unless asked otherwise: the leader's frame under noise, and
their slots too where views are local and imperfect otherwise."""


FRAME_MIN_STEPS = 15
"""A leader tells no frame for a pattern whose plan at its first step is shorter than this
(steps): on the demo's short transitions (a bound of 5-12 steps at 10 robots) the mean of
its frames still moved while the team landed (circle -> cross, 5 cm of noise, 2.65x -> 2.76x
the bound with a frame)."""
LEAD_SLACK_STEPS = 10
"""Steps past twice its plan's the leader goes by the frame it tells
(:meth:`SlotAgreement.lead_due`)."""


def agree_mode(value: bool | str | None, conditions: Conditions | None = None) -> str:
    """A mode of :data:`AGREE_MODES` from ``value``: True is ``slots`` (a bare ``--agree``),
    False and None ``off``; ValueError for anything else. ``auto`` is resolved under
    ``conditions`` (None: as it stays, ``auto``): ``slots`` where the views are local and
    imperfect in another way too, ``frame`` elsewhere. A robot that sees only its k nearest
    carries the peers out of its view along its own plan, and under noise the robots' plans
    may differ from the start (each solves the assignment on its own noisy roll call): a
    robot whose plan put a peer it never sees again on another slot than the peer took
    heads for a slot another robot holds and never learns of it, unless the two tell their
    slots (n = 25, the realistic preset with 6 nearest seen, ``benchmarks/conditions.py``,
    100 episodes: 84 %, 1.363x -> 99 %, 1.226x; docs/conditions.md, "Local views tell their
    slots"). With local views alone, exact and on time, every plan is the same and slots
    add nothing to tell."""
    if value is None or value is False:
        return "off"
    if value is True:
        return "slots"
    if value not in AGREE_MODES:
        raise ValueError(f"agree must be one of {', '.join(AGREE_MODES)}, got {value!r}")
    if value == "auto" and conditions is not None:
        return "slots" if local_and_imperfect(conditions) else "frame"
    return str(value)


def local_views(c: Conditions) -> bool:
    """Whether a robot under ``c`` sees only part of its team: its k nearest peers, or
    those within a range."""
    return c.k_nearest > 0 or math.isfinite(c.range_m)


def local_and_imperfect(c: Conditions) -> bool:
    """Whether a robot under ``c`` sees only part of its team (:func:`local_views`), and its
    views are noisy, late or lost too."""
    return local_views(c) and (c.noise_m > 0.0 or c.latency_steps > 0 or c.loss > 0.0)


def add_agree_argument(parser: Any, who: str = "the robots") -> None:
    """``--agree [MODE]`` on ``parser`` (an argparse parser or group): the mode of
    :data:`AGREE_MODES`, :data:`DEFAULT_AGREE` unless given, ``slots`` when bare."""
    parser.add_argument(
        "--agree", nargs="?", const="slots", default=DEFAULT_AGREE, choices=AGREE_MODES,
        metavar="MODE",
        help=f"what {who} tell each other: 'frame': under noisy --conditions "
        "the lowest-id robot tells its plan's frame each step (robot/<id>/slots) and every "
        "robot plans in it, one frame for the team; 'slots' (a bare --agree): under "
        "imperfect --conditions every robot also tells the slot it goes by, the lowest-id "
        "robot its whole assignment, and a robot that hears a peer claim its own slot goes "
        "by that assignment (n (n - 1) messages a step); 'auto' (the default): 'slots' where "
        "--conditions make views local (k_nearest, range_m) and noisy, late or lost too, "
        "else 'frame'; 'off': nothing")


def hears(mode: bool | str | None, conditions: Conditions) -> bool:
    """Whether robots under ``conditions`` that agree as ``mode`` tell each other anything:
    slots under imperfect sensing, the frame under noise only (exact views, late or lost,
    already give every robot the same frame)."""
    m = agree_mode(mode, conditions)
    if m == "slots":
        return not conditions.sensing_perfect
    return m == "frame" and conditions.noise_m > 0.0

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
    frame: Array | None = None
    """(2,) m the leader's plan frame as last heard (None: nothing heard; see
    :meth:`SlotAgreement.frame`)."""


class SlotAgreement:
    """One robot's side of the agreement (see the module docstring)."""

    def __init__(self, partial: bool = False) -> None:
        self.partial = partial
        """Whether the robot sees only part of its team (:func:`local_views`): it carries
        the peers out of its view along its own plan, and a peer heard to claim another slot
        than the robot's assignment gives it is a conflict too (:meth:`agree`)."""
        self.reset()

    def reset(self) -> None:
        """A new team or pattern."""
        self.adopted = False
        """Whether the last step took the leader's assignment."""
        self._frame_sum = np.zeros(2)
        self._frame_count = 0
        self.told_frame: Array | None = None
        """(2,) m the plan frame this robot tells as the leader, or its landing frame
        (:meth:`tell_landing`; None: none yet)."""
        self.heard_frame = False
        """Whether the last step's plan went in the leader's frame, as heard."""
        self._land: tuple[Array, int] | None = None  # the leader's landing frame and its steps
        self._lead_k0: float | None = None  # the leader's plan's steps at its first step

    def lead_frame(self, planned: Array, steps_left: float) -> Array | None:
        """The leader's plan frame (2,) m under noise, which it goes by and tells: the mean
        of ``planned``, its plan's frame as it solves it each step on its own view, over the
        pattern's steps so far (its noise averages out; the frame a team heading for its
        slots in it keeps still). None (it tells none, and every robot keeps its own) where
        the plan of the pattern's first step, ``steps_left`` then, is shorter than
        :data:`FRAME_MIN_STEPS`: the mean would still move while the team lands."""
        if self._lead_k0 is None:
            self._lead_k0 = steps_left
        if self._lead_k0 < FRAME_MIN_STEPS:
            return None
        self._frame_sum += np.asarray(planned, dtype=np.float64)
        self._frame_count += 1
        self.told_frame = self._frame_sum / self._frame_count
        return self.told_frame.copy()

    def tell_landing(self, m: Array) -> Array | None:
        """The frame (2,) m the leader lands in and tells where it sees only part of its
        team (:attr:`partial`) and declined a plan frame (its first plan was short): its
        landing frame ``m`` (None where it sees all of its team: each robot lands in its own,
        the team's centroid, the same for all). Each in the frame its nearest peers show, the
        robots' frames differed by centimetres that views with noise do not average away,
        and a team on a short transition crept to the tolerance for tens of steps or never
        held (8 robots that see their 4 nearest, the realistic preset, 40 episodes at seed
        12, both with :func:`runtime.decision.landing_frame.view_centroid`: cross -> line held
        60 % -> 100 %, line -> heart 5 % -> 55 %; docs/conditions.md, "Small teams that see
        few of their peers land in one frame")."""
        if not self.partial:
            return None
        self.told_frame = np.array(m, dtype=np.float64)
        return self.told_frame.copy()

    @property
    def frame_declined(self) -> bool:
        """Whether the leader tells no frame for this pattern (its first plan was short):
        nothing more to solve for it."""
        return self._lead_k0 is not None and self._lead_k0 < FRAME_MIN_STEPS

    def lead_due(self) -> bool:
        """Whether the leader has led long enough that its team, had it followed, would
        stand formed: twice its plan's steps from the pattern's first step, and
        :data:`LEAD_SLACK_STEPS` more. From then on it lands where the team's core stands
        (:meth:`land_frame`)."""
        k0 = math.inf if self._lead_k0 is None else self._lead_k0
        return self._frame_count > 2.0 * k0 + LEAD_SLACK_STEPS

    def land_frame(self, core: Array, weight: Any, gate: float) -> Array:
        """The leader's frame (2,) m for its plan's last steps: the frame its team's core
        stands in (``core``, :func:`runtime.decision.landing_frame.core_frame` of its view),
        averaged from the frame it told (the mean of each step's, ``weight(k)`` of the k-th,
        one that comes ``gate`` m or more off moving it at once): where the others went by
        the leader's frame their core stands in it and nothing moves; where they never heard
        it, the leader lands in theirs."""
        if self._land is None:
            self._land = (np.array(self.told_frame if self.told_frame is not None else core,
                                   dtype=np.float64), 0)
        prev, k = self._land
        c = np.asarray(core, dtype=np.float64)
        off = math.hypot(*(c - prev).tolist()) / gate if gate > 0.0 else math.inf
        g = float(weight(k + 1))
        g = g + (1.0 - g) * min(1.0, off * off)
        m = prev + g * (c - prev)
        self._land = (m, k + 1)
        return m.copy()

    def follow_frame(self, heard: Heard | None, own: Array, within_m: float) -> Array | None:
        """The plan frame (2,) m a robot other than the leader goes by under noise: the
        leader's as last heard, where it lies within ``within_m`` of ``own``, the frame the
        robot would go by itself (None: none heard yet, or one no plan of this team could
        have: it goes by its own)."""
        self.heard_frame = False
        if heard is None or heard.frame is None:
            return None
        f = np.array(heard.frame, dtype=np.float64)
        if not np.isfinite(f).all() or math.hypot(*(f - own).tolist()) > within_m:
            return None
        self.heard_frame = True
        return f

    def agree(self, i: int, own: IntArray, step: int, heard: Heard | None) -> IntArray:
        """The team's slots robot ``i`` goes by at ``step``: ``own`` (its assignment,
        (n,)) or, where a peer's claim heard within :data:`HEARD_STEPS` is its own slot,
        the leader's (a copy). A robot that sees only part of its team (:attr:`partial`)
        also takes the leader's where a peer claims another slot than ``own`` gives it: it
        carries a peer out of its view along its own plan, and a peer whose slot its plan
        has wrong stays wrong in its view, where its landing reads the team's core (8 robots
        that see their 4 nearest, the realistic preset, circle -> cross and cross -> line,
        20 episodes each, slots: formed 50 % / 20 % -> 100 % / 95 %, 14 colliding pairs ->
        0; docs/conditions.md, "A robot that sees part of its team takes a peer's claim
        against its plan")."""
        n = len(own)
        self.adopted = False
        if (heard is None or i == 0 or heard.leader is None or len(heard.claims) != n
                or not is_permutation(heard.leader, n)):
            return own
        c, s = heard.claims, heard.claim_steps
        fresh = (s >= 0) & (step - s <= HEARD_STEPS)
        clash = (c == own[i]) & fresh
        if self.partial:  # a peer it may not see goes elsewhere than its plan has it
            clash |= (c >= 0) & (c != own) & fresh
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
        self._told: dict[int, tuple[IntArray, IntArray, Array]] = {}  # step -> what was told
        self.claims = np.full((E * n, n), -1, dtype=np.int64)
        self.claim_steps = np.full((E * n, n), -1, dtype=np.int64)
        self.leader = np.full((E * n, n), -1, dtype=np.int64)
        self._has_leader = np.zeros(E * n, dtype=bool)
        self.frame = np.full((E * n, 2), np.nan)

    def restart(self, envs: IntArray) -> None:
        """These teams start again: nothing heard."""
        n = self.n_robots
        rows = (np.asarray(envs, dtype=np.int64)[:, None] * n + np.arange(n)).ravel()
        self.claims[rows] = -1
        self.claim_steps[rows] = -1
        self._has_leader[rows] = False
        self.frame[rows] = np.nan

    def tell(self, step: int, slots: IntArray, leaders: IntArray,
             frames: Array | None = None) -> None:
        """After :meth:`hear` of ``step``: what every robot told at it: its slot (E, n) (-1:
        none), and each team's leader its assignment (E, n) and its plan frame (E, 2) m
        (NaN or None: none)."""
        E = self.n_envs
        f = np.full((E, 2), np.nan) if frames is None else np.array(frames, dtype=np.float64)
        self._told[step] = (np.array(slots, dtype=np.int64), np.array(leaders, dtype=np.int64),
                            f)
        for s in [s for s in self._told if s <= step - self.delay]:  # heard at s + delay
            del self._told[s]

    def hear(self, step: int) -> None:
        """Take in what arrives at ``step`` (what was told ``delay`` steps before)."""
        src = step - self.delay
        got = self._told.get(src)
        if got is None:
            return
        E, n = self.n_envs, self.n_robots
        slots, leaders, frames = got
        arrive = self._rng.random((E * n, n)) >= self.loss if self.loss > 0 else np.ones(
            (E * n, n), dtype=bool)
        told = np.repeat(slots, n, axis=0)  # (E n, n): row b hears its team's claims
        lead_arrives = arrive[:, 0].copy()  # the leader's message, claim or not
        arrive &= told >= 0
        self.claims[arrive] = told[arrive]
        self.claim_steps[arrive] = src
        lead = arrive[:, 0] & (np.repeat(leaders, n, axis=0) >= 0).all(axis=1)
        self.leader[lead] = np.repeat(leaders, n, axis=0)[lead]
        self._has_leader |= lead
        framed = lead_arrives & np.isfinite(np.repeat(frames, n, axis=0)).all(axis=1)
        self.frame[framed] = np.repeat(frames, n, axis=0)[framed]

    def heard(self, b: int) -> Heard:
        """What robot ``b`` has heard."""
        f = self.frame[b]
        return Heard(self.claims[b], self.claim_steps[b],
                     self.leader[b] if self._has_leader[b] else None,
                     f.copy() if np.isfinite(f).all() else None)
