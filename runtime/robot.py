"""``patternrl robot``: one robot's process. Observe peers over Zenoh, act with a brain.

Loop (one thread decides; Zenoh callbacks only store what arrives):

* **lockstep** (default): the robot decides for step t as soon as it holds the
  poses of step t of all ``Pose.n_live`` live robots, or when
  ``--lockstep-deadline-s`` has passed since the first pose of step t (then
  with the freshest poses it has; peers older than ``--stale-s`` are absent).
  One command per step, stamped with the step.
* **realtime**: at ``--rate-hz`` with the latest poses; peers whose pose is
  older than ``--stale-s`` are absent.

Nothing waits on another robot's decision. Every decision goes through the
:class:`runtime.controller.Controller`: shared assignment, the observation the
brain's spec names, the brain, clamp to v_max, the ORCA safety filter.

Faults (DESIGN.md section 4): a malformed message on any key is dropped and
counted; a brain that outputs NaN/inf makes the robot hold still (counted as an
error); when no pose arrives for ``--watchdog-s`` the robot publishes a zero
command once and stops acting until poses return; with
``--exit-after-silence-s S`` it exits (code 0) once the world it had heard has
been silent S seconds.

Brain swap: a :class:`runtime.messages.BrainMsg` on the swarm's brain key,
addressed to this robot (or to all), is decoded and validated on a background
thread (digest, onnxruntime load, input/output shapes, finite outputs on
probes, warm-up) and swapped in between two steps; the answer is a status
with ``swap_request_id``, ``swap_accepted``, ``swap_reason`` and the old and
new brain ids, published at once. A refused brain leaves the old one running.
A manifest ``{"rule": "rule:assign"}`` with no ONNX bytes swaps in a rule brain.

Status: about once a second on the robot's status key (decision latency p50 and
p99 over the last period, loop jitter = p99 - p50 of the interval between
consecutive decisions, messages dropped, errors, safety interventions).

Exit codes: 0 on SIGINT/SIGTERM or ``--exit-after-silence-s``; 2 on bad input
(missing or invalid brain, bad pattern, bad options), with one line on stderr;
1 on an unexpected failure.
"""

from __future__ import annotations

import argparse
import json
import math
import queue
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from types import FrameType, MappingProxyType
from typing import Any, Final, TextIO

import numpy as np
import zenoh

from runtime import keys
from runtime.brain import Brain, BrainError, BrainManifest, load_brain, validate_brain_bytes
from runtime.controller import Controller, Decision
from runtime.errors import InputError
from runtime.messages import (
    BrainMsg,
    Command,
    MessageError,
    PatternMsg,
    Pose,
    Status,
    decode_brain,
    decode_pattern,
    decode_pose,
    encode_command,
    encode_status,
)
from runtime.patterns import (
    PatternError,
    make_pattern,
    min_spacing,
    pattern_label,
)
from runtime.safety import OrcaParams
from runtime.team_pattern import fit_pattern
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from runtime.zenoh_session import ZenohSetupError, add_zenoh_arguments, open_session_from_args

__all__ = ["Robot", "RobotConfig", "add_arguments", "run"]


HEAVY_MODULES = ("torch", "onnx", "pymunk", "mcap", "matplotlib")
MAX_STATUS_TEXT = 400
MAX_COORD_M = 1e6  # a pose farther from the origin is malformed (and would overflow costs)
SWAP_QUEUE = 4


# -------------------------------------------------------------------- logging


