"""One robot over Zenoh: observe peers, act with a brain (its process:
:mod:`runtime.robot.process`).

Loop (one decision at a time; Zenoh callbacks store what arrives, and the all-poses
callback decides its step at once on Zenoh's thread when nothing else is pending -- see
:meth:`Robot._decide_here` -- else the loop's thread does):

* **lockstep** (default): the robot decides for step t as soon as it holds the
  poses of step t of all ``Pose.n_live`` live robots, or when
  ``--lockstep-deadline-s`` has passed since the first pose of step t (then
  with the freshest poses it has; peers older than ``--stale-s`` are absent).
  One command per step, stamped with the step.
* **realtime**: at ``--rate-hz`` with the latest poses; peers whose pose is
  older than ``--stale-s`` are absent.

With the world's poses of a step in one message (``patternrl/<swarm>/poses``,
what ``patternrl sim`` sends), both modes decide on each new step as soon as
its message arrives, on the newest step only (:mod:`runtime.robot.inbox`).

Late is slower, never unsafe: a command carries the step whose poses it was decided
from. In realtime the world applies a late one for one step while it is at most a
few steps old (the world's rule, :mod:`sim_bridge.world.world_link`, guarded by
:mod:`sim_bridge.world.stale_guard`); the robot decides from where its own late
commands will have taken it (:mod:`runtime.robot.in_flight`). A robot that falls
behind -- all-poses messages queued while it decided -- lets those go undecided
until the newest, and decides on the next one that did not wait behind another
(:meth:`Robot._on_poses`): a backlog drains instead of growing.

Nothing waits on another robot's decision. Every decision goes through the
:class:`runtime.decision.controller.Controller`: shared assignment, the observation the
brain's spec names, the brain, clamp to v_max, the ORCA safety filter.

Faults (DESIGN.md section 4): a malformed message on any key is dropped and
counted; a step whose brain output is NaN/inf is decided by the fallback the
user chose (``--nonfinite-fallback``: ``rule``, the default, decides it with
``rule:frame-balanced`` -- the shipped plan brains' own base -- or with the
robot's own rule brain; ``hold`` holds still for the step, counted as an
error), counted either way in the status (``nonfinite_fallbacks``), so the log
shows it; when no pose arrives for ``--watchdog-s`` the robot publishes a zero
command once and stops acting until poses return; with
``--exit-after-silence-s S`` it exits (code 0) once the world it had heard has
been silent S seconds.

Brain swap: a :class:`runtime.wire.messages.BrainMsg` on the swarm's brain key,
addressed to this robot (or to all), is decoded and validated on a background
thread (digest, onnxruntime load, input/output shapes, finite outputs on
probes, warm-up) and swapped in between two steps; the answer is a status
with ``swap_request_id``, ``swap_accepted``, ``swap_reason`` and the old and
new brain ids, published at once. A refused brain leaves the old one running.
A manifest ``{"rule": "rule:assign"}`` with no ONNX bytes swaps in a rule brain.

Slots: with ``--agree`` under imperfect sensing, each step the slot the robot goes by (the
lowest-id robot its whole assignment) on its slots key, just before the step's command, and
the team's heard (:mod:`runtime.robot.slot_talk`, :mod:`runtime.decision.agreement`).

The pieces (the robot holds them; its loop reads observe -> decide -> send):
:class:`runtime.robot.inbox.PoseInbox` (poses in, lockstep/realtime readiness, stale
peers), :class:`runtime.decision.team_pattern.TeamPattern` (which target),
:class:`runtime.robot.swap_worker.SwapWorker` (brain swaps),
:class:`runtime.robot.publish.Outbox` (commands, status, slots and views out),
:class:`runtime.robot.status.RobotStats` (status figures), the options in
:mod:`runtime.robot.cli`.
"""

from __future__ import annotations

import contextlib
import math
import random
import threading
import time
from typing import Final

import numpy as np
import zenoh

