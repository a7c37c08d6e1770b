"""One robot's decision maker: :class:`Controller`, the pipeline's steps on its own row.

The steps are :mod:`runtime.decision`'s (assign, observe, act, command); the
controller runs them for one robot of one team, once per step, with the current
poses of the live robots ordered by robot id. It keeps the state the steps need
between calls -- the last three frames (the paper observation and velocity
estimates need them), the previous assignment (hysteresis) and its proof's or
solver's potentials, the centred pattern, the plan's frame -- and builds only its
own row. What it computes is what the shared functions give, number for number
(tests hold the two equal), with less work:

* with the compiled kernel (:mod:`runtime.kernel`, when built) the per-robot
  arithmetic of every step runs in C: the assignment's cost and solver (warm from
  the last step), the plan's frame, the neighbour order and row, the ORCA filter;
  onnxruntime reads the row where the kernel wrote it;
* in Python, from :data:`PROOF_FROM` robots the previous assignment is proven
  still optimal before the solver runs (:func:`runtime.assignment.certify_team`);
  the general observation's neighbour order (one sort of the squared distances)
  also gives the safety filter its nearest neighbours; velocities are estimated
  only as one array operation.

Frames. ``frames[0]`` is the newest (t), ``frames[1]`` is t-1 and ``frames[2]``
is t-2; at the start (or after the team size changes) the missing earlier frames
repeat frame t, so the first velocity estimate is zero.
"""

from __future__ import annotations

import math
import time

import numpy as np

from runtime.assignment import certify_team
from runtime.brain import Brain
from runtime.decision import (
    ERR_BRAIN,
    ERR_NONFINITE,
    ERR_TEAM,
    Command,
    Decision,
    Rows,
    _filtered,
    _near_in_order,
    brain_velocities,
    command,
    neighbour_rows,
)
from runtime.formation import (
    HYSTERESIS_ABS_M2,
    HYSTERESIS_REL,
    keeps_previous,
    linear_sum_assignment,
)
from runtime.kernel import use_kernel
from runtime.observation import frame_velocities, general_row, neighbour_order, observe
from runtime.rules import PlanFrame
from runtime.safety import OrcaParams, clamp_speed, landing
from runtime.types import Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["PROOF_FROM", "Controller"]

PROOF_FROM = 64
"""Team size from which the robot proves its previous assignment still optimal
(:func:`runtime.assignment.certify_team`) before it solves. Measured (general
brain, a formed circle, decision p50 without -> with the proof): 64 robots
101 -> 101 us, 80 robots 140 -> 126 us, 100 robots 190 -> 160-176 us; below 64
scipy's solver on a formed team's (n, n) cost costs no more than the proof's
numpy calls."""

PROOF_RETRY_STEPS = 4
"""Steps the robot solves without trying the proof after it failed. Measured
(general brain, circle, from random starts): while a team forms, its slot
potentials move more per step than a few relaxation rounds follow (at n = 100
about 17 rounds a step would be needed, more than the solver costs), so the
proof fails and would only add its cost. After a failure the potentials restart
at zero, which prove "every robot's own slot is its nearest" at once: the
formed team's case, where the proof then holds step after step (100 % of the
steps of a formed 64-, 80- or 100-robot circle)."""