class Log:
    """One line per event on stderr; text by default, JSON with ``--json-logs``."""

    LEVELS: Final[Mapping[str, int]] = MappingProxyType(
        {"debug": 10, "info": 20, "warning": 30, "error": 40}
    )

    def __init__(
        self, name: str, json_lines: bool, level: str = "info", stream: TextIO | None = None
    ) -> None:
        self.name = name
        self.json_lines = json_lines
        self.level = self.LEVELS[level]
        self.stream = stream if stream is not None else sys.stderr
        self._lock = threading.Lock()

    def __call__(self, level: str, event: str, msg: str = "", **fields: Any) -> None:
        if self.LEVELS[level] < self.level:
            return
        if self.json_lines:
            rec: dict[str, Any] = {
                "t": round(time.time(), 6),
                "level": level,
                "src": self.name,
                "event": event,
            }
            if msg:
                rec["msg"] = msg
            rec.update(fields)
            line = json.dumps(rec, default=str, separators=(",", ":"))
        else:
            extra = " ".join(f"{k}={v}" for k, v in fields.items())
            line = (
                f"{self.name}: {event}"
                + (f": {msg}" if msg else "")
                + (f" [{extra}]" if extra else "")
            )
        with self._lock:
            try:
                self.stream.write(line + "\n")
                self.stream.flush()
            except (OSError, ValueError):
                pass


# --------------------------------------------------------------------- config


@dataclass
class RobotConfig:
    swarm: str
    robot_id: int
    mode: str = "lockstep"
    rate_hz: float = 10.0
    lockstep_deadline_s: float = 0.02
    watchdog_s: float = 1.0
    stale_s: float = 1.0
    exit_after_silence_s: float = 0.0
    status_period_s: float = 1.0
    pattern: str | None = None


def _percentile(sorted_vals: list[float], q: float) -> float:
    if not sorted_vals:
        return 0.0
    idx = min(len(sorted_vals) - 1, max(0, math.ceil(q * len(sorted_vals)) - 1))
    return float(sorted_vals[idx])


def _one_line(text: str, limit: int = MAX_STATUS_TEXT) -> str:
    line = " ".join(str(text).split())
    return line[:limit]


def _short(brain_id: str) -> str:
    return brain_id if brain_id.startswith("rule:") else brain_id[:12]


# ---------------------------------------------------------------------- robot