from runtime.brain.brain import RULE_PREFIX, Brain, load_brain
from runtime.decision.agreement import agree_mode, hears, local_views
from runtime.decision.controller import Controller
from runtime.decision.local import Perception, Seen
from runtime.decision.patterns import PatternError
from runtime.decision.pipeline import ERR_NONFINITE, Decision
from runtime.decision.safety import OrcaParams, guard_distance
from runtime.decision.settle import settle_for
from runtime.decision.team_pattern import TeamPattern
from runtime.log import Log, one_line
from runtime.net.session import direct
from runtime.robot.cli import FALLBACK_RULE, RobotConfig
from runtime.robot.in_flight import InFlight
from runtime.robot.inbox import PoseInbox, Step
from runtime.robot.publish import Outbox
from runtime.robot.slot_talk import SlotTalk
from runtime.robot.status import RobotStats
from runtime.robot.swap_worker import SwapWorker
from runtime.types import Array
from runtime.wire import keys
from runtime.wire.messages import MessageError, decode_pattern
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = ["Robot"]


IDLE_WAKE_S: Final = 0.2  # the loop looks at status, watchdog and stop at least this often
BACKLOG_GAP_S: Final = 0.002
"""realtime: an all-poses message whose callback starts this soon after the last one ended was
queued behind it (the robot is behind): it is kept, not decided."""


def _still(why: str) -> Decision:
    """Hold still, saying why."""
    return Decision((0.0, 0.0), (0.0, 0.0), False, 0.0, 0.0, why)


