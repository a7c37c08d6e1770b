"""One robot's decision maker: :class:`Controller`, the pipeline's steps on its own row.

The steps are :mod:`runtime.decision.pipeline`'s (assign, target, observe, act, command); the
controller runs them for one robot of one team, once per step, with the current
poses of the live robots ordered by robot id, calling the very functions a batch
of teams runs (:mod:`runtime.core`) on its team as a batch of one. It holds state
only: the last three frames (the paper observation and velocity estimates need
them), the previous assignment (hysteresis) and its slot potentials (the solver's
warm start), the centred pattern, the plan's support, and the scratch of the row
builder and the safety filter; each step is one call.

Frames. ``frames[0]`` is the newest (t), ``frames[1]`` is t-1 and ``frames[2]``
is t-2; at the start (or after the team size changes) the missing earlier frames
repeat frame t, so the first velocity estimate is zero.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.brain.brain import Brain
from runtime.core.assignment import TeamAssignment
from runtime.core.general_row import GeneralRows
from runtime.core.orca import CHANGE_TOL_MPS
from runtime.decision.agreement import Heard, SlotAgreement
from runtime.decision.kinematics import diff_drive_step
from runtime.decision.landing_frame import (
    CORE_M,
    centroid_targets,
    core_frame,
    seen_team,
    shared_slots,
)
from runtime.decision.observation import observe
from runtime.decision.patterns import min_spacing
from runtime.decision.pipeline import ERR_BRAIN, ERR_NONFINITE, ERR_TEAM, Decision
from runtime.decision.rules import PlanFrame, pace_velocity, plan_targets
from runtime.decision.safety import OrcaParams, guard_distance, landing, make_filter
from runtime.decision.settle import Lander, Settle, landing_steps
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["FRAME_SLACK_M", "HEADING_MIN_MOVE_M", "TURN_IN_PLACE_MPS", "Controller"]

FRAME_SLACK_M = 1.0
"""The leader's frame may lie this much (m) beyond the farthest a plan's frame could lie
from the team's centroid frame (:meth:`Controller._frame_reach`) and still be taken."""

TURN_IN_PLACE_MPS = 1e-3
"""A differential-drive command the guard would stop keeps this speed (m/s, 0.1 mm a step)
and its direction, so the base still turns toward it: stopped outright, two bases facing
each other inside the guard never turned, and 4 % of the episodes of
``benchmarks/conditions.py``'s differential-drive case did not form."""
HEADING_MIN_MOVE_M = 1e-3
"""A move this long (m) or longer shows a differential-drive base's heading (up to a half
turn, which its drive law does not tell apart)."""