class Robot:
    """One robot's runtime: Zenoh plumbing around a :class:`Controller`."""

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
        self.log = log if log is not None else Log(f"robot {cfg.robot_id}", False)
        self.controller = Controller(brain, world, safety)
        self.id = cfg.robot_id
        self._t_start = time.monotonic()
        self._stop = threading.Event()
        self._cond = threading.Condition(threading.Lock())
        # --- state written by callbacks, under self._cond
        self._poses: dict[int, tuple[Pose, float]] = {}
        self._last_pose_t: float | None = None
        self._col_step = -1
        self._col_ids: set[int] = set()
        self._col_t0 = 0.0
        self._col_n_live = 0
        self._restart = False
        self._pattern_msg: PatternMsg | None = None
        self._pending: deque[tuple[str, Brain | None, str]] = deque()  # (request, brain, why)
        self._answers: deque[tuple[str, bool, str, str, str]] = deque()
        self._recent_answers: dict[str, tuple[bool, str, str, str]] = {}
        # --- counters, incremented under _count_lock (several threads count)
        self._count_lock = threading.Lock()
        self.dropped = 0
        self.errors = 0
        self.interventions = 0
        self.steps = 0
        self.last_error = ""
        # --- loop state (loop thread only)
        self._last_decided = -1
        self._team_ids: list[int] = []
        self._pattern_cache: tuple[object, int, Array | None, str] | None = None
        self._lat: list[float] = []
        self._dec_times: list[float] = []
        self._holding = False
        self._last_step_seen = 0
        self._first_cmd_logged = False
        self._swap_q: queue.Queue[bytes] = queue.Queue(maxsize=SWAP_QUEUE)
        self._decls: list[Any] = []
        self._fixed_pattern: Array | None = None
        self._default_pattern: str | None = cfg.pattern
        self._refresh_fixed_pattern()

    # ------------------------------------------------------------- lifecycle

    def start(self) -> None:
        s = self.session
        sw = self.cfg.swarm
        self._cmd_pub = s.declare_publisher(keys.cmd_key(sw, self.id), express=True)
        self._status_pub = s.declare_publisher(keys.status_key(sw, self.id), express=True)
        self._decls += [self._cmd_pub, self._status_pub]
        self._decls.append(s.declare_subscriber(keys.all_poses(sw), self._on_pose))
        self._decls.append(s.declare_subscriber(keys.pattern_key(sw), self._on_pattern))
        self._decls.append(s.declare_subscriber(keys.brain_key(sw), self._on_brain))
        self._decls.append(s.liveliness().declare_token(keys.alive_key(sw, self.id)))
        self._worker = threading.Thread(target=self._swap_worker, name="brain-swap", daemon=True)
        self._worker.start()
        try:  # the latest pattern, if someone (the world) answers queries on it
            s.get(keys.pattern_key(sw), self._on_pattern_reply, timeout=2.0)
        except Exception as e:  # a query nobody answers is not an error
            self.log("debug", "pattern_query", str(e))
        self._publish_status()

    def stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    def close(self) -> None:
        """Undeclare everything this robot declared (the session is the caller's)."""
        self._stop.set()
        try:
            self._swap_q.put_nowait(b"")
        except queue.Full:
            pass
        for d in reversed(self._decls):
            try:
                d.undeclare()
            except Exception:
                pass
        self._decls.clear()

    # -------------------------------------------------------------- callbacks

    def _drop(self, what: str, why: str) -> None:
        with self._count_lock:  # callbacks run on several Zenoh threads
            self.dropped += 1
        self.log("debug", "dropped", f"{what}: {_one_line(why, 160)}")

    def _on_pose(self, sample: zenoh.Sample) -> None:
        try:
            pose = decode_pose(sample.payload.to_bytes())
        except MessageError as e:
            self._drop("pose", str(e))
            return
        rid = keys.parse_robot_id(str(sample.key_expr))
        if rid is None or rid != pose.robot_id:
            self._drop("pose", f"robot_id {pose.robot_id} on key {sample.key_expr}")
            return
        if pose.n_live < 1:
            self._drop("pose", f"n_live {pose.n_live}")
            return
        if max(abs(pose.x), abs(pose.y)) > MAX_COORD_M:
            self._drop("pose", f"position ({pose.x:g}, {pose.y:g}) beyond {MAX_COORD_M:g} m")
            return
        now = time.monotonic()
        with self._cond:
            self._poses[rid] = (pose, now)
            self._last_pose_t = now
            s = pose.step
            if s > self._col_step:
                self._col_step, self._col_ids, self._col_t0 = s, {rid}, now
            elif s == self._col_step:
                self._col_ids.add(rid)
            elif rid == self.id:  # our own step went back: the world restarted
                self._col_step, self._col_ids, self._col_t0 = s, {rid}, now
                self._restart = True
            if s == self._col_step:
                self._col_n_live = pose.n_live
                if self.id in self._col_ids and len(self._col_ids) >= pose.n_live:
                    self._cond.notify()

    def _take_pattern(self, payload: bytes) -> None:
        try:
            msg = decode_pattern(payload)
        except MessageError as e:
            self._drop("pattern", str(e))
            return
        if len(msg.points) < 2 or min_spacing(msg.points) < self.world.min_separation_m:
            self._drop("pattern", f"'{msg.name}' has fewer than 2 points or points closer than 2R")
            return
        with self._cond:
            old = self._pattern_msg
            if old is None or msg.version >= old.version:
                self._pattern_msg = msg

    def _on_pattern(self, sample: zenoh.Sample) -> None:
        self._take_pattern(sample.payload.to_bytes())

    def _on_pattern_reply(self, reply: zenoh.Reply) -> None:
        ok = reply.ok
        if ok is not None:
            self._take_pattern(ok.payload.to_bytes())

    def _on_brain(self, sample: zenoh.Sample) -> None:
        try:
            self._swap_q.put_nowait(sample.payload.to_bytes())
        except queue.Full:
            self._drop("brain", "swap queue full")

    # ------------------------------------------------------------ swap worker

    def _swap_worker(self) -> None:
        # Not niced on purpose: this thread holds the GIL in stretches, and a
        # low-priority GIL holder would stall the control loop under CPU load.
        while not self._stop.is_set():
            payload = self._swap_q.get()
            if self._stop.is_set() or not payload:
                return
            try:
                self._handle_brain(payload)
            except Exception as e:  # never let a brain take the worker down
                with self._count_lock:
                    self.errors += 1
                self.last_error = _one_line(f"swap worker: {e}")

    def _handle_brain(self, payload: bytes) -> None:
        try:
            msg = decode_brain(payload)
        except MessageError as e:
            self._drop("brain", str(e))
            return
        if msg.target_robots and self.id not in msg.target_robots:
            return
        done = self._recent_answers.get(msg.request_id)
        if done is not None:  # a re-sent request: answer again, do not swap again
            with self._cond:
                self._answers.append((msg.request_id, *done))
                self._cond.notify()
            return
        brain, reason = self._validate(msg)
        with self._cond:
            self._pending.append((msg.request_id, brain, reason))
            self._cond.notify()

    def _validate(self, msg: BrainMsg) -> tuple[Brain | None, str]:
        try:
            try:
                raw = json.loads(msg.manifest_json)
            except (ValueError, RecursionError):
                raw = None
            if isinstance(raw, dict) and "rule" in raw and not msg.onnx_bytes:
                brain: Brain = load_brain(str(raw["rule"]), self.world)
            else:
                manifest = BrainManifest.from_json(msg.manifest_json)
                if not manifest.brain_id:
                    raise BrainError("manifest has no brain_id (the sha256 of the ONNX bytes)")
                brain = validate_brain_bytes(
                    msg.onnx_bytes, manifest, manifest.brain_id, self.world
                )
            n = len(self._team_ids)
            if n and not brain.spec.accepts_team(n):
                raise BrainError(f"brain observes {brain.spec.n_robots} robots, the team has {n}")
            return brain, ""
        except BrainError as e:
            return None, _one_line(str(e))

    def _apply_swap(self) -> None:
        """Between two steps: swap in a validated brain, queue the answer."""
        while True:
            with self._cond:
                if not self._pending:
                    return
                pending = self._pending.popleft()
            self._swap_one(*pending)

    def _swap_one(self, req: str, brain: Brain | None, reason: str) -> None:
        old = self.controller.brain.brain_id
        if brain is None:
            ans = (False, reason, old, old)
            self.log("info", "swap", f"refused: {reason}", request=req, brain=_short(old))
        else:
            if brain.brain_id == old:
                reason = "already running"
            self.controller.set_brain(brain)
            self._refresh_fixed_pattern()
            ans = (True, reason, old, brain.brain_id)
            self.log(
                "info", "swap", "accepted", request=req, old=_short(old), new=_short(brain.brain_id)
            )
        self._recent_answers[req] = ans
        while len(self._recent_answers) > 64:
            self._recent_answers.pop(next(iter(self._recent_answers)))
        self._answers.append((req, *ans))

    # ---------------------------------------------------------------- pattern

    def _refresh_fixed_pattern(self) -> None:
        """A paper brain trained for one pattern uses that pattern, whatever the key says."""
        m = self.controller.brain.manifest
        self._fixed_pattern = None
        if m is not None and self.controller.brain.spec.name == "paper" and m.pattern:
            n = m.n_robots or self.controller.brain.spec.n_robots
            try:
                self._fixed_pattern = make_pattern(m.pattern, n, self.world)
            except PatternError as e:
                self.log("warning", "pattern", f"brain's own pattern unusable: {e}")

    def _pattern_for(self, n: int) -> tuple[Array | None, str]:
        """The target for a team of n (cached), or (None, why not)."""
        if self._fixed_pattern is not None:
            src: object = self._fixed_pattern
        else:
            src = self._pattern_msg if self._pattern_msg is not None else self._default_pattern
        cache = self._pattern_cache
        if cache is not None and cache[0] is src and cache[1] == n:
            return cache[2], cache[3]
        pts: Array | None = None
        why = ""
        try:
            if src is None:
                why = "no pattern yet"
            elif isinstance(src, np.ndarray):
                pts = src if len(src) == n else None
                why = "" if pts is not None else f"brain's pattern has {len(src)} points, team {n}"
            elif isinstance(src, PatternMsg):
                pts = self._fit_pattern(src, n)
                self.log("info", "pattern", f"{src.name} v{src.version} for {n} robots")
            else:
                pts = make_pattern(str(src), n, self.world)
                self.log("info", "pattern", f"{pattern_label(str(src))} for {n} robots")
        except PatternError as e:
            why = _one_line(str(e))
            self.log("warning", "pattern", why)
        self._pattern_cache = (src, n, pts, why)
        return pts, why

    def _fit_pattern(self, msg: PatternMsg, n: int) -> Array:
        return fit_pattern(msg.name, np.asarray(msg.points, dtype=np.float64), n, self.world)

    # ------------------------------------------------------------------- loop

    def _team(self, now: float, step: int | None) -> tuple[list[int], Array] | None:
        """Ids and positions of the live robots (sorted by id); None without our own pose."""
        stale = self.cfg.stale_s
        ids: list[int] = []
        xy: list[tuple[float, float]] = []
        for rid in sorted(self._poses):
            pose, t = self._poses[rid]
            if step is not None:
                if pose.step != step:
                    continue
            elif now - t > stale:
                continue
            ids.append(rid)
            xy.append((pose.x, pose.y))
        if self.id not in ids:
            return None
        return ids, np.array(xy, dtype=np.float64)

    def _ready_lockstep(self, now: float) -> tuple[int, list[int], Array] | None:
        """Under the lock: (step, ids, positions) when step t is complete or overdue."""
        s = self._col_step
        if s < 0 or s <= self._last_decided:
            return None
        complete = self.id in self._col_ids and len(self._col_ids) >= self._col_n_live
        if complete:
            team = self._team(now, s)
        elif now >= self._col_t0 + self.cfg.lockstep_deadline_s:
            team = self._team(now, None)
            own = self._poses.get(self.id)
            if own is None or now - own[1] > self.cfg.stale_s:
                team = None
        else:
            return None
        if team is None:
            self._last_decided = s  # cannot act on this step without our own pose
            self.log("debug", "skip", f"step {s}: no fresh pose of this robot")
            return None
        return s, team[0], team[1]

    def _ready_realtime(self, now: float) -> tuple[int, list[int], Array] | None:
        team = self._team(now, None)
        if team is None:
            return None
        own = self._poses[self.id][0]
        return own.step, team[0], team[1]

    def _decide(self, step: int, ids: list[int], pos: Array) -> None:
        n = len(ids)
        if ids != self._team_ids:
            if self._team_ids:
                self.log("info", "team", f"{len(self._team_ids)} -> {n} robots")
            self.controller.reset()
            self._team_ids = ids
        pattern, why = self._pattern_for(n)
        if pattern is None:
            d = Decision((0.0, 0.0), (0.0, 0.0), False, 0.0, 0.0, why)
        else:
            try:
                d = self.controller.decide(ids.index(self.id), pos, pattern, step)
            except Exception as e:  # whatever arrives, the loop goes on, holding still
                self.controller.reset()
                d = Decision((0.0, 0.0), (0.0, 0.0), False, 0.0, 0.0, f"decision failed: {e}")
        if d.error:
            if pattern is not None:  # waiting for a pattern is not an error
                with self._count_lock:
                    self.errors += 1
            if d.error != self.last_error:
                self.log("warning", "hold", d.error, step=step)
            self.last_error = d.error
        if d.safety_changed:
            self.interventions += 1
        self._publish_cmd(step, d)
        self.steps += 1
        self._last_step_seen = step
        t = time.monotonic()
        self._lat.append(d.decision_us)
        self._dec_times.append(t)
        if not self._first_cmd_logged:
            self._first_cmd_logged = True
            self.log("debug", "first_command", step=step, since_start_s=round(t - self._t_start, 3))

    def _publish_cmd(self, step: int, d: Decision) -> None:
        cmd = Command(
            robot_id=self.id,
            step=step,
            vx=d.velocity[0],
            vy=d.velocity[1],
            brain_id=self.controller.brain.brain_id[:64],
            safety_changed=d.safety_changed,
            safety_change_mps=d.safety_change_mps if math.isfinite(d.safety_change_mps) else 0.0,
            decision_us=d.decision_us,
        )
        self._cmd_pub.put(encode_command(cmd))

    def _status(self, swap: tuple[str, bool, str, str, str] | None = None) -> Status:
        lat = sorted(self._lat)
        gaps = sorted(b - a for a, b in zip(self._dec_times, self._dec_times[1:], strict=False))
        jitter_ms = (_percentile(gaps, 0.99) - _percentile(gaps, 0.5)) * 1000.0 if gaps else 0.0
        kw: dict[str, Any] = {}
        if swap is not None:
            req, accepted, reason, old, new = swap
            kw = dict(
                swap_request_id=_one_line(req, 256),
                swap_accepted=accepted,
                swap_reason=reason,
                old_brain_id=old[:64],
            )
            brain_id = new
        else:
            brain_id = self.controller.brain.brain_id
        return Status(
            robot_id=self.id,
            step=max(self._last_step_seen, 0),
            brain_id=brain_id[:64],
            decision_latency_us_p50=_percentile(lat, 0.5),
            decision_latency_us_p99=_percentile(lat, 0.99),
            loop_jitter_ms=max(jitter_ms, 0.0),
            messages_dropped=self.dropped,
            errors=self.errors,
            safety_interventions=self.interventions,
            last_error=_one_line(self.last_error),
            uptime_s=time.monotonic() - self._t_start,
            **kw,
        )

    def _publish_status(self, swap: tuple[str, bool, str, str, str] | None = None) -> None:
        try:
            self._status_pub.put(encode_status(self._status(swap)))
        except MessageError as e:
            with self._count_lock:
                self.errors += 1
            self.last_error = _one_line(f"status: {e}")

    def _hold_still(self, why: str) -> None:
        self._holding = True
        self.controller.reset()
        self._team_ids = []
        self.last_error = f"watchdog: {why}"
        self.log("warning", "watchdog", why)
        z = Decision((0.0, 0.0), (0.0, 0.0), False, 0.0, 0.0, why)
        self._publish_cmd(max(self._last_step_seen, 0), z)

    def run(self) -> int:
        """The control loop; returns the exit code once stopped."""
        cfg = self.cfg
        period = 1.0 / cfg.rate_hz
        next_tick = time.monotonic()
        next_status = time.monotonic() + cfg.status_period_s
        realtime = cfg.mode == "realtime"
        while not self._stop.is_set():
            now = time.monotonic()
            # --- between two steps: brain swaps and their answers
            self._apply_swap()
            while self._answers:
                self._publish_status(self._answers.popleft())
            # --- status, watchdog, exit on silence
            if now >= next_status:
                self._publish_status()
                self._lat.clear()
                self._dec_times = self._dec_times[-1:]
                next_status = now + cfg.status_period_s
            with self._cond:
                last = self._last_pose_t
                if self._restart:
                    self._restart = False
                    self._last_decided = -1
            if last is not None:
                silent = now - last
                if silent > cfg.watchdog_s and not self._holding:
                    self._hold_still(f"no pose for {silent:.1f} s, holding still")
                elif silent <= cfg.watchdog_s and self._holding:
                    self._holding = False
                    self.log("info", "resume", "poses are back")
                if cfg.exit_after_silence_s > 0 and silent > cfg.exit_after_silence_s:
                    self.log("info", "exit", f"world silent for {silent:.1f} s")
                    return 0
            # --- decide, or wait for the next thing to do
            ready = None
            with self._cond:
                if not self._holding:
                    if realtime:
                        if now >= next_tick:
                            ready = self._ready_realtime(now)
                            next_tick += period
                            if next_tick < now:
                                next_tick = now + period
                    else:
                        ready = self._ready_lockstep(now)
                if ready is None:
                    wake = min(next_status, now + 0.05)
                    if realtime:
                        wake = min(wake, next_tick)
                    elif self._col_step > self._last_decided and not self._holding:
                        wake = min(wake, self._col_t0 + cfg.lockstep_deadline_s)
                    if not self._pending and not self._answers:
                        self._cond.wait(max(0.0, wake - time.monotonic()))
                    continue
                self._last_decided = ready[0]
            self._decide(*ready)
        return 0

    def heavy_modules(self) -> list[str]:
        return [m for m in HEAVY_MODULES if m in sys.modules]


