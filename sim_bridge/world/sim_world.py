"""The pymunk world over Zenoh, playing a sequence of patterns: :class:`SimWorld`.

The world owns the truth (where every robot is) and the clock. Each step it

1. publishes every live robot's :class:`~runtime.wire.messages.Pose` (step, position,
   velocity over the last step, ``n_live``) on ``patternrl/<swarm>/robot/<id>/pose``;
2. collects the robots' :class:`~runtime.wire.messages.Command` for that step
   (:meth:`sim_bridge.world.world_link.WorldLink.exchange`):

   * ``lockstep`` (default, reproducible): until every live robot has answered or
     ``step_deadline_ms`` has passed; a robot that has not answered holds still
     for the step and is counted (``deadline_miss``); an answer that comes late
     is dropped and counted, and nothing ever waits longer than the deadline;
   * ``realtime``: one step every ``1 / rate_hz`` seconds on a fixed schedule
     (the world's own work comes out of the period); the commands for that step
     that arrived before its tick are applied fresh. When most robots have no
     command young enough to apply (:data:`HELD_SLOW_DOWN` of them, averaged
     over a few steps: the machine cannot decide that fast), the world lengthens
     its period, down to ``min_rate_hz``, and speeds up again as they catch up
     (below :data:`HELD_SPEED_UP`): a swarm too big for its machine runs slower,
     not frozen (each step's rate is on ``/world/metrics``);
   * in both modes a step that brings news -- the run's first few (:data:`WARM_UP_STEPS`),
     each pattern's first, the first after a join -- waits for every robot's command (up to
     ``first_step_deadline_ms``), and realtime's schedule starts again after it: the
     robots decide it from scratch, all at once; the phase's lower bounds are worked
     out meanwhile (:meth:`SimWorld._bounds`);

   a robot whose command for the step is missing or late (a deadline miss) moves on
   its newest command if that is at most ``max_command_age_steps`` steps old
   (realtime's default :data:`~sim_bridge.world.world_link.DEFAULT_MAX_AGE_STEPS`,
   lockstep's 0), else holds still (see :mod:`sim_bridge.world.world_link`); when a
   robot missed, the step's motions go through the guard
   (:mod:`sim_bridge.world.stale_guard`), which slows the older of two commands that
   would bring their robots closer than 2R;

3. steps the physics (:mod:`sim_bridge.world.physics`), then measures the formation
   against the current pattern (:mod:`sim_bridge.world.phase_tally`) and records
   everything (:mod:`sim_bridge.world.world_log`).

A pattern is **formed** when every robot is within ``world.formed_tol_m`` of its
slot under the centred optimal assignment; the world then publishes the next
pattern. A pattern not formed within ``max_steps`` is logged as a failure and the
sequence goes on. With ``hold_steps`` N > 0 the world watches a formed pattern N
steps more before the next one (the robots deciding as ever) and counts the steps
after which the team is still formed: the phase **held** when that is at least
:data:`~runtime.world_config.HOLD_SHARE` of N
(:class:`~sim_bridge.world.run_results.PhaseResult` keeps the first passage's steps,
travel and error, and counts collisions and deadline figures over the whole phase).
The current :class:`~runtime.wire.messages.PatternMsg` is republished about once a
second and answered to queries on the pattern key, for robots that join late.

The world starts once ``robots`` robots are alive (or ``wait_robots_s`` has
passed with at least two); robots that join or leave later are followed
(:mod:`sim_bridge.world.membership`) and the pattern is resized to the live count (a
new pattern version), which general and rule brains follow; a paper brain knows
one team size and cannot. With ``brains`` set, each pattern's brain is swapped
into the robots that run another one at the pattern change
(:mod:`sim_bridge.world.brain_swaps`).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import zenoh

from runtime import heap
from runtime.conditions import PERFECT, Conditions
from runtime.decision.formation import lower_bounds
from runtime.decision.kinematics import Wheels
from runtime.decision.patterns import make_pattern, pattern_label
from runtime.types import Array
from runtime.wire.messages import PatternMsg, encode_pattern
from runtime.world_config import DEFAULT_WORLD, WorldConfig, holds
from sim_bridge.log.recorder import Recorder, SimTime
from sim_bridge.world.brain_choice import BrainChoice
from sim_bridge.world.brain_swaps import phase_brain_label, swap_brain_in
from sim_bridge.world.membership import Membership
from sim_bridge.world.phase_tally import PhaseTally
from sim_bridge.world.physics import PhysicsWorld, arena_for_patterns
from sim_bridge.world.run_results import PhaseResult, Progress, RunResult
from sim_bridge.world.stale_guard import guard_stale
from sim_bridge.world.world_link import DEFAULT_MAX_AGE_STEPS, WorldLink
from sim_bridge.world.world_log import Say, WorldLog

DEFAULT_PATTERNS = "circle,cross,line,heart"
HELD_SLOW_DOWN = 0.5
"""realtime: above this share of robots held still (averaged), the world slows down."""
HELD_SPEED_UP = 0.1
"""realtime: below it, the world goes back toward ``rate_hz``."""
HELD_AVERAGING = 0.2
"""Weight of a step in the average of the held share."""
SLOW_DOWN, SPEED_UP = 1.1, 1.02
"""Factors on the period per step: slow down fast, speed up gently."""
MIN_WINDOW_SHARE = 0.9
"""realtime: a step's robots have at least this share of the period between its poses going
out and its deadline. The schedule is fixed (the world's own work of a step comes out of
the next period), but when the world's poses go out late -- the machine stalled the world
and the robots alike for tens of ms -- the schedule slips rather than squeeze the next step:
squeezed, that step's window fell below the robots' round trip and every command of a
hundred-robot swarm came late at once (the slip is reported: ``schedule_slipped_s``)."""
WARM_UP_STEPS = 3
"""The run's first steps that wait for every robot's command, as a pattern's first does
(:meth:`SimWorld._deadline_s`): a hundred robots just started took 1.1-1.4 s over their first
decision and 150 ms over each of the next two (a steady step: 55-70 ms), cold."""
STEP_LIMIT_OVER_BOUND = 2
"""Without ``--max-steps``, a pattern gets this many times its steps lower bound (at least
the world's ``step_limit``): a hundred robots in the arena of four patterns start up to
700 steps from the circle, which no fixed limit of 400 lets them form."""


def phase_step_limit(lower_bound_steps: int, world: WorldConfig = DEFAULT_WORLD) -> int:
    """The step limit of a pattern whose steps lower bound is ``lower_bound_steps``."""
    return max(world.step_limit, STEP_LIMIT_OVER_BOUND * int(lower_bound_steps))


@dataclass
class SimConfig:
    """Everything a run of the world needs; units in the names."""

    swarm: str = "demo"
    robots: int = 10
    patterns: list[str] = field(default_factory=lambda: DEFAULT_PATTERNS.split(","))
    mode: str = "lockstep"
    seed: int = 0
    step_deadline_ms: float = 250.0
    first_step_deadline_ms: float = 5000.0
    max_steps: int | None = None
    """Step limit per pattern; None: :func:`phase_step_limit` of its lower bound."""
    hold_steps: int = 0
    """Steps a formed pattern is watched before the next (0: the next at the first passage)."""
    rate_hz: float = 1.0 / DEFAULT_WORLD.dt_s
    min_rate_hz: float | None = None
    """realtime: the slowest the world goes when robots cannot keep up (None: rate_hz / 4;
    rate_hz: a fixed rate)."""
    brains: dict[str, BrainChoice] | None = None
    """Brain per pattern; None leaves the robots' brains alone."""
    wait_robots_s: float = 30.0
    swap_timeout_s: float = 15.0
    pattern_republish_s: float = 1.0
    max_command_age_steps: int | None = None
    """Oldest command still applied (steps); None: 0 in lockstep, DEFAULT_MAX_AGE_STEPS in
    realtime."""
    world: WorldConfig = DEFAULT_WORLD
    conditions: Conditions = PERFECT
    """The wheels' part is the world's (gain, actuation noise, differential drive); the
    sensing part is each robot's."""
    ros2: bool = False
    """The robots move as a ROS 2 fleet (``sim --ros2``: :mod:`sim_bridge.ros2.fleet`)."""

    @property
    def max_age_steps(self) -> int:
        if self.max_command_age_steps is not None:
            return self.max_command_age_steps
        return 0 if self.mode == "lockstep" else DEFAULT_MAX_AGE_STEPS


@dataclass
class _Phase:
    """One pattern being played: where it started, what it has measured."""

    index: int
    name: str
    C: Array
    """The pattern at the live team size, (n, 2) metres."""
    choice: BrainChoice | None
    start_pos: Array
    """Where the team was when the pattern came, (n, 2) metres: the lower bounds' start."""
    start_step: int
    late0: int
    t_start: float
    lower_bound_steps: int = -1
    lower_bound_travel_m: float = math.nan
    limit: int | None = None
    """The phase's step limit (None until the lower bounds are known)."""
    steps: int = 0
    tally: PhaseTally = field(default_factory=PhaseTally)
    brain_ids: set[str] = field(default_factory=set)
    first: tuple[int, float, float] | None = None
    """At the first passage: (steps, travel in metres, formation error in metres)."""
    hold_done: int = 0
    """Steps stepped since the first passage."""
    held_steps: int = 0
    """Of those, the ones after which the team was still formed."""

    @property
    def label(self) -> str:
        return pattern_label(self.name)


CPU_SECTIONS = ("exchange", "guard", "physics", "measures", "log")
"""What the world's thread spends a step's CPU on: exchange (the poses encoded and published,
the commands received and checked), guard (wheels, the stale-command guard, the rate),
physics (pymunk), measures (formation, collisions, the phase's tally), log (the metrics row
and the Foxglove scene built and queued for the recorder's writer)."""


class _Stopwatch:
    """CPU time of this thread, lap by lap, added to ``into[section]``."""

    def __init__(self, into: dict[str, float]) -> None:
        self.into = into
        self.start = self.last = time.thread_time()

    def lap(self, section: str) -> None:
        now = time.thread_time()
        self.into[section] += now - self.last
        self.last = now

    @property
    def total(self) -> float:
        return self.last - self.start


def _print_say(msg: str, detail: bool) -> None:
    print(f"sim: {msg}", file=sys.stderr, flush=True)


class SimWorld:
    """One run of the world on an open Zenoh session."""

    def __init__(
        self,
        cfg: SimConfig,
        session: zenoh.Session,
        recorder: Recorder | None = None,
        on_progress: Callable[[Progress], None] | None = None,
        log: Say | None = None,
    ) -> None:
        self.cfg = cfg
        self.w = cfg.world
        self.session = session
        self.rec = recorder
        self.on_progress = on_progress
        self.stop_event = threading.Event()
        self.rng = np.random.default_rng(cfg.seed)
        self.step = 0
        self.version = 0
        # Time spent in steps (poses out to physics and record done), phase changes left
        # out: wall, and CPU of the world's thread.
        self.stepping_wall_s = 0.0
        self.stepping_cpu_s = 0.0
        self.cpu_split_s = dict.fromkeys(CPU_SECTIONS, 0.0)
        """CPU of the world's thread in steps, by what it spent it on (:data:`CPU_SECTIONS`)."""
        self._process_cpu0 = time.process_time()
        self.bounds_cpu_s = 0.0  # the phases' lower bounds (in their first steps: measures)
        self.gc_pauses = heap.Pauses()
        """The collector's pauses of the world's process while the patterns played (every
        thread waits for them: Zenoh's callbacks, the recorder's writer)."""
        self._tick: float | None = None  # realtime: when the current step's period began
        self.period_s = 1.0 / cfg.rate_hz
        """realtime: the current period (longer than 1 / rate_hz while robots cannot keep up)."""
        self._held_avg = 0.0
        self.overruns = 0
        self.slipped_s = 0.0
        """realtime: how far the schedule slipped to keep each step's window (MIN_WINDOW_SHARE)."""
        self._wheel_ids: list[int] = []
        self._wheel_model: Wheels | None = None
        """realtime: steps whose tick had passed before their poses went out."""
        patterns_at_n = [make_pattern(p, cfg.robots, self.w) for p in cfg.patterns]
        self.arena_m = arena_for_patterns(patterns_at_n, self.w)
        self.physics = PhysicsWorld(self.arena_m, self.w)
        self.journal = WorldLog(recorder, self.w, self.arena_m, log or _print_say,
                                lambda: self.step)
        if cfg.ros2:  # odom out and Twists in over ROS 2 (rclpy loads here only)
            from sim_bridge.ros2.fleet import Ros2FleetLink

            self.link: WorldLink = Ros2FleetLink(session, cfg.swarm, False, recorder,
                                                 self.journal.event, self.w, cfg.seed)
        else:
            self.link = WorldLink(session, cfg.swarm, cfg.mode == "lockstep", recorder,
                                  self.journal.event, cfg.max_age_steps)
        self.members = Membership(self.link.roster, self.physics, self.link, self.journal,
                                  self.rng, self.arena_m, self.w)
        if recorder is not None and cfg.mode == "lockstep" and recorder.sim_time is None:
            # the log's clock is the world's: a run plays back at the speed it moved
            recorder.sim_time = SimTime(time.time_ns(), round(self.w.dt_s * 1e9),
                                        lambda: self.step)

    @property
    def latencies_ms(self) -> list[float]:
        """Pose-to-command latency of every command that made its step."""
        return self.link.latencies_ms

    @property
    def decision_us(self) -> list[float]:
        """Decision time as the robots report it, for benchmarks."""
        return self.link.decision_us

    @property
    def malformed(self) -> int:
        return self.link.malformed

    def open(self) -> None:
        """Declare the world on the session (done by :meth:`run` if not before)."""
        self.link.open()

    def stop(self) -> None:
        """Stop after the current step (safe from a signal handler or another thread)."""
        self.stop_event.set()
        self.link.wake()

    # ------------------------------------------------------------------ run

    def run(self) -> RunResult:
        """Wait for the robots, play every pattern, finish; never raises for a robot's fault."""
        cfg = self.cfg
        t0 = time.monotonic()
        phases: list[PhaseResult] = []
        outcome = "done"
        self.open()
        try:
            self.journal.event(
                "run_start", swarm=cfg.swarm, robots=cfg.robots, patterns=cfg.patterns,
                mode=cfg.mode, seed=cfg.seed, step_deadline_ms=cfg.step_deadline_ms,
                max_command_age_steps=cfg.max_age_steps,
                max_steps=cfg.max_steps, rate_hz=cfg.rate_hz, arena_m=self.arena_m,
                world=asdict(self.w), brains={k: asdict(v) for k, v in (cfg.brains or {}).items()})
            if not self.members.wait_for_robots(cfg.robots, cfg.wait_robots_s, self.stop_event):
                outcome = "interrupted" if self.stop_event.is_set() else "no robots"
            else:
                outcome = self._play(phases)
                if self.physics.ids:  # the final state, on the wire and on the log
                    self.link.publish_final(self.step, self.w.dt_s, list(self.physics.ids),
                                            self.physics.positions())
        finally:
            wall = time.monotonic() - t0
            cpu = self._cpu_figures()
            self.journal.event(
                "run_end", outcome=outcome, wall_s=round(wall, 3),
                formed=[p.formed for p in phases], malformed=self.malformed,
                over_budget=self.link.budget.dropped,
                contacts_total=self.physics.contacts_total, **cpu,
                stepping_wall_s=round(self.stepping_wall_s, 4),
                rate_hz_end=round(1.0 / self.period_s, 3),
                log_dropped=self.rec.dropped if self.rec is not None else 0)
            self.link.close()
        return RunResult(phases, outcome, self.step, round(wall, 3),
                         str(self.rec.path) if self.rec and self.rec.path else None,
                         self.latencies_ms, cpu)

    def _cpu_figures(self) -> dict[str, Any]:
        """The world's CPU while the patterns played (:attr:`RunResult.world_cpu`)."""
        played = self.step > 0
        return {
            "steps": self.step, "overruns": self.overruns,
            "schedule_slipped_s": round(self.slipped_s, 3),
            "stepping_cpu_s": round(self.stepping_cpu_s, 4),
            "stepping_cpu_split_s": {k: round(v, 4) for k, v in self.cpu_split_s.items()},
            "writer_cpu_s": round(self.rec.writer_cpu_s, 3) if self.rec is not None else 0.0,
            "process_cpu_s": (round(time.process_time() - self._process_cpu0, 3) if played
                              else 0.0),
            "gc_pauses": self.gc_pauses.figures(),
        }

    def _play(self, phases: list[PhaseResult]) -> str:
        """Place the robots and play the patterns in turn; the outcome."""
        self._process_cpu0 = time.process_time()  # the process's CPU from here: stepping on
        self.members.place_start(self.cfg.robots)
        outcome = "done"
        with self.gc_pauses:
            for k, name in enumerate(self.cfg.patterns):
                if self.stop_event.is_set():
                    break
                phases.append(self._run_phase(k, name))
                if len(self.physics.ids) < 2:
                    outcome = "no robots"
                    break
        return "interrupted" if self.stop_event.is_set() else outcome

    # ------------------------------------------------------------------ phases

    def _run_phase(self, index: int, name: str) -> PhaseResult:
        """Play one pattern until formed (and watched ``hold_steps`` more), out of steps or
        stopped."""
        ph = self._start_phase(index, name)
        while True:
            if ph.first is None and ph.tally.formed(self.w):  # the first passage
                ph.first = (ph.steps, ph.tally.travel_m, ph.tally.error_m)
            done = (ph.hold_done >= self.cfg.hold_steps if ph.first is not None
                    else ph.limit is not None and ph.steps >= ph.limit)
            if done or self.stop_event.is_set():
                break
            joined = self._follow_membership(ph)
            if joined is None:
                break
            if not self._step(ph, first=(self.step < WARM_UP_STEPS or ph.steps == 0
                                         or joined > 0)):
                break
            if ph.first is not None:
                ph.hold_done += 1
                ph.held_steps += int(ph.tally.formed(self.w))
        return self._end_phase(ph)

    def _start_phase(self, index: int, name: str) -> _Phase:
        cfg = self.cfg
        t_start = time.monotonic()
        choice = cfg.brains.get(name) if cfg.brains else None
        if choice is not None:
            swap_brain_in(choice, name, self.physics.ids, self.link, self.journal,
                          cfg.swap_timeout_s)
        C = self._publish_pattern(name, "phase")
        pos = self.physics.positions()
        ph = _Phase(index, name, C, choice, pos, self.step, self.link.late, t_start)
        ph.tally.start(pos, C)
        return ph

    def _bounds(self, ph: _Phase) -> None:
        """The phase's lower bounds (its step limit with them) and its ``phase_start`` event.

        Worked out during the phase's first step, while the robots take the new pattern
        (that step waits for all of them: :meth:`_deadline_s`): a hundred robots or more
        took a few tenths of a second to solve them, which the whole swarm waited for."""
        if ph.limit is not None:
            return
        cfg, w = self.cfg, self.w
        cpu = time.thread_time()
        lb_travel, lb_steps = lower_bounds(ph.start_pos, ph.C, w.v_max_mps, w.dt_s)
        ph.lower_bound_travel_m, ph.lower_bound_steps = lb_travel, lb_steps
        ph.limit = cfg.max_steps if cfg.max_steps is not None else phase_step_limit(lb_steps)
        self.bounds_cpu_s += time.thread_time() - cpu
        self.journal.event("phase_start", phase=ph.index, pattern=ph.label,
                           n=len(ph.start_pos), lower_bound_steps=lb_steps,
                           lower_bound_travel_m=round(lb_travel, 6),
                           brain=ph.choice.label if ph.choice else "robots' own")
        self.journal.say(f"pattern {ph.index + 1}/{len(cfg.patterns)}: {ph.label} with "
                         f"{len(ph.start_pos)} robots (lower bound {lb_steps} steps)", True)

    def _follow_membership(self, ph: _Phase) -> int | None:
        """Apply joins and leaves (resizing the pattern): robots joined; None when < 2 left."""
        joined, left = self.members.apply()
        if joined or left:
            ph.tally.joins += joined
            ph.tally.leaves += left
            if len(self.physics.ids) < 2:
                self.journal.say("fewer than 2 robots left: the phase cannot go on")
                return None
            ph.C = self._publish_pattern(ph.name, "resize")
        elif time.monotonic() - self.link.pattern_sent_s >= self.cfg.pattern_republish_s:
            self.link.put_pattern()
        return joined

    def _wheels(self, ids: list[int], v: Array) -> Array:
        """The velocities the robots move at for their commands ``v`` (n, 2), under the
        conditions' wheels (a new team draws its wheels afresh, seeded by the world's seed)."""
        c = self.cfg.conditions
        if c.acting_perfect:
            return v
        if self._wheel_ids != ids or self._wheel_model is None:
            seed = np.random.SeedSequence((self.cfg.seed, 2, len(ids), self.step))
            self._wheel_model = Wheels(c, 1, len(ids), [seed], self.w.dt_s)
            self._wheel_ids = list(ids)
        return np.asarray(self._wheel_model.apply(np.asarray(v)[None])[0])

    def _step(self, ph: _Phase, first: bool) -> bool:
        """Poses out, commands in, physics, measures, record; False if stopped meanwhile."""
        ids = list(self.physics.ids)
        pos = self.physics.positions()
        t_step = time.monotonic()
        cpu = _Stopwatch(self.cpu_split_s)
        bounds0 = self.bounds_cpu_s
        v, missed, age = self.link.exchange(
            self.step, self.w.dt_s, ids, pos, self._deadline_s(first), self.stop_event,
            wait_all=first, meanwhile=None if ph.limit is not None else lambda: self._bounds(ph))
        bounds = self.bounds_cpu_s - bounds0
        cpu.lap("exchange")
        self.cpu_split_s["exchange"] -= bounds  # the bounds are a measure
        self.cpu_split_s["measures"] += bounds
        if self.stop_event.is_set():
            return False
        v = self._wheels(ids, v)  # what the wheels make of the commands, then the guard
        scaled: list[int] = []
        if missed:  # stale commands and robots held still: no motion may close a pair in
            v, rows = guard_stale(pos, v, age, self.w, self.arena_m)
            scaled = [ids[k] for k in rows.tolist()]
        if self.cfg.mode == "realtime":
            self._adapt_rate(float(np.mean(age < 0)))
        cpu.lap("guard")
        res = self.physics.step(v)
        self.link.moved(ids, pos)
        self.step += 1
        ph.steps += 1
        cpu.lap("physics")
        m = ph.tally.step(ids, pos, res.positions, ph.C, res.new_contacts, missed, self.w,
                          age=age, scaled=scaled)
        brains = self.link.brains()
        ph.brain_ids.update(brains.get(r, "") for r in ids)
        cpu.lap("measures")
        self.journal.step_measures(m)
        self.journal.record_step(ph.index, ph.label, self.version, ph.steps, ids,
                                 res.positions, ph.C, m, t_step,
                                 1.0 / self.period_s if self.cfg.mode == "realtime" else None,
                                 self.link.views())
        cpu.lap("log")
        self.stepping_wall_s += time.monotonic() - t_step
        self.stepping_cpu_s += cpu.total
        if self.on_progress is not None:
            self.on_progress(Progress(ph.index, len(self.cfg.patterns), ph.label, self.step,
                                      ph.steps, m.error_m, len(ids), ph.tally.deadline_misses))
        return True

    def _adapt_rate(self, held_share: float) -> None:
        """realtime: a longer period while most robots hold still for want of a command."""
        a = HELD_AVERAGING
        self._held_avg = (1 - a) * self._held_avg + a * held_share
        cfg = self.cfg
        slowest = 1.0 / (cfg.min_rate_hz if cfg.min_rate_hz is not None else cfg.rate_hz / 4)
        if self._held_avg > HELD_SLOW_DOWN:
            self.period_s = min(self.period_s * SLOW_DOWN, slowest)
        elif self._held_avg < HELD_SPEED_UP:
            self.period_s = max(self.period_s / SPEED_UP, 1.0 / cfg.rate_hz)

    def _deadline_s(self, first: bool) -> float:
        """How long a step waits for commands. A step that brings news -- the run's first
        few, a pattern's first, the first after a join -- waits for every robot's command up to
        ``first_step_deadline_ms`` in both modes: robots decide their first step of a team
        or pattern from scratch (no warm start, cold caches), a hundred of them at once on
        two cores take a few periods, and in realtime the clock starts again after it."""
        if first:
            self._tick = None  # realtime: the schedule starts from the end of this step
            return self.cfg.first_step_deadline_ms / 1000.0
        if self.cfg.mode != "lockstep":  # to the step's tick, on a fixed schedule
            period = self.period_s
            now = time.monotonic()
            if self._tick is None or now > self._tick + period:
                if self._tick is not None:
                    self.overruns += 1
                self._tick = now  # behind by a whole period (or the first step): start again
            self._tick += period
            window = MIN_WINDOW_SHARE * period
            if self._tick - now < window:  # the poses go out late: slip, do not squeeze
                self.slipped_s += window - (self._tick - now)
                self._tick = now + window
            return self._tick - now
        return self.cfg.step_deadline_ms / 1000.0

    def _end_phase(self, ph: _Phase) -> PhaseResult:
        self._bounds(ph)  # a phase that ended before its first step
        t = ph.tally
        seen = sorted(b for b in ph.brain_ids if b)
        formed = ph.first is not None
        steps, travel_m, error_m = ph.first if ph.first is not None else (
            ph.steps, t.travel_m, t.error_m)
        hold = self.cfg.hold_steps
        result = PhaseResult(
            index=ph.index, pattern=ph.label, n_robots=len(self.physics.ids),
            formed=formed, steps=steps, step_limit=int(ph.limit or 0),
            lower_bound_steps=int(ph.lower_bound_steps), travel_m=round(travel_m, 6),
            lower_bound_travel_m=round(ph.lower_bound_travel_m, 6), collisions=t.collisions,
            contacts=t.contacts,
            min_separation_m=(round(t.min_separation_m, 6) if math.isfinite(t.min_separation_m)
                              else -1.0),
            deadline_misses=t.deadline_misses, late_commands=self.link.late - ph.late0,
            stale_commands=t.stale_commands, held_still=t.held_still,
            command_age_max=t.command_age_max, guard_scaled=t.guard_scaled,
            final_error_m=round(error_m, 6), brain=phase_brain_label(ph.choice, seen),
            brain_ids=seen, joins=t.joins, leaves=t.leaves, start_step=ph.start_step,
            end_step=self.step, wall_s=round(time.monotonic() - ph.t_start, 3),
            hold_steps=hold, held_steps=ph.held_steps,
            held=holds(formed, ph.held_steps, hold),
        )
        self.journal.event("phase_end", **asdict(result))
        verdict = "formed" if formed else "NOT formed"
        held = result.hold_text()
        self.journal.say(f"{ph.label}: {verdict} in {steps} steps"
                         + (f", {held}" if held else "")
                         + f" (lower bound {ph.lower_bound_steps}), error {error_m:.3f} m")
        return result

    def _publish_pattern(self, name: str, reason: str) -> Array:
        """A new version of the pattern at the live team size: published and logged."""
        n = len(self.physics.ids)
        pts = make_pattern(name, n, self.w)
        self.version = self.link.next_pattern_version()  # above any operator pattern held
        msg = PatternMsg(self.version, pattern_label(name), pts, self.w.formed_tol_m)
        self.link.put_pattern(encode_pattern(msg))
        self.journal.event("pattern", version=self.version, name=msg.name, n=n, reason=reason,
                           points=np.round(pts, 6).tolist(), formed_tol_m=self.w.formed_tol_m)
        return pts