class Robot:
    """One robot: Zenoh in and out around a :class:`Controller`, and its loop."""

    def __init__(
        self,
        cfg: RobotConfig,
        brain: Brain,
        session: zenoh.Session,
        world: WorldConfig = DEFAULT_WORLD,
        safety: OrcaParams | None = OrcaParams(),  # noqa: B008 - frozen, immutable default
        log: Log | None = None,
    ) -> None:
        self.cfg = cfg
        self.world = world
        self.session = session
        self.id = cfg.robot_id
        self.log = log if log is not None else Log(f"robot {cfg.robot_id}", False)
        self.controller = Controller(brain, world, safety,
                                     settle_for(cfg.conditions, cfg.estimator, world),
                                     cfg.conditions.diff_turn_rps, local_views(cfg.conditions))
        self._perception: Perception | None = None  # for the team of the last decision
        self._perceived: tuple[int, Seen] | None = None
        self._fallback: Controller | None = None  # decides the steps a brain's NaN would lose
        self._fallback_step = -2  # the last step it decided (its history is fresh after it)
        self.stats = RobotStats()
        self.inbox = PoseInbox(
            self.id,
            cfg.swarm,
            realtime=cfg.mode == "realtime",
            rate_hz=cfg.rate_hz,
            lockstep_deadline_s=cfg.lockstep_deadline_s,
            stale_s=cfg.stale_s,
            log=self.log,
            drop=self._drop,
            on_restart=lambda: self.pattern.world_restarted(),
            decide_on_own_pose=cfg.ros2 is not None,
        )
        self.pattern = TeamPattern(cfg.pattern, world, self.log)
        self.pattern.guard_m = guard_distance(safety, world)
        self.pattern.use_brain(brain)
        self.swaps = SwapWorker(
            self.id,
            world,
            self.log,
            wake=self.inbox.cond,
            team_size=lambda: len(self._team_ids),
            drop=self._drop,
            error=self.stats.error,
            trust=cfg.trust,
        )
        self._stop = threading.Event()
        # held by whoever decides, swaps or holds: the loop, or a pose callback (_decide_here)
        self._loop_lock = threading.Lock()
        self._team_ids: list[int] = []  # the team of the last decision
        self._holding = False
        self._first_cmd_logged = False
        self._zenoh = contextlib.ExitStack()  # declarations, undeclared in reverse order
        self._delay_rng = random.Random(cfg.robot_id)  # --debug-delay-ms only
        self._in_flight = InFlight() if cfg.mode == "realtime" else None
        self._poses_done = -math.inf  # when the last all-poses callback ended
        self.backlog_skipped = 0
        """realtime: all-poses messages left undecided because they waited behind another."""
        self._pose_sub: zenoh.Subscriber[None] | None = None
        self._pose_keys_wanted = False  # set by _on_own_pose, taken by the loop
        self._t_start = time.monotonic()  # --world-timeout-s counts from here until a pose
        self.outbox = Outbox(self.id, self.stats, cfg.view_every)
        """What it tells: commands, status, its slots and views (and to ROS 2 with --ros2)."""
        mode = agree_mode(cfg.agree, cfg.conditions)
        self.slot_talk = (SlotTalk(self.id, cfg.conditions, (cfg.sensing_seed, self.id),
                                   self._drop, slots=mode == "slots")
                          if hears(mode, cfg.conditions) else None)
        """What it tells and hears of its team's slots and frame (``--agree``, under noise by
        default)."""

    # ------------------------------------------------------------- lifecycle

    def start(self) -> None:
        """Declare publishers, subscribers and the liveliness token; start the swap worker."""
        s, sw, z = self.session, self.cfg.swarm, self._zenoh
        views = self.cfg.view_every > 0 and not self.cfg.conditions.sensing_perfect
        self.outbox.declare(s, sw, z, views=views, slots=self.slot_talk is not None)
        if self.slot_talk is not None:  # before the poses: a step's decision hears them
            z.enter_context(s.declare_subscriber(keys.all_slots(sw), direct(self._on_slots)))
        z.enter_context(s.declare_subscriber(keys.poses_key(sw), direct(self._on_poses)))
        # per-robot poses until the first all-poses message (then undeclared). In realtime
        # its own only: a world without all-poses messages shows itself there, and every
        # robot's key is then listened to (:meth:`_on_own_pose`), from the next step on
        if self._in_flight is not None and self.cfg.ros2 is None:  # realtime: no step waits
            self.inbox.per_robot = False
            self._pose_sub = s.declare_subscriber(keys.pose_key(sw, self.id),
                                                  direct(self._on_own_pose))
        else:  # lockstep: the world waits for its first step; ROS 2: peers publish their own
            self._pose_sub = s.declare_subscriber(keys.all_poses(sw), self._on_pose)
        z.callback(self._drop_pose_keys)
        # patterns on the receiving thread too: a pattern the world sends just before a
        # step's poses is taken before that step is decided (handed to another thread, it
        # raced them, and the step was decided on the old pattern or none)
        z.enter_context(s.declare_subscriber(keys.pattern_key(sw), direct(self._on_pattern)))
        z.enter_context(s.declare_subscriber(keys.operator_pattern_key(sw),
                                             direct(self._on_operator_pattern)))
        z.enter_context(s.declare_subscriber(keys.brain_key(sw), self._on_brain))
        z.enter_context(s.liveliness().declare_token(keys.alive_key(sw, self.id)))
        self.swaps.start()
        z.callback(self.swaps.close)
        if self.cfg.ros2 is not None:  # rclpy loads here only
            from runtime.ros2.robot_link import open_robot_link

            self.outbox.ros2 = z.enter_context(open_robot_link(
                self.cfg.ros2, self, lambda: len(self._team_ids)
            ))
        try:  # the latest pattern, if someone (the world) answers queries on it
            s.get(keys.pattern_key(sw), self._on_pattern_reply, timeout=2.0)
        except zenoh.ZError as e:  # a query nobody can answer is not an error
            self.log("debug", "pattern_query", str(e))
        self.outbox.status(self._brain_id())

    def stop(self) -> None:
        """Ask the loop to end (within IDLE_WAKE_S); safe from a signal handler."""
        self._stop.set()

    def close(self) -> None:
        """Stop the swap worker, undeclare everything declared (the session is the caller's)."""
        self._stop.set()
        self._zenoh.close()

    # ------------------------------------------------------------- callbacks

    def _drop(self, what: str, why: str) -> None:
        self.stats.drop()
        self.log("debug", "dropped", f"{what}: {one_line(why, 160)}")

    def _on_pose(self, sample: zenoh.Sample) -> None:
        self.inbox.take(str(sample.key_expr), sample.payload.to_bytes())

    def _on_own_pose(self, sample: zenoh.Sample) -> None:
        """This robot's per-robot pose. A world that sends all poses in one message sends
        it before the per-robot ones: heard first without any, every robot's pose key is
        listened to (by the loop, :meth:`_listen_to_pose_keys`). Listening to them from the
        start cost a hundred-robot swarm ten thousand messages a step until the robots
        undeclared them, and its first steps were late."""
        self._on_pose(sample)
        if not self.inbox.batches and not self._pose_keys_wanted:
            self._pose_keys_wanted = True
            self.inbox.wake()

    def _listen_to_pose_keys(self) -> None:
        """Every robot's per-robot pose instead of this robot's own (loop only)."""
        self._pose_keys_wanted = False
        if self._pose_sub is None or self.inbox.batches:
            return
        self._drop_pose_keys()
        self._pose_sub = self.session.declare_subscriber(keys.all_poses(self.cfg.swarm),
                                                         self._on_pose)
        self.inbox.listen_per_robot()
        self.log("debug", "poses", "no all-poses message: listening to every robot's pose")

    def _drop_pose_keys(self) -> None:
        sub, self._pose_sub = self._pose_sub, None
        if sub is not None:
            sub.undeclare()  # type: ignore[no-untyped-call]

    def _on_poses(self, sample: zenoh.Sample) -> None:
        # realtime: a message that was waiting while the last one was handled is likely not
        # the newest: deciding every message of a backlog would keep the robot behind
        behind = (self._in_flight is not None
                  and time.monotonic() - self._poses_done < BACKLOG_GAP_S)
        if self.inbox.take_batch(sample.payload.to_bytes(), notify=False):
            if behind:
                self.backlog_skipped += 1
            elif not self._decide_here():
                self.inbox.wake()
        self._poses_done = time.monotonic()

    def _decide_here(self) -> bool:
        """Decide and send the step just received, on Zenoh's thread: no hand-over to the
        loop's thread, whose wake-up per step cost more than the decision in a 100-robot
        swarm. Only in the plain case -- poses in one message, not holding, no swap
        waiting, no testing delay, the loop not busy -- else False and the loop does it."""
        if self._pose_sub is not None or self.cfg.debug_delay_ms > 0:
            return False
        if not self._loop_lock.acquire(blocking=False):
            return False
        try:
            if self._holding or self._stop.is_set() or self.swaps.busy():
                return False
            step = self.inbox.take_ready()
            if step is None:
                return False
            try:
                self._send(step.step, self._decide(step))
            except Exception as e:  # never a traceback on Zenoh's thread: the step is lost
                self.stats.error(f"send: {one_line(f'{type(e).__name__}: {e}', 160)}")
            return True
        finally:
            self._loop_lock.release()

    def _on_slots(self, sample: zenoh.Sample) -> None:
        if self.slot_talk is not None:
            try:
                self.slot_talk.take(str(sample.key_expr), sample.payload.to_bytes())
            except Exception as e:  # whatever arrives, never a traceback on Zenoh's thread
                self._drop("slots", f"{type(e).__name__}: {e}")

    def _on_pattern(self, sample: zenoh.Sample) -> None:
        self._take_pattern(sample.payload.to_bytes())

    def _on_operator_pattern(self, sample: zenoh.Sample) -> None:
        self._take_pattern(sample.payload.to_bytes(), operator=True)

    def _on_pattern_reply(self, reply: zenoh.Reply) -> None:
        ok = reply.ok
        if ok is not None:
            self._take_pattern(ok.payload.to_bytes())

    def _take_pattern(self, payload: bytes, operator: bool = False) -> None:
        try:
            self.pattern.offer(decode_pattern(payload), operator)
        except (MessageError, PatternError) as e:  # sizes, values, then meaning
            self._drop("pattern", str(e))
        except Exception as e:  # whatever arrives, never a traceback on Zenoh's thread
            self._drop("pattern", f"{type(e).__name__}: {e}")

    def _on_brain(self, sample: zenoh.Sample) -> None:
        self.swaps.offer(sample.payload.to_bytes())

    # ------------------------------------------------------------------ loop

    def run(self) -> int:
        """The control loop; returns the exit code once stopped."""
        period = self.cfg.status_period_s
        next_status = time.monotonic() + period
        while not self._stop.is_set():
            with self._loop_lock:
                for reply in self.swaps.apply(self._brain_id, self._install):  # between steps
                    self.outbox.status(self._brain_id(), reply)
                now = time.monotonic()
                if now >= next_status:
                    self.outbox.status(self._brain_id())
                    self.stats.new_period()
                    next_status = now + period
                code = self._watch(now)
                if self._pose_keys_wanted:
                    self._listen_to_pose_keys()
            if code is not None:
                return code
            wake_by = min(next_status, now + IDLE_WAKE_S)
            step = self.inbox.next_step(now, wake_by, self._holding, self.swaps.busy)  # observe
            if step is None:
                continue
            with self._loop_lock:
                if self._pose_sub is not None and self.inbox.batches:
                    self._drop_pose_keys()  # the world sends all poses in one message
                decision = self._decide(step)  # decide
                if self.cfg.debug_delay_ms > 0:  # testing only: a slow robot, on purpose
                    time.sleep(self._delay_rng.uniform(0.0, self.cfg.debug_delay_ms) / 1000.0)
                self._send(step.step, decision)  # send
        return 0

    def _watch(self, now: float) -> int | None:
        """The watchdog: hold still without poses, resume with them; an exit code on silence."""
        cfg = self.cfg
        silent = self.inbox.silence_s(now)
        if silent is None:  # never heard: only the world timeout counts, from the start
            waited = now - self._t_start
            if cfg.world_timeout_s > 0 and waited > cfg.world_timeout_s:
                self.log("error", "exit", f"no world: no pose in {waited:.1f} s "
                         f"(--world-timeout-s {cfg.world_timeout_s:g}), exiting")
                return 1
            return None
        if silent > cfg.watchdog_s and not self._holding:
            self._hold_still(f"no pose for {silent:.1f} s, holding still")
        elif silent <= cfg.watchdog_s and self._holding:
            self._holding = False
            self.log("info", "resume", "poses are back")
        if cfg.exit_after_silence_s > 0 and silent > cfg.exit_after_silence_s:
            self.log("info", "exit", f"world silent for {silent:.1f} s")
            return 0
        if cfg.world_timeout_s > 0 and silent > cfg.world_timeout_s:
            self.log("error", "exit", f"the world is gone: no pose for {silent:.1f} s "
                     f"(--world-timeout-s {cfg.world_timeout_s:g}), exiting")
            return 1
        return None

    def _decide(self, step: Step) -> Decision:
        n = len(step.ids)
        if step.ids != self._team_ids:
            if self._team_ids:
                self.log("info", "team", f"{len(self._team_ids)} -> {n} robots")
            self.controller.reset()
            self._team_ids = step.ids
            self._perception = self._perceive_team(step.ids.index(self.id))
        pattern, why = self.pattern.for_team(n)
        if pattern is None:
            d = _still(why)
        else:
            try:
                me = step.ids.index(self.id)
                positions = step.positions
                if self._in_flight is not None:  # where its late commands take it meanwhile
                    dx, dy = self._in_flight.displacement(step.step, self.inbox.arrived,
                                                          self.world.dt_s)
                    if dx or dy:
                        positions = positions.copy()
                        positions[me] += (dx, dy)
                seen = (Seen(positions) if self._perception is None
                        else self._perceive(step, positions))
                if self.outbox.sends_views and self._perception is not None:
                    self.outbox.stage_view(step, seen, self._perception)
                talk, version = self.slot_talk, self.pattern.version
                heard = (None if talk is None
                         else talk.heard(step.step, step.ids, me, version))
                d = self.controller.decide(me, seen.plan, pattern, step.step, seen.vel,
                                           seen.now, seen.guard_ref, seen.moment, heard,
                                           seen.in_view)
                if d.error == ERR_NONFINITE:
                    d = self._nonfinite(step, pattern, d, seen)
                if talk is not None:
                    agreement = self.controller.agreement
                    talk.adopted_steps += agreement.adopted
                    talk.frame_steps += agreement.heard_frame
                    self.outbox.stage_slots(talk.told(
                        step.step, version, step.ids, me,
                        None if d.slot < 0 else self.controller.previous_slots,
                        agreement.told_frame))
            except Exception as e:  # whatever arrives, the loop goes on, holding still
                self.controller.reset()
                d = _still(f"decision failed: {e}")
        if d.error:
            if d.error != self.stats.last_error:
                self.log("warning", "hold", d.error, step=step.step)
            self.stats.error(d.error, count=pattern is not None)  # no pattern yet: no error
        return d

    def _perceive_team(self, index: int) -> Perception | None:
        """A new team's sensing (None when the robot sees the poses as they are)."""
        c = self.cfg.conditions
        if c.sensing_perfect and not self.cfg.estimator:
            return None
        seed = np.random.SeedSequence((self.cfg.sensing_seed, self.id))
        self._perceived = None
        return Perception(c, np.array([index]), [seed], self.cfg.estimator, self.world)

    def _perceive(self, step: Step, positions: Array) -> Seen:
        """This step's team (``positions``, the poses of ``step``) as the robot perceives it:
        sensed once per world step (a repeated step in realtime reuses it, so latency counts
        world steps); peers out of view go along the plan of the robot's last decision."""
        assert self._perception is not None
        if self._perceived is None or self._perceived[0] != step.step:
            team = self.controller.team_velocity
            follow = team[None] if team is not None and len(team) == len(positions) else None
            self._perceived = (step.step, self._perception.perceive(
                np.asarray(positions)[None], follow, step.step).row(0))
        return self._perceived[1]

    def _nonfinite(self, step: Step, pattern: Array, d: Decision,
                   seen: Seen) -> Decision:
        """A step whose brain output is not finite: counted, and decided by the fallback."""
        self.stats.nonfinite()
        if self.cfg.nonfinite_fallback == "hold":
            return d
        fb = self._fallback
        if fb is None:
            own = self.controller.brain
            rule = own if own.brain_id.startswith(RULE_PREFIX) else load_brain(FALLBACK_RULE,
                                                                                 self.world)
            fb = self._fallback = Controller(
                rule, self.world, self.controller.safety,
                settle_for(self.cfg.conditions, self.cfg.estimator, self.world),
                self.cfg.conditions.diff_turn_rps, local_views(self.cfg.conditions))
        if self._fallback_step != step.step - 1:  # not the step after its last: no history
            fb.reset()
            self.log("warning", "fallback", f"{ERR_NONFINITE.split(':')[0]}: "
                     f"deciding by {fb.brain.brain_id}", step=step.step)
            self.stats.error(f"{ERR_NONFINITE.split(':')[0]}: decided by {fb.brain.brain_id}",
                             count=False)
        self._fallback_step = step.step
        fd = fb.decide(step.ids.index(self.id), seen.plan, pattern, step.step, seen.vel,
                       seen.now, seen.guard_ref, seen.moment, in_view=seen.in_view)
        return d if fd.error else fd

    def _send(self, step: int, d: Decision) -> None:
        self.outbox.send(step, d, self._brain_id())
        if self._in_flight is not None:
            self._in_flight.sent(step, d.velocity[0], d.velocity[1], time.monotonic(),
                                 self.inbox.newest_step)
        t = self.stats.decided(step, d.decision_us, d.safety_changed)
        if not self._first_cmd_logged:
            self._first_cmd_logged = True
            since = round(t - self.stats.t_start, 3)
            self.log("debug", "first_command", step=step, since_start_s=since)

    def _hold_still(self, why: str) -> None:
        self._holding = True
        self.controller.reset()
        if self._in_flight is not None:
            self._in_flight.reset()
        self._team_ids = []
        self.stats.error(f"watchdog: {why}", count=False)
        self.log("warning", "watchdog", why)
        self.outbox.command(max(self.stats.last_step, 0), _still(why), self._brain_id())

    def _brain_id(self) -> str:
        return self.controller.brain.brain_id

    def _install(self, brain: Brain) -> None:
        self.controller.set_brain(brain)
        self._fallback = None  # the fallback follows a new rule brain
        self.pattern.use_brain(brain)