# ------------------------------------------------------------------------ CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--swarm", required=True, help="swarm name ([A-Za-z0-9_-]+)")
    parser.add_argument("--id", type=int, required=True, help="this robot's id (>= 0)")
    parser.add_argument(
        "--brain", required=True, help="a brain: path to .onnx (manifest beside it) or rule:assign"
    )
    parser.add_argument(
        "--mode", choices=("lockstep", "realtime"), default="lockstep", help="(default lockstep)"
    )
    parser.add_argument(
        "--rate-hz", type=float, default=None, help="realtime decision rate (default 1/dt = 10)"
    )
    parser.add_argument(
        "--pattern",
        default=None,
        help="target until the swarm's pattern key says otherwise: built-in name or file",
    )
    parser.add_argument(
        "--lockstep-deadline-s",
        type=float,
        default=0.02,
        help="decide step t this long after its first pose even if poses are missing",
    )
    parser.add_argument(
        "--watchdog-s", type=float, default=1.0, help="hold still after this long without poses"
    )
    parser.add_argument(
        "--stale-s", type=float, default=1.0, help="a peer's pose older than this is absent"
    )
    parser.add_argument(
        "--exit-after-silence-s",
        type=float,
        default=0.0,
        help="exit (code 0) once the world has been silent this long (0: never)",
    )
    parser.add_argument("--status-period-s", type=float, default=1.0, help=argparse.SUPPRESS)
    g = parser.add_argument_group("safety filter (ORCA)")
    d = OrcaParams()
    g.add_argument("--safety", choices=("orca", "off"), default="orca", help="(default orca)")
    g.add_argument(
        "--orca-time-horizon-s",
        type=float,
        default=d.time_horizon_s,
        help=f"avoid collisions this far ahead (default {d.time_horizon_s})",
    )
    g.add_argument(
        "--orca-radius-margin-m",
        type=float,
        default=d.radius_margin_m,
        help=f"added to R for the filter (default {d.radius_margin_m})",
    )
    g.add_argument(
        "--orca-max-neighbours",
        type=int,
        default=d.max_neighbours,
        help=f"nearest neighbours considered (default {d.max_neighbours})",
    )
    g.add_argument(
        "--orca-neighbour-dist-m",
        type=float,
        default=d.neighbour_dist_m,
        help=f"neighbours farther are ignored (default {d.neighbour_dist_m})",
    )
    g.add_argument(
        "--orca-keep-right-rad",
        type=float,
        default=d.keep_right_rad,
        help=f"deadlock breaking turn, 0 = plain RVO2 (default {d.keep_right_rad})",
    )
    add_zenoh_arguments(parser)
    lg = parser.add_argument_group("logging")
    lg.add_argument("--json-logs", action="store_true", help="one JSON object per log line")
    lg.add_argument("-v", "--verbose", action="store_true", help="debug events too")