class Controller:
    """One robot's decision maker: the pipeline's steps on its own row, with their state.

    Not thread-safe: call :meth:`decide`, :meth:`set_brain` and :meth:`reset`
    from one thread (the control loop); swapping a brain between two decisions
    is then atomic by construction.
    """

    def __init__(
        self,
        brain: Brain,
        world: WorldConfig = DEFAULT_WORLD,
        safety: OrcaParams | None = OrcaParams(),  # noqa: B008 - frozen, immutable default
        settle: Settle | None = None,
        turn_rate_rps: float | None = None,
        partial_view: bool = False,
    ) -> None:
        """``turn_rate_rps``: the robot's base is a differential drive that turns at most
        this fast (:func:`runtime.decision.kinematics.diff_drive`); the safety filter's
        guard then bounds what its wheels will drive, not only what it commands, from the
        heading its own motion shows (None: a holonomic base). ``partial_view``: the robot
        sees only part of its team (:func:`runtime.decision.agreement.local_views`), which
        its slot agreement counts on (:attr:`SlotAgreement.partial`)."""
        self.world = world
        self._turn = turn_rate_rps
        self.safety = safety
        self._lander = Lander(settle, world.dt_s) if settle is not None else None
        self._brain = brain
        self._filter = make_filter(safety, world)
        self._landed_filter = (  # the guard near the slot (runtime.decision.settle)
            make_filter(settle.landed_safety(safety), world)
            if settle is not None and safety is not None and safety.guard_margin_m > 0.0
            else None)
        self._guard_m = guard_distance(safety, world)
        self._landed_guard_m = (guard_distance(settle.landed_safety(safety), world)
                                if settle is not None and safety is not None
                                and self._landed_filter is not None else self._guard_m)
        self._two_views = settle is not None and settle.sigma_m > 0.0 and self._guard_m > 0.0
        """Whether a pair seen inside the guard needs two views to leave it (noisy views,
        a pattern whose slots lie outside the guard: :meth:`_seen_twice`)."""
        self._last_view: Array | None = None  # the guard's views of the peers this step
        self._prev_view: Array | None = None  # and the step before's
        self._view_step: int | None = None
        self._reach = world.v_max_mps * world.dt_s
        self._rows = GeneralRows(brain.spec.k_neighbours, self._reach)
        self._row: NDArray[Any] = np.zeros((1, 1, self._rows.dim))  # a brain's own input
        self._pattern_obj: object = None
        self._cc: Array = np.zeros((0, 2))
        self._spacing = 0.0  # the pattern's closest pair (m), where the guard needs it
        self._tick = 0  # distinct steps decided (a repeated realtime step is the same)
        self._to_slot: float | None = None  # the robot's way left to its slot under a plan
        self._me = 0  # the robot deciding, and its raw views (the landing's centroid)
        self._ref: Array | None = None
        self._in_view: BoolArray | None = None
        self._team_plan: tuple[Array, Array, Array] | Array | None = None
        """The last decision's plan for the team: (targets, positions, steps left: the team's,
        or in a landing at its own pace each robot's), or the team rule's velocities; None
        without a plan (see :attr:`team_velocity`)."""
        self._pace = 0.0  # the steps left the robot's own row reads (its pace)
        self._landing_targets: Array | None = None  # the landing's targets, (n, 2), or None
        self._claims: tuple[IntArray, int] | None = None  # heard claims and its own slot
        self._heard: Heard | None = None  # what it heard this step (None: not agreeing)
        self.agreement = SlotAgreement(partial_view)
        """What the robot held and told of its slots (:mod:`runtime.decision.agreement`)."""
        self.reset()

    @property
    def team_velocity(self) -> Array | None:
        """(n, 2) m/s: every robot's velocity under the synchronised plan this robot computed
        in its last decision, in a landing at its own pace each robot over its own steps left
        (None: its brain has no plan); a robot that cannot see every
        peer carries the unseen ones along it (:class:`runtime.decision.estimator.PeerTracker`).
        Worked out when asked: a decision only keeps what it is made from."""
        plan = self._team_plan
        if plan is None or not isinstance(plan, tuple):
            return plan
        target, pos, k = plan
        return pace_velocity(target, pos, k, self.world)

    # ---------------------------------------------------------------- state

    @property
    def brain(self) -> Brain:
        return self._brain

    def set_brain(self, brain: Brain) -> None:
        """Use ``brain`` from the next decision on (frames and slots are kept)."""
        self._brain = brain
        if brain.spec.needs_slots and brain.spec.dim != self._rows.dim:  # another row width
            self._rows = GeneralRows(brain.spec.k_neighbours, self._reach)
            self._row = np.zeros((1, 1, self._rows.dim))
        self._forget_memory()  # another brain's memory means nothing to this one

    def _forget_memory(self) -> None:
        """Zeros for the brain's memory: what it reads at a start (none: no memory)."""
        m = self._brain.spec.memory_dim
        self._memory_in = np.zeros((1, m), dtype=np.float32)  # what this step's decision reads
        self._memory = self._memory_in  # what the last decision answered

    @property
    def memory(self) -> NDArray[np.float32]:
        """(1, memory_dim): the memory the last decision answered (zeros at a start)."""
        return self._memory

    def reset(self) -> None:
        """Forget the history: frames, previous assignment, the plan's support."""
        self._n = -1
        self._frames: list[Array] = []  # positions at t, t-1, t-2 (own copies)
        self._last_step: int | None = None
        self._prev_slots: IntArray | None = None
        self._assignment: TeamAssignment | None = None  # its slots and potentials, kept
        self._vel: Array = np.zeros((1, 0, 2))  # the team's velocity estimates (m/s)
        self._plan = PlanFrame()
        self._heading = math.nan  # a differential-drive base's, from its own motion (rad)
        self._forget_memory()
        self.agreement.reset()
        self._last_view = self._prev_view = None
        if self._lander is not None:
            self._lander.reset()

    @property
    def previous_slots(self) -> IntArray | None:
        return self._prev_slots

    def _set_pattern(self, pattern: Array) -> None:
        c = np.asarray(pattern, dtype=np.float64)
        if c.ndim != 2 or c.shape[-1] != 2:
            raise ValueError(f"pattern must have shape (n, 2), got {c.shape}")
        self._cc = c - c.mean(axis=0, keepdims=True)
        self._spacing = min_spacing(self._cc) if self._two_views else 0.0
        self._pattern_obj = pattern
        self._prev_slots = None
        self._assignment = None
        self.agreement.reset()  # slots of another pattern
        if self._lander is not None:  # a new pattern lands afresh
            self._lander.reset()

    def _use_pattern(self, pattern: Array) -> None:
        """Cache the centred pattern; equal values in a new array object keep it."""
        old = self._pattern_obj
        if (
            isinstance(old, np.ndarray)
            and old.shape == np.shape(pattern)
            and np.array_equal(old, pattern)
        ):
            self._pattern_obj = pattern
        else:
            self._set_pattern(pattern)

    def _push(self, pos: Array, step: int | None) -> None:
        n = pos.shape[0]
        if n != self._n:
            self._n = n
            self._frames = [pos, pos, pos]
            self._prev_slots = None
            self._assignment = None
            self._vel = np.zeros((1, n, 2))
            self.agreement.reset()
            self._forget_memory()
            if self._lander is not None:  # another team's centroid
                self._lander.reset()
        elif step is not None and step == self._last_step:
            self._frames[0] = pos  # the same step again (realtime): refresh, do not shift
        else:
            f = self._frames
            self._frames = [pos, f[0], f[1]]
            self._memory_in = self._memory  # a new step reads what the last one answered
            self._tick += 1
        self._last_step = step

    # -------------------------------------------------------------- decide

    def _assign(self, pos: Array, moment: Array | None = None
                ) -> tuple[IntArray, float, float]:
        """Step 1: the shared assignment with hysteresis, warm from the last step's
        potentials, of the team of one ``moment`` (None: ``pos``); also the centroid of
        ``pos`` (cx, cy)."""
        if self._assignment is None:  # a new team or pattern: no warm start to keep
            self._assignment = TeamAssignment(self._cc)
        slots: IntArray = np.empty(len(pos), dtype=np.int64)
        if moment is None or np.shape(moment) != pos.shape:
            cx, cy = self._assignment.step(pos, slots)
        else:
            self._assignment.step(np.ascontiguousarray(moment, dtype=np.float64), slots)
            cx, cy = pos.mean(axis=0).tolist()
        self._prev_slots = slots
        return slots, cx, cy

    def _target(self, i: int, pos: Array, slots: IntArray, cx: float, cy: float
                ) -> tuple[float, float, float | None]:
        """Step 2: robot i's slot in the world (sx, sy) and the plan's steps left (None for a
        brain without a plan)."""
        spec = self._brain.spec
        if spec.name == "plan":  # the slot in the plan's frame (the whole team's)
            pts = self._cc[slots]
            tx, ty, k = self._plan.solve_floats(pos, pts, spec.travel_weight, self.world)
            if self._lander is not None and self._lander.settle.lands_in_centroid(k):
                target, kk = self._landing_plan(pos, pts)
                self._landing_targets = target
                k = float(kk)
                each = landing_steps(target, pos, kk, self._lander.settle, self.world)
                self._team_plan = (target, pos, each)
                self._pace = float(each[i])
            else:
                target = pts + np.array([tx, ty])
                self._team_plan = (target, pos, np.asarray(k))
                self._pace = k
            sx, sy = target[i].tolist()
            self._to_slot = math.hypot(sx - pos[i, 0], sy - pos[i, 1])
            return sx, sy, k
        qx, qy = self._cc[int(slots[i])].tolist()
        return qx + cx, qy + cy, None  # == slot_positions(...)[i]

    def _landing_filter(self, V: Array, steps_left: float | None) -> tuple[Any, Array]:
        """The safety filter and the team's velocities (1, n, 2) m/s it takes: in a landing
        under noise the team's plan (every robot computes the same and follows it; the
        tracker's estimates lag a team that stops, and the filter dodged peers that had
        stopped), and within ``landed_m`` of the slot the landed robot's filter (see
        :mod:`runtime.decision.settle`); the filter and ``V`` otherwise."""
        lander = self._lander
        if (lander is None or steps_left is None
                or not lander.settle.filters_on_plan(steps_left)
                or self._contested(self._me, self._frames[0] if self._ref is None
                                   else self._ref[:, 0:2])):
            return self._filter, V
        way = self._to_slot
        flt = (self._landed_filter if self._landed_filter is not None and way is not None
               and way < lander.settle.landed_m else self._filter)
        plan = None if self._team_plan is None else self.team_velocity
        if plan is None or plan.shape != V.shape[1:] or not np.isfinite(plan).all():
            return flt, V
        return flt, np.ascontiguousarray(plan[None], dtype=np.float64)

    def _contested(self, i: int, pos: Array) -> bool:
        """Whether, in a landing, a peer as sensed (``pos``, (n, 2): the guard's raw views,
        not carried along the plan) lies nearer robot i's target than its own: robots that
        disagree on their slots, each sure the other lands elsewhere. The landing's filter,
        which takes every peer to follow this robot's plan and keeps half the guard, let two
        such robots touch. Under slot agreement a peer heard to claim another slot than this
        robot's does not contest it (it passes by on its way)."""
        t = self._landing_targets
        if t is None or t.shape != pos.shape:
            return False
        mine = t[i]
        to_mine = np.hypot(pos[:, 0] - mine[0], pos[:, 1] - mine[1])
        to_own = np.hypot(pos[:, 0] - t[:, 0], pos[:, 1] - t[:, 1])
        near = to_mine < to_own
        near[i] = False
        if self._claims is not None:  # a peer heard to claim another slot does not contest
            claims, mine_slot = self._claims
            near &= (claims < 0) | (claims == mine_slot)
        return bool(near.any())

    def _landing_plan(self, pos: Array, points: Array) -> tuple[Array, Array]:
        """Under noise or latency, the last steps of a plan: the team's targets (n, 2) in the
        frame of its centroid seen raw, as the lander averages it (on exact late views the
        plan's frame, kept, then the frame of the team's core at one moment's slots:
        :meth:`runtime.decision.settle.Lander.frame`), and the steps left (a 0-d array).
        Under noise, agreeing (a step heard), in the leader's frame instead: the leader's own
        mean frame, which it tells, and every other robot's as last heard
        (:meth:`runtime.decision.agreement.SlotAgreement.lead_frame`, ``follow_frame``); the
        leader lands where its team's core stands once the team would have formed had it
        followed (``lead_due``, ``land_frame``)."""
        assert self._lander is not None
        m, points = self._lander.frame(
            seen_team(pos, self._me, self._ref), points, self._tick, pos.mean(axis=0),
            lambda team: self._planned_centroid(team, points),
            lambda team: self._cc[shared_slots(team, self._cc)], self._in_view)
        if self._heard is not None and self._lander.settle.sigma_m > 0.0:  # one frame for all
            told: Array | None = None
            if self._me == 0 and not self.agreement.frame_declined:
                planned = self._planned_centroid(pos, points)
                told = self.agreement.lead_frame(
                    planned, float(centroid_targets(pos, points, planned, self.world)[1]))
            elif self._me == 0:  # no plan frame: under a local view it tells where it lands
                told = self.agreement.tell_landing(m)
            else:  # a frame no plan of this team could have is not taken
                told = self.agreement.follow_frame(self._heard, m, self._frame_reach(pos))
            if told is not None:
                target, k = centroid_targets(pos, points, told, self.world)
                if self._me != 0 or not self.agreement.lead_due():
                    return target, k
                st = self._lander.settle  # the leader lands where its team's core stands
                team = seen_team(pos, self._me, self._ref)
                m = self.agreement.land_frame(core_frame(team, points, CORE_M), st.centroid_weight,
                                              float(st.centroid_gate(len(pos))))
        return centroid_targets(pos, points, m, self.world)

    def _frame_reach(self, team: Array) -> float:
        """How far (m) a plan's frame may lie from the team's centroid frame: where every
        robot's way to its slot is at most the longest in the centroid frame (at most the
        team's and the pattern's radii together), the frames lie at most twice that apart;
        a metre more for the plan's weight on travel."""
        r_team = float(np.hypot(*(team - team.mean(axis=0)).T).max(initial=0.0))
        r_pattern = float(np.hypot(*self._cc.T).max(initial=0.0))
        return 2.0 * (r_team + r_pattern) + FRAME_SLACK_M

    def _planned_centroid(self, team: Array, points: Array) -> Array:
        """The centroid (2,) m of the targets the plan gives ``team``, as the robot sees it of
        one moment (:func:`seen_team`): on exact late views the same for every robot."""
        weight = getattr(self._brain, "travel_weight", self._brain.spec.travel_weight)
        target, _ = plan_targets(team[None], points[None], np.arange(len(team))[None],
                                 float(weight), self.world)
        out: Array = target[0].mean(axis=0)
        return out

    def _act(self, i: int, P: Array, V: Array, slots: IntArray, cx: float, cy: float
             ) -> tuple[float, float, float | None]:
        """Steps 2-4: the brain's velocity for robot i (m/s) and the plan's steps left."""
        brain = self._brain
        spec = brain.spec
        team = getattr(brain, "team_plan", None)
        if team is not None:  # a team rule plans from the poses
            c = np.asarray(self._pattern_obj, dtype=np.float64)
            out, k = team(P, c[None], slots[None])
            way = None
            if self._lander is not None and self._lander.settle.lands_in_centroid(k[0]):
                target, kk = self._landing_plan(P[0], c[slots])  # landing under noise
                self._landing_targets = target
                each = landing_steps(target, P[0], kk, self._lander.settle, self.world)
                out, k = pace_velocity(target, P[0], each, self.world)[None], kk[None]
                way = math.hypot(*(target[i] - P[0, i]).tolist())
            team_v: Array = np.asarray(out, dtype=np.float64)[0]
            self._team_plan = team_v
            vx, vy = team_v[i].tolist()
            self._to_slot = (math.hypot(vx, vy) * float(k[0]) * self.world.dt_s
                             if way is None else way)
            return vx, vy, float(k[0])
        if not spec.needs_slots:  # the paper's observation
            obs = observe(spec, self._frames, None, (i,), self.world)
            vx, vy = np.asarray(brain.act(obs), dtype=np.float64)[0].tolist()
            return vx, vy, None
        sx, sy, steps_left = self._target(i, P[0], slots, cx, cy)
        pace = 0.0 if steps_left is None else self._pace * self._reach
        if spec.memory_dim:  # the row and the memory in, the action and the next memory out
            self._rows.robot_f64(0, i, P, V, sx, sy, pace, self._row)
            act, self._memory = brain.act_memory(self._row[0], self._memory_in)  # type: ignore[attr-defined]
            vx, vy = act[0].tolist()
            return vx, vy, steps_left
        direct: NDArray[np.float32] | None = getattr(brain, "input_row", None)
        if direct is not None:  # onnxruntime reads the row where it is written
            self._rows.robot(0, i, P, V, sx, sy, pace, direct.reshape(1, 1, -1))
            vx, vy = brain.act_input()  # type: ignore[attr-defined]
        else:
            self._rows.robot_f64(0, i, P, V, sx, sy, pace, self._row)
            vx, vy = np.asarray(brain.act(self._row[0]), dtype=np.float64)[0].tolist()
        return vx, vy, steps_left

    def decide(
        self,
        robot_index: int,
        positions: Array,
        pattern: Array,
        step: int | None = None,
        velocities: Array | None = None,
        filter_positions: Array | None = None,
        guard_ref: Array | None = None,
        moment: Array | None = None,
        heard: Heard | None = None,
        in_view: BoolArray | None = None,
    ) -> Decision:
        """Decide robot ``robot_index``'s velocity for this step.

        ``positions``: (n, 2) current poses of the live robots, ordered by robot
        id; ``robot_index`` is this robot's row. ``pattern``: (n, 2) target
        pattern (pass the same array object while it does not change: its
        centred copy is cached). ``step``: the world step these poses belong
        to; a repeated step refreshes the newest frame instead of shifting the
        history (realtime mode deciding faster than the world steps).
        ``velocities``: (n, 2) m/s, the team's velocities as an estimator has them
        (:class:`runtime.decision.estimator.PeerTracker`); None: the difference of the
        last two frames / dt. ``filter_positions``: (n, 2) where the safety filter takes
        the team to be (an estimator's positions carried forward to now), when the brain
        plans from others (the positions as sensed, so that a team does not chase its
        own extrapolation); None: ``positions``. ``guard_ref``: (n, 6), each peer as
        last sensed, this robot's pose then, the way the peer may have come since where
        an update was lost, and this robot's share of the pair's room, for the filter's guard
        (:class:`runtime.decision.local.Seen`); None: as they are now. ``moment``: (n, 2) the
        team of one moment, which the assignment reads (:attr:`runtime.decision.local.Seen.moment`;
        None: ``positions``). ``heard``: the slots the robot has heard its team tell, and the
        leader's assignment (:mod:`runtime.decision.agreement`; None: it goes by its own; read
        only with ``step``). ``in_view``: (n,) the peers in view, where the robot sees part
        of its team (:attr:`runtime.decision.local.Seen.in_view`): the landing's frame reads
        those alone (None: every peer).
        A non-finite brain output, a brain that cannot drive n robots or a
        brain that raises makes the robot hold still, with ``error`` set.
        """
        t0 = time.perf_counter_ns()
        self._team_plan = None
        self._landing_targets = None
        self._to_slot = None
        pos = np.array(positions, dtype=np.float64)  # a copy: the history is ours
        if pattern is not self._pattern_obj:
            self._use_pattern(pattern)
        self._push(pos, step)
        n = pos.shape[0]
        i = robot_index
        if not self._brain.spec.accepts_team(n) or self._cc.shape[0] != n:
            return self._hold(t0, 0.0, 0.0, ERR_TEAM, -1)
        if self._turn is not None:  # a base drives along its heading: its last move shows it
            dx = float(pos[i, 0] - self._frames[1][i, 0])
            dy = float(pos[i, 1] - self._frames[1][i, 1])
            if math.hypot(dx, dy) > HEADING_MIN_MOVE_M:
                self._heading = math.atan2(dy, dx)
        self._me, self._ref = i, guard_ref  # the raw views, for the landing's centroid
        self._in_view = in_view
        slots, cx, cy = self._assign(pos, moment)  # 1. assign
        self._claims = None
        self._heard = heard if step is not None else None
        self.agreement.heard_frame = False
        if heard is not None and step is not None:  # 1b. agree on a conflict it hears
            slots = self.agreement.agree(i, slots, step, heard)
            self._prev_slots = slots
            if len(heard.claims) == len(slots):
                self._claims = (heard.claims, int(slots[i]))
        slot = int(slots[i])
        P = pos[None]  # the team as a batch of one
        V = self._vel
        if velocities is None:
            np.subtract(pos, self._frames[1], out=V[0])
            V /= self.world.dt_s
        else:
            V[0] = velocities
        try:  # 2-4. target, observe, act
            bvx, bvy, steps_left = self._act(i, P, V, slots, cx, cy)
        except Exception:  # a brain must never take the loop down
            return self._hold(t0, 0.0, 0.0, ERR_BRAIN, slot)
        if not (math.isfinite(bvx) and math.isfinite(bvy)):
            return self._hold(t0, bvx, bvy, ERR_NONFINITE, slot)
        px, py = (bvx, bvy) if self._lander is None else self._lander.apply(bvx, bvy,
                                                                             self._to_slot)
        # 5. command: clamp and the safety filter (no neighbour considered without one)
        horizon = landing(self.safety or OrcaParams(), steps_left, self.world)
        if filter_positions is not None:
            P = np.asarray(filter_positions, dtype=np.float64)[None]
        ref = None if guard_ref is None else np.ascontiguousarray(guard_ref,
                                                                   dtype=np.float64)[None]
        flt, Vf = self._landing_filter(V, steps_left)
        if ref is not None and self._two_views and self._guard_m < self._spacing:
            ref = self._seen_twice(ref, step, self._landed_guard_m
                                   if flt is self._landed_filter else self._guard_m)
        vx, vy, changed, change = flt.robot(0, i, P, Vf, px, py, horizon, ref)
        if self._turn is not None:  # what the wheels will drive of it, within the guard
            if math.isfinite(self._heading):
                fx, fy, _ = diff_drive_step(vx, vy, self._heading, self._turn,
                                            self.world.dt_s)
                k = self._filter.guard_scale(0, i, P, float(fx), float(fy), False, ref)
            else:
                k = self._filter.guard_scale(0, i, P, vx, vy, True, ref)
            sp = math.hypot(vx, vy)
            if k < 1.0 and sp > 0.0:  # never quite still: the base must be able to turn
                k = max(k, min(1.0, TURN_IN_PLACE_MPS / sp))
                vx, vy = vx * k, vy * k
                change = math.hypot(vx - px, vy - py)
                changed = change > CHANGE_TOL_MPS
        us = (time.perf_counter_ns() - t0) / 1000.0
        return Decision((vx, vy), (bvx, bvy), changed and self.safety is not None, change, us,
                        "", slot)

    def _seen_twice(self, ref: Array, step: int | None, guard_m: float) -> Array:
        """``ref`` (1, n, 6), the guard's references, with each peer that the step before's
        view put inside the guard (``guard_m``, m between centres) no farther than that view,
        from this robot's pose of this step's view: a pair seen inside needs two views to
        leave it.

        Under noise one view in a few hundred puts a peer 3 sigmas farther than it is. A
        pair outside the guard may take that room: the guard's margin covers it. A pair
        pressed together inside it (a team that never formed, the robots behind pushing)
        took it too, and the next view, from where the robot then stood, never gave it back:
        a ratchet, and such pairs crept into each other over tens of steps. Now the room of
        a pair seen inside grows only as two views in a row show it; where a peer has truly
        gone, the next view shows it again. Exact views (latency, the wheels) need no second
        view, nor does a pattern whose closest slots lie inside the guard (10 cm of noise,
        ``harsh``), which robots reach only as the noise lets them through ("Patterns inside
        the guard"). Measured: realistic with the 6 nearest seen, n = 25, cross -> line with
        ``--agree frame`` (teams that jam; 20 episodes on each of 3 seeds): 7, 10 and 15
        colliding steps -> 0 (docs/conditions.md, "A pair seen inside the guard needs two
        views to leave it")."""
        view = ref[0, :, 0:2]
        if step is None or step != self._view_step:  # a new step: last step's views move back
            self._prev_view, self._view_step = self._last_view, step
        self._last_view = view.copy()  # the same step again (real time): refreshed
        last = self._prev_view
        if last is None or last.shape != view.shape:
            return ref
        own = ref[0, :, 2:4]
        before = np.hypot(*(last - own).T)
        toward = view - own
        d = np.hypot(*toward.T)
        over = (before < guard_m) & (before > 1e-9) & (d > before)
        if not over.any():
            return ref
        out = ref.copy()
        out[0, over, 0:2] = own[over] + toward[over] * (before[over] / d[over])[:, None]
        return out

    @staticmethod
    def _hold(t0: int, bvx: float, bvy: float, error: str, slot: int) -> Decision:
        us = (time.perf_counter_ns() - t0) / 1000.0
        return Decision((0.0, 0.0), (bvx, bvy), False, 0.0, us, error, slot)