class _Buffers:
    """The compiled path's arrays for one team size and observation width, reused."""

    __slots__ = ("d2", "dim", "keys", "n", "obs", "order", "vel")

    def __init__(self, n: int, dim: int) -> None:
        self.n, self.dim = n, dim
        self.vel = np.zeros((n, 2))  # every robot's velocity estimate (m/s)
        self.order = np.zeros(n, dtype=np.int64)  # robot ids nearest first
        self.d2 = np.zeros(n)  # squared distances to this robot (m^2)
        self.keys = np.zeros((n, 2))  # the sort's scratch
        self.obs = np.zeros((1, dim))  # the row, for a brain without its own input


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
        compiled: bool | None = None,
    ) -> None:
        """``compiled``: decide with :mod:`runtime.kernel` (None: when it is built; True
        requires it); False runs the Python reference throughout."""
        self.world = world
        self.safety = safety
        self._brain = brain
        self._kernel = use_kernel(compiled)
        self._bufs: _Buffers | None = None
        self._pattern_obj: object = None
        self._cc: Array = np.zeros((0, 2))
        self._ccx: Array = np.zeros(0)
        self._ccy: Array = np.zeros(0)
        self._cost: Array = np.zeros((0, 0))  # (n, n) m^2, the assignment's cost
        self._work: Array = np.zeros((0, 0))  # (n, n) scratch
        self.reset()

    # ---------------------------------------------------------------- state

    @property
    def brain(self) -> Brain:
        return self._brain

    def set_brain(self, brain: Brain) -> None:
        """Use ``brain`` from the next decision on (frames and slots are kept)."""
        self._brain = brain

    def reset(self) -> None:
        """Forget the history: frames and previous assignment."""
        self._n = -1
        self._frames: list[Array] = []  # positions at t, t-1, t-2 (own copies)
        self._last_step: int | None = None
        self._prev_slots: IntArray | None = None
        self._duals: Array = np.zeros(0)  # the assignment proof's slot potentials (m^2)
        self._v: Array = np.zeros(0)  # the compiled solver's slot potentials (m^2), warm start
        self._proof_wait = 0  # steps until the proof is tried again after it failed
        self._plan = PlanFrame(self._kernel is not None)  # the plan's frame, support kept

    @property
    def previous_slots(self) -> IntArray | None:
        return self._prev_slots

    def _set_pattern(self, pattern: Array) -> None:
        c = np.asarray(pattern, dtype=np.float64)
        if c.ndim != 2 or c.shape[-1] != 2:
            raise ValueError(f"pattern must have shape (n, 2), got {c.shape}")
        self._cc = c - c.mean(axis=0, keepdims=True)
        # its columns, contiguous, for the cost kernel of _assign
        self._ccx, self._ccy = self._cc[:, 0].copy(), self._cc[:, 1].copy()
        self._pattern_obj = pattern
        self._prev_slots = None
        self._duals = np.zeros(0)
        self._v = np.zeros(0)

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
        elif step is not None and step == self._last_step:
            self._frames[0] = pos  # the same step again (realtime): refresh, do not shift
        else:
            f = self._frames
            self._frames = [pos, f[0], f[1]]
        self._last_step = step

    def _velocities(self) -> Rows:
        """:func:`frame_velocities` of the last two frames: the same IEEE operations,
        on the arrays (one subtraction and one division instead of n of each)."""
        v: Rows = ((self._frames[0] - self._frames[1]) / self.world.dt_s).tolist()
        return v

    def _assign(self, pos: Array) -> tuple[IntArray, float, float]:
        """:func:`runtime.formation.assign_centred` of the team ``pos`` (n, 2) against the
        cached pattern, with its hysteresis; also the team's centroid (cx, cy). The same
        cost, bit for bit, built from contiguous columns ((n, n) twice instead of one
        (n, n, 2) array: 4x less time at n = 100) or by the compiled kernel (one call
        instead of eight numpy ones), the same solver and the same rule.

        From :data:`PROOF_FROM` robots the previous assignment is first checked with
        the assignment proof (:func:`runtime.assignment.certify_team`, its slot
        potentials kept from step to step): proven within half the hysteresis margin,
        the rule would keep it whatever the solver said, so it is kept unsolved (as
        :func:`runtime.formation.assign_slots_env_last` does for the training world).
        """
        n = len(pos)
        if self._cost.shape[0] != n:  # the team's buffers: no (n, n) allocation a step
            self._cost, self._work = np.empty((n, n)), np.empty((n, n))
        dx, dy = self._cost, self._work
        if self._kernel is not None:
            cx, cy = self._kernel.centred_cost(pos, self._ccx, self._ccy, dx)
        else:
            cen = np.add.reduce(pos, 0) / n  # == pos.mean(0), without mean's Python overhead
            cx, cy = cen.tolist()
            Pc = pos - cen
            np.subtract(Pc[:, 0:1], self._ccx, out=dx)  # (n, n): robot i to point j
            dx *= dx
            np.subtract(Pc[:, 1:2], self._ccy, out=dy)
            dy *= dy
            dx += dy
        prev = self._prev_slots
        if self._kernel is not None:  # the compiled solver, warm from the last step
            return self._solve_compiled(dx, prev, n), cx, cy
        if prev is not None and len(prev) == n and n >= PROOF_FROM:
            if self._duals.shape[0] != n:
                self._duals = np.zeros(n)
                self._proof_wait = 0
            if self._proof_wait > 0:
                self._proof_wait -= 1
            else:
                old = float(dx[np.arange(n), prev].sum())
                tol = (HYSTERESIS_REL * old + HYSTERESIS_ABS_M2) * (0.5 / n)
                if certify_team(dx, prev, tol, self._duals, work=dy):
                    return prev, cx, cy
                self._proof_wait = PROOF_RETRY_STEPS
                self._duals[:] = 0.0  # zeros: "every robot is nearest its own slot"
        cols: IntArray = linear_sum_assignment(dx)[1]
        if prev is not None and len(prev) == len(cols) and prev.tolist() != cols.tolist():
            rows = np.arange(len(cols))
            if keeps_previous(dx[rows, cols].sum(), dx[rows, prev].sum()):
                return prev, cx, cy
        return cols, cx, cy

    def _solve_compiled(self, cost: Array, prev: IntArray | None, n: int) -> IntArray:
        """Step 1's solver and hysteresis with the compiled kernel: scipy's algorithm
        (the same assignment, cold), started from the last step's slot potentials and the
        previous slots still tight, so that only the robots whose slot is no longer their
        best are re-solved (100 robots forming a circle, general brain: the assignment
        72 -> 38 us a decision on average, scipy's solver and the proof against this).
        Without exact ties the answer is scipy's; the hysteresis rule is then
        applied as in the Python path (which proves the previous assignment first from
        :data:`PROOF_FROM` robots: the warm start is that proof, exact)."""
        kern = self._kernel
        assert kern is not None
        warm = prev is not None and len(prev) == n and self._v.shape[0] == n
        if self._v.shape[0] != n:
            self._v = np.zeros(n)
        cols: IntArray = np.empty(n, dtype=np.int64)
        p = prev if warm and prev is not None else cols
        if kern.assign(cost, p, self._v, warm, cols) < 0:  # cannot be with finite costs
            self._v = np.zeros(0)
            cols = linear_sum_assignment(cost)[1]
        if prev is not None and len(prev) == n and prev.tolist() != cols.tolist():
            rows = np.arange(n)
            if keeps_previous(cost[rows, cols].sum(), cost[rows, prev].sum()):
                return prev
        return cols

    # -------------------------------------------------------------- decide

    def _decide_compiled(self, t0: int, i: int, pos: Array, cx: float, cy: float,
                         slots: IntArray, safety: OrcaParams | None) -> Decision:
        """Steps 2-4 of :meth:`decide` for the general and plan observations with the
        compiled kernel (:mod:`runtime.kernel`): the same numbers as the Python steps."""
        kern = self._kernel
        assert kern is not None
        brain, world = self._brain, self.world
        spec = brain.spec
        n = pos.shape[0]
        slot = int(slots[i])
        reach = world.v_max_mps * world.dt_s
        b = self._bufs
        if b is None or b.n != n or b.dim != spec.dim:
            b = self._bufs = _Buffers(n, spec.dim)
        # 2. observe: the slot (in the plan's frame), the neighbour order, the row
        steps_left = 0.0
        if spec.name == "plan":
            pts = self._cc[slots]
            tx, ty, steps_left = self._plan.solve_floats(pos, pts, spec.travel_weight, world)
            qx, qy = pts[i].tolist()
            sx, sy = qx + tx, qy + ty
            safety = landing(safety, steps_left, world)
        else:
            qx, qy = self._cc[slot].tolist()
            sx, sy = qx + cx, qy + cy  # == slot_positions(...)[i]
        direct: Array | None = getattr(brain, "input_row", None)  # onnxruntime's own input
        out = b.obs[0] if direct is None else direct
        kern.row(pos, self._frames[1], i, sx, sy, spec.k_neighbours, reach, world.dt_s,
                 steps_left * reach, b.vel, b.order, b.d2, b.keys, out)
        # 3. act
        error = ""
        bvx = bvy = 0.0
        try:
            if direct is not None:
                bvx, bvy = brain.act_input()  # type: ignore[attr-defined]
            else:
                bvx, bvy = brain_velocities(brain, b.obs)[0]
        except Exception:  # a brain must never take the loop down
            error = ERR_BRAIN
        if not error and not (math.isfinite(bvx) and math.isfinite(bvy)):
            error = ERR_NONFINITE
        # 4. command
        if error:
            us = (time.perf_counter_ns() - t0) / 1000.0
            return Decision((0.0, 0.0), (bvx, bvy), False, 0.0, us, error, slot)
        vx, vy = clamp_speed(bvx, bvy, world.v_max_mps)
        changed, change = False, 0.0
        if safety is not None:
            reach_m = safety.neighbour_dist_m
            vx, vy, changed, change = kern.orca(
                vx, vy, pos, b.vel, i, b.order, b.d2, safety.max_neighbours, reach_m * reach_m,
                2.0 * (world.radius_m + safety.radius_margin_m), safety.time_horizon_s,
                world.dt_s, safety.keep_right_rad, world.v_max_mps)
        us = (time.perf_counter_ns() - t0) / 1000.0
        return Decision((vx, vy), (bvx, bvy), changed, change, us, "", slot)

    def decide(
        self,
        robot_index: int,
        positions: Array,
        pattern: Array,
        step: int | None = None,
    ) -> Decision:
        """Decide robot ``robot_index``'s velocity for this step.

        ``positions``: (n, 2) current poses of the live robots, ordered by robot
        id; ``robot_index`` is this robot's row. ``pattern``: (n, 2) target
        pattern (pass the same array object while it does not change: its
        centred copy is cached). ``step``: the world step these poses belong
        to; a repeated step refreshes the newest frame instead of shifting the
        history (realtime mode deciding faster than the world steps).
        A non-finite brain output, a brain that cannot drive n robots or a
        brain that raises makes the robot hold still, with ``error`` set.
        """
        t0 = time.perf_counter_ns()
        pos = np.array(positions, dtype=np.float64)  # a copy: the history is ours
        if pattern is not self._pattern_obj:
            self._use_pattern(pattern)
        self._push(pos, step)
        n = pos.shape[0]
        i = robot_index
        brain = self._brain
        spec = brain.spec
        safety = self.safety if n >= 2 else None
        slot = -1
        error = ""
        bvx = bvy = 0.0
        cmd: Command | None = None
        if not spec.accepts_team(n) or self._cc.shape[0] != n:
            error = ERR_TEAM
        else:
            # 1. assign
            slots, cx, cy = self._assign(pos)
            self._prev_slots = slots
            slot = int(slots[i])
            team = getattr(brain, "team_plan", None)
            rows = spec.needs_slots  # the general layout: general or plan
            if self._kernel is not None and team is None and rows:
                return self._decide_compiled(t0, i, pos, cx, cy, slots, safety)
            L: Rows = pos.tolist()
            V = self._velocities() if rows or team is not None else []
            near = None  # the safety filter's neighbours, when the observation found them
            # 2. observe (own row): the general builder's one-robot kernel on plain
            # floats, its neighbour order shared with the safety filter; else the builder
            obs: Array | None = None  # a team rule plans from the poses (step 3)
            steps_left = 0.0  # the plan's steps left, for the filter's landing horizon
            if team is None and rows:
                if spec.name == "plan":  # the slot in the plan's frame (the whole team's)
                    pts = self._cc[slots]
                    t, steps_left = self._plan.solve(pos, pts, spec.travel_weight, self.world)
                    sx, sy = (pts[i] + t).tolist()
                else:
                    qx, qy = self._cc[slot].tolist()
                    sx, sy = qx + cx, qy + cy  # == slot_positions(...)[i]
                order, d2 = neighbour_order(i, L, pos)
                row = general_row(i, L, V, (sx, sy), spec.k_neighbours, self.world, order=order)
                if steps_left:  # plan_pace on the row's floats
                    den = steps_left * (self.world.v_max_mps * self.world.dt_s)
                    row[2], row[3] = row[0] / den, row[1] / den
                obs = np.array([row])
                if steps_left:
                    safety = landing(safety, steps_left, self.world)
                if safety is not None:
                    near = _near_in_order(i, L, order, d2, safety)
            elif team is None:
                obs = observe(spec, self._frames, None, (i,), self.world)
            # 3. act
            try:
                if team is not None:
                    c = np.asarray(self._pattern_obj, dtype=np.float64)
                    out, k = team(pos[None], c[None], slots[None])
                    safety = landing(safety, float(k[0]), self.world)  # the plan's steps left
                    bvx, bvy = np.asarray(out)[0, i].tolist()
                elif obs is not None:
                    bvx, bvy = brain_velocities(brain, obs)[0]
            except Exception:  # a brain must never take the loop down
                error = ERR_BRAIN
            # 4. command
            if error:
                pass
            elif not (math.isfinite(bvx) and math.isfinite(bvy)):
                error = ERR_NONFINITE
            elif near is not None and safety is not None:
                vx, vy = clamp_speed(bvx, bvy, self.world.v_max_mps)
                cmd = _filtered(vx, vy, V[i], near, [V[k[3]] for k in near], safety, self.world)
            else:
                if safety is not None and not V:
                    V = frame_velocities(L, self._frames[1].tolist(), self.world.dt_s)
                nb = neighbour_rows(i, L, V) if safety is not None else None
                cmd = command(bvx, bvy, nb, safety, self.world)
        us = (time.perf_counter_ns() - t0) / 1000.0
        if cmd is None:
            return Decision((0.0, 0.0), (bvx, bvy), False, 0.0, us, error, slot)
        return Decision(cmd.velocity, (bvx, bvy), cmd.changed, cmd.change_mps, us, "", slot)