def _check_args(
    args: argparse.Namespace, world: WorldConfig
) -> tuple[RobotConfig, OrcaParams | None]:
    try:
        keys.validate_swarm(args.swarm)
    except ValueError as e:
        raise InputError(str(e)) from None
    if args.id < 0:
        raise InputError(f"--id must be >= 0, got {args.id}")
    rate = args.rate_hz if args.rate_hz is not None else 1.0 / world.dt_s
    for name, v in (
        ("--rate-hz", rate),
        ("--watchdog-s", args.watchdog_s),
        ("--stale-s", args.stale_s),
        ("--status-period-s", args.status_period_s),
        ("--orca-time-horizon-s", args.orca_time_horizon_s),
        ("--orca-neighbour-dist-m", args.orca_neighbour_dist_m),
    ):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v}")
    for name, v in (
        ("--lockstep-deadline-s", args.lockstep_deadline_s),
        ("--exit-after-silence-s", args.exit_after_silence_s),
        ("--orca-radius-margin-m", args.orca_radius_margin_m),
    ):
        if not (math.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be >= 0, got {v}")
    if args.orca_max_neighbours < 1:
        raise InputError("--orca-max-neighbours must be >= 1")
    if args.pattern is not None:
        try:
            make_pattern(args.pattern, 4, world)  # readable and well-formed
        except PatternError as e:
            # a pattern fine for the real team may be too dense for 4: only reject unreadable
            if "closer than 2R" not in str(e):
                raise InputError(str(e)) from None
    safety = (
        None
        if args.safety == "off"
        else OrcaParams(
            time_horizon_s=args.orca_time_horizon_s,
            radius_margin_m=args.orca_radius_margin_m,
            max_neighbours=args.orca_max_neighbours,
            neighbour_dist_m=args.orca_neighbour_dist_m,
            keep_right_rad=args.orca_keep_right_rad,
        )
    )
    cfg = RobotConfig(
        swarm=args.swarm,
        robot_id=args.id,
        mode=args.mode,
        rate_hz=rate,
        lockstep_deadline_s=args.lockstep_deadline_s,
        watchdog_s=args.watchdog_s,
        stale_s=args.stale_s,
        exit_after_silence_s=args.exit_after_silence_s,
        status_period_s=args.status_period_s,
        pattern=args.pattern,
    )
    return cfg, safety


def run(args: argparse.Namespace) -> int:
    world = DEFAULT_WORLD
    log = Log(f"robot {args.id}", args.json_logs, "debug" if args.verbose else "info")
    try:
        cfg, safety = _check_args(args, world)
        brain = load_brain(args.brain, world)
    except (InputError, BrainError) as e:
        print(f"patternrl robot: error: {_one_line(str(e))}", file=sys.stderr)
        return 2
    sys.setswitchinterval(0.001)  # a validating swap thread yields the GIL quickly
    stop = threading.Event()
    robot_ref: list[Robot] = []

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()
        if robot_ref:
            robot_ref[0]._stop.set()

    old_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            session = open_session_from_args(args, "robot", cfg.swarm)
        except ZenohSetupError as e:
            print(f"patternrl robot: error: {e}", file=sys.stderr)
            return 2
        try:
            robot = Robot(cfg, brain, session, world, safety, log)
            robot_ref.append(robot)
            if stop.is_set():
                return 0
            robot.start()
            log(
                "info",
                "start",
                f"swarm {cfg.swarm}, {cfg.mode}, brain {_short(brain.brain_id)} "
                f"({brain.spec.name}), safety {'orca' if safety else 'off'}",
            )
            try:
                code = robot.run()
            finally:
                robot.close()
            heavy = robot.heavy_modules()
            log(
                "info",
                "stop",
                f"after {robot.steps} steps",
                dropped=robot.dropped,
                errors=robot.errors,
                heavy_modules=",".join(heavy) if heavy else "none",
            )
            return code
        finally:
            try:
                session.close()  # type: ignore[no-untyped-call]
            except Exception:
                pass
    except Exception as e:  # unexpected: one line, no traceback
        print(f"patternrl robot: error: {_one_line(f'{type(e).__name__}: {e}')}", file=sys.stderr)
        return 1
    finally:
        for s, h in old_handlers.items():
            signal.signal(s, h)
