"""``patternrl sim``: the pymunk world over Zenoh, playing a sequence of patterns.

The world owns the truth (where every robot is) and the clock. Each step it

1. publishes every live robot's :class:`~runtime.messages.Pose` (step, position,
   velocity over the last step, ``n_live``) on ``patternrl/<swarm>/robot/<id>/pose``;
2. collects the robots' :class:`~runtime.messages.Command` for that step:

   * ``lockstep`` (default, reproducible): until every live robot has answered or
     ``--step-deadline-ms`` has passed; a robot that has not answered holds still
     for the step and is counted (``deadline_miss``); an answer that comes late
     is dropped and counted, and nothing ever waits longer than the deadline;
   * ``realtime``: one step every ``1 / --rate-hz`` seconds with each robot's
     latest command (a command more than two steps old is not used: that robot
     holds still, counted);

3. steps the physics (:mod:`sim_bridge.physics`), then measures the formation
   against the current pattern (error under the centred optimal assignment, the
   farthest robot from its slot, min separation, robot pairs that overlapped
   during the step) and records everything (:mod:`sim_bridge.recorder`).

A pattern is **formed** when every robot is within ``world.formed_tol_m`` of its
slot under the centred optimal assignment (:func:`runtime.formation.assign_slots`);
the world then publishes the next pattern of ``--patterns``. A pattern not formed
within ``--max-steps`` is logged as a failure and the sequence goes on. The
current :class:`~runtime.messages.PatternMsg` is republished about once a second
and answered to queries on the pattern key, for robots that join late.

Robots are followed by their liveliness tokens (``patternrl/<swarm>/alive/<id>``):
the world starts once ``--robots`` robots are alive (or ``--wait-robots-s`` has
passed with at least two), places them at seeded starts (uniform in the arena,
pairwise >= ``world.start_separation_m``), and between steps places a robot that
joins at a free seeded spot and removes one that leaves, logging both. The
pattern is then resized to the live count (a new pattern version), which general
and rule brains follow; a paper brain knows one team size and cannot.

Brains (``--brains``): ``none`` leaves the robots' brains alone; ``rule:assign``
or one brain file (``.onnx``, e.g. ``exports/general.onnx``) runs that brain for
every pattern (swapped in once, before the first, where a robot runs another);
a directory of brains (``<stem>.onnx`` + ``<stem>.json`` manifests) makes the
world choose a brain per pattern (by the manifest's ``pattern``, ``observation``
and ``n_robots``; ``--brain-kind`` says which observation to prefer) and, at
every pattern change, swap it into each robot that runs another one, through the
runtime's swap mechanism (:func:`runtime.swap.swap_brain`); every answer is
logged. So paper brains, one per pattern, play a whole sequence.

Exit codes: 0 when every pattern formed; 1 when one did not, or no robots came;
2 on bad input; 130 when interrupted (the log is finished either way).
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
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import zenoh

from runtime import keys
from runtime.brain import RULE_ASSIGN, BrainError, BrainManifest, sidecar_path
from runtime.errors import InputError
from runtime.formation import (
    assign_slots,
    centred,
    collision_pairs,
    lower_bounds,
    min_separation,
)
from runtime.messages import (
    Command,
    MessageError,
    PatternMsg,
    Pose,
    decode_command,
    decode_status,
    encode_pattern,
    encode_pose,
)
from runtime.patterns import PatternError, make_pattern, pattern_label
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from runtime.zenoh_session import ZenohSetupError, add_zenoh_arguments, open_session_from_args
from sim_bridge.physics import PhysicsError, PhysicsWorld, arena_for_patterns, sample_starts
from sim_bridge.recorder import Recorder, scene_update

DEFAULT_PATTERNS = "circle,cross,line,heart"


# ------------------------------------------------------------------------ brains


@dataclass(frozen=True)
class BrainChoice:
    """The brain the world wants running for one pattern."""

    ref: str
    """``rule:assign`` or the path of an ``.onnx`` file."""
    brain_id: str
    kind: str
    """``rule``, ``general`` or ``paper``."""
    label: str
    """What tables print: the file name (or rule) and a short id."""


def rule_choice(ref: str = RULE_ASSIGN) -> BrainChoice:
    return BrainChoice(ref, ref, "rule", ref)


def scan_brains(directory: Path) -> list[tuple[Path, BrainManifest]]:
    """Every brain in ``directory``: (onnx path, manifest) for each readable sidecar."""
    out: list[tuple[Path, BrainManifest]] = []
    for side in sorted(directory.glob("*.json")):
        onnx = side.with_suffix(".onnx")
        if not onnx.is_file() or sidecar_path(onnx) != side:
            continue
        try:
            manifest = BrainManifest.from_json(side.read_text(encoding="utf-8"))
        except (BrainError, OSError, UnicodeDecodeError):
            continue
        out.append((onnx, manifest))
    return out


def choose_brains(
    directory: Path, patterns: list[str], n_robots: int, prefer: str = "general"
) -> tuple[dict[str, BrainChoice], list[str]]:
    """The brain for each pattern from a brains directory, and the patterns with none.

    A brain fits a pattern when its manifest names that pattern (by label), or
    names none and observes ``general`` (any pattern); a paper brain must also
    observe ``n_robots``. Preference: the ``prefer`` kind, then a brain made for
    the pattern over a pattern-free one, then the file name.
    """
    found = scan_brains(directory)
    chosen: dict[str, BrainChoice] = {}
    missing: list[str] = []
    for p in patterns:
        label = pattern_label(p)
        fits = []
        for onnx, m in found:
            obs = m.observation.name
            if m.pattern is not None and pattern_label(m.pattern) != label:
                continue
            if m.pattern is None and obs != "general":
                continue
            if not m.observation.accepts_team(n_robots):
                continue
            fits.append((obs != prefer, m.pattern is None, onnx.name, onnx, m))
        if not fits:
            missing.append(p)
            continue
        *_, onnx, m = min(fits, key=lambda f: f[:3])
        bid = m.brain_id
        chosen[p] = BrainChoice(str(onnx), bid, m.observation.name, f"{onnx.name} ({bid[:8]})")
    return chosen, missing


# ------------------------------------------------------------------------ config


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
    max_steps: int = DEFAULT_WORLD.step_limit
    rate_hz: float = 1.0 / DEFAULT_WORLD.dt_s
    brains: dict[str, BrainChoice] | None = None
    """Brain per pattern; None leaves the robots' brains alone."""
    wait_robots_s: float = 30.0
    swap_timeout_s: float = 15.0
    pattern_republish_s: float = 1.0
    world: WorldConfig = DEFAULT_WORLD


@dataclass
class PhaseResult:
    """How one pattern of the sequence went (also the ``phase_end`` event)."""

    index: int
    pattern: str
    n_robots: int
    formed: bool
    steps: int
    step_limit: int
    lower_bound_steps: int
    travel_m: float
    lower_bound_travel_m: float
    collisions: int
    contacts: int
    min_separation_m: float
    deadline_misses: int
    late_commands: int
    final_error_m: float
    brain: str
    brain_ids: list[str]
    joins: int
    leaves: int
    start_step: int
    end_step: int
    wall_s: float


@dataclass
class RunResult:
    """A whole run: the phases, the outcome and the log path."""

    phases: list[PhaseResult]
    outcome: str
    """``done``, ``interrupted`` or ``no robots``."""
    steps: int
    wall_s: float
    record: str | None
    latencies_ms: list[float] = field(default_factory=list, repr=False)

    @property
    def all_formed(self) -> bool:
        return self.outcome == "done" and all(p.formed for p in self.phases)


@dataclass
class Progress:
    """What a progress line shows, after each step."""

    phase: int
    n_phases: int
    pattern: str
    step: int
    phase_step: int
    formation_error_m: float
    n_live: int
    deadline_misses: int


# ------------------------------------------------------------------------- world


class SimWorld:
    """One run of the world on an open Zenoh session."""

    def __init__(
        self,
        cfg: SimConfig,
        session: zenoh.Session,
        recorder: Recorder | None = None,
        on_progress: Callable[[Progress], None] | None = None,
        log: Callable[[str, bool], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.w = cfg.world
        self.session = session
        self.rec = recorder
        self.on_progress = on_progress
        # log(message, detail): detail lines (joins at the start, swaps) matter less
        self.log = log or (lambda msg, detail: print(f"sim: {msg}", file=sys.stderr, flush=True))
        self.stop_event = threading.Event()
        self.rng = np.random.default_rng(cfg.seed)
        self.step = 0
        self.version = 0
        self.latencies_ms: list[float] = []
        self.decision_us: list[float] = []  # as the robots report them, for benchmarks
        # Time spent in steps (poses out to physics and record done), phase changes left
        # out: wall, and CPU of the world's thread.
        self.stepping_wall_s = 0.0
        self.stepping_cpu_s = 0.0
        self.malformed = 0
        # --- shared with Zenoh callbacks, under self._cond
        self._cond = threading.Condition(threading.Lock())
        self._alive: set[int] = set()
        self._gone: set[int] = set()
        self._membership: queue.SimpleQueue[tuple[str, int]] = queue.SimpleQueue()
        self._collect_step = -1
        self._expect: set[int] = set()
        self._cmds: dict[int, Command] = {}
        self._cmd_t: dict[int, float] = {}
        self._latest: dict[int, Command] = {}
        self._brain_of: dict[int, str] = {}
        self._late = 0
        self._t_publish = 0.0
        # --- world state (main thread)
        patterns_at_n = [make_pattern(p, cfg.robots, self.w) for p in cfg.patterns]
        self.arena_m = arena_for_patterns(patterns_at_n, self.w)
        self.physics = PhysicsWorld(self.arena_m, self.w)
        self._pose_pubs: dict[int, zenoh.Publisher] = {}
        self._prev_pos: dict[int, tuple[float, float]] = {}
        self._pattern: PatternMsg | None = None
        self._pattern_payload = b""
        self._pattern_sent = 0.0
        self._decls: list[Any] = []
        self._removed_since_scene: list[int] = []

    # ------------------------------------------------------------------ events

    def _say(self, msg: str, detail: bool = False) -> None:
        self.log(msg, detail)

    def _event(self, kind: str, **fields: Any) -> None:
        if self.rec is not None:
            self.rec.event(kind, self.step, self.step * self.w.dt_s, **fields)

    # ------------------------------------------------------------------ zenoh

    def open(self) -> None:
        """Declare the world on the session (done by :meth:`run` if not before)."""
        if self._decls:
            return
        s, sw = self.session, self.cfg.swarm
        self._decls.append(s.liveliness().declare_token(keys.alive_key(sw, keys.WORLD_ID)))
        self._pattern_pub = s.declare_publisher(keys.pattern_key(sw), express=True)
        self._decls.append(self._pattern_pub)
        self._decls.append(
            s.declare_subscriber(keys.swarm_root(sw), self._on_sample,
                                 allowed_origin=zenoh.Locality.REMOTE)
        )
        if self.rec is not None:  # brains this session sends (swaps) are on the log too
            self._decls.append(
                s.declare_subscriber(keys.brain_key(sw), self._on_own_brain,
                                     allowed_origin=zenoh.Locality.SESSION_LOCAL)
            )
        self._decls.append(s.declare_queryable(keys.pattern_key(sw), self._on_pattern_query))
        self._decls.append(
            s.liveliness().declare_subscriber(keys.all_alive(sw), self._on_alive, history=True)
        )

    def _close(self) -> None:
        for d in reversed(self._decls + list(self._pose_pubs.values())):
            try:
                d.undeclare()
            except Exception:  # a session already closed: nothing left to undeclare
                pass
        self._decls.clear()
        self._pose_pubs.clear()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        rid = keys.parse_robot_id(str(sample.key_expr))
        if rid is None:
            return
        kind = "join" if sample.kind == zenoh.SampleKind.PUT else "leave"
        with self._cond:
            if kind == "join":
                self._alive.add(rid)
                self._gone.discard(rid)
            else:
                self._alive.discard(rid)
                self._gone.add(rid)
            self._membership.put((kind, rid))
            self._cond.notify_all()

    def _on_own_brain(self, sample: zenoh.Sample) -> None:
        if self.rec is not None:
            self.rec.write_wire(str(sample.key_expr), sample.payload.to_bytes())

    def _on_pattern_query(self, query: zenoh.Query) -> None:
        payload = self._pattern_payload
        if payload:
            try:
                query.reply(keys.pattern_key(self.cfg.swarm), payload)
            except Exception:  # the querier went away
                pass

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        if self.rec is not None:
            self.rec.write_wire(key, payload)
        tail = key.rsplit("/", 1)[-1]
        if tail == "cmd":
            self._on_cmd(key, payload)
        elif tail == "status":
            try:
                st = decode_status(payload)
            except MessageError as e:
                self._malformed(key, str(e))
                return
            with self._cond:
                self._brain_of[st.robot_id] = st.brain_id

    def _malformed(self, key: str, why: str) -> None:
        self.malformed += 1
        if self.malformed <= 100:  # enough to diagnose; the count goes on
            self._event("malformed", key=key, reason=why[:200])

    def _on_cmd(self, key: str, payload: bytes) -> None:
        now = time.monotonic()
        try:
            cmd = decode_command(payload)
        except MessageError as e:
            self._malformed(key, str(e))
            return
        rid = keys.parse_robot_id(key)
        if rid is None or rid != cmd.robot_id:
            self._malformed(key, f"robot_id {cmd.robot_id} on key {key}")
            return
        with self._cond:
            self._brain_of[rid] = cmd.brain_id
            self._latest[rid] = cmd
            if cmd.step == self._collect_step and rid in self._expect:
                if rid not in self._cmds:
                    self._cmds[rid] = cmd
                    self._cmd_t[rid] = now
                    self.decision_us.append(cmd.decision_us)
                    if self._expect - self._gone <= self._cmds.keys():
                        self._cond.notify_all()
            elif cmd.step < self._collect_step and self.cfg.mode == "lockstep":
                self._late += 1

    # ------------------------------------------------------------------ robots

    def _wait_for_robots(self) -> bool:
        deadline = time.monotonic() + self.cfg.wait_robots_s
        with self._cond:
            while len(self._alive) < self.cfg.robots and not self.stop_event.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(min(left, 0.2))
            n = len(self._alive)
        if n < self.cfg.robots:
            self._say(f"{n} of {self.cfg.robots} robots alive after {self.cfg.wait_robots_s:g} s")
        return n >= 2 and not self.stop_event.is_set()

    def _place_start(self) -> None:
        """The robots alive at the start take the seeded starts, in id order."""
        while True:  # the first drain: joins already known
            try:
                self._membership.get_nowait()
            except queue.Empty:
                break
        with self._cond:
            ids = sorted(self._alive)
        starts = sample_starts(max(len(ids), self.cfg.robots), self.arena_m, self.rng, self.w)
        for rid, (x, y) in zip(ids, starts, strict=False):
            self._add(rid, float(x), float(y))

    def _add(self, rid: int, x: float, y: float) -> None:
        self.physics.add_robot(rid, x, y)
        self._pose_pubs[rid] = self.session.declare_publisher(
            keys.pose_key(self.cfg.swarm, rid), express=False
        )
        self._prev_pos[rid] = (x, y)
        self._event("join", robot=rid, x=round(x, 6), y=round(y, 6), n_live=len(self.physics.ids))
        self._say(f"robot {rid} joined at ({x:.2f}, {y:.2f}); {len(self.physics.ids)} live",
                 self.version == 0)

    def _remove(self, rid: int) -> None:
        self.physics.remove_robot(rid)
        pub = self._pose_pubs.pop(rid, None)
        if pub is not None:
            pub.undeclare()  # type: ignore[no-untyped-call]
        self._prev_pos.pop(rid, None)
        self._removed_since_scene.append(rid)
        self._event("leave", robot=rid, n_live=len(self.physics.ids))
        self._say(f"robot {rid} left; {len(self.physics.ids)} live")

    def _apply_membership(self) -> tuple[int, int]:
        """Joins and leaves since the last step: (joined, left)."""
        joined = left = 0
        while True:
            try:
                kind, rid = self._membership.get_nowait()
            except queue.Empty:
                return joined, left
            present = rid in self.physics.ids
            if kind == "join" and not present:
                try:
                    avoid = self.physics.positions()
                    (x, y), = sample_starts(1, self.arena_m, self.rng, self.w, avoid=avoid)
                except PhysicsError as e:
                    self._say(f"robot {rid} cannot join: {e}")
                    continue
                self._add(rid, float(x), float(y))
                joined += 1
            elif kind == "leave" and present:
                self._remove(rid)
                left += 1

    # ------------------------------------------------------------------ brains

    def _swap_brains(self, pattern: str) -> None:
        """Put the pattern's brain into every live robot that runs another one."""
        if self.cfg.brains is None or pattern not in self.cfg.brains:
            return
        choice = self.cfg.brains[pattern]
        with self._cond:
            known = dict(self._brain_of)
        ids = self.physics.ids
        targets = {r for r in ids if known.get(r, "") != choice.brain_id[:64]}
        if not targets:
            return
        from runtime.swap import read_brain, swap_brain

        try:
            manifest_json, onnx_bytes, _ = read_brain(choice.ref)
        except BrainError as e:
            self._say(f"cannot read brain {choice.ref}: {e}")
            self._event("brain_swap", robot=None, brain=choice.label, accepted=False,
                        reason=str(e)[:200])
            return
        self._say(f"swapping {choice.label} into {len(targets)} robot(s) for {pattern}", True)
        answers = swap_brain(self.session, self.cfg.swarm, manifest_json, onnx_bytes,
                             robots=targets, timeout_s=self.cfg.swap_timeout_s, discover_s=2.0)
        for rid, a in sorted(answers.items()):
            reason = a.reason if a.answered else "no answer in time"
            self._event("brain_swap", robot=rid, brain=choice.label, brain_id=choice.brain_id,
                        old_brain_id=a.old_brain, accepted=a.accepted and a.answered,
                        reason=reason)
            if a.accepted and a.answered:
                with self._cond:
                    self._brain_of[rid] = a.new_brain
            else:
                self._say(f"robot {rid} did not take {choice.label}: {reason}")

    # ------------------------------------------------------------------ pattern

    def _publish_pattern(self, name: str, reason: str) -> Array:
        n = len(self.physics.ids)
        pts = make_pattern(name, n, self.w)
        self.version += 1
        msg = PatternMsg(self.version, pattern_label(name), pts, self.w.formed_tol_m)
        self._pattern = msg
        self._pattern_payload = encode_pattern(msg)
        self._send_pattern()
        self._event("pattern", version=self.version, name=msg.name, n=n, reason=reason,
                    points=np.round(pts, 6).tolist(), formed_tol_m=self.w.formed_tol_m)
        return pts

    def _send_pattern(self) -> None:
        self._pattern_pub.put(self._pattern_payload)
        if self.rec is not None:
            self.rec.write_wire(keys.pattern_key(self.cfg.swarm), self._pattern_payload)
        self._pattern_sent = time.monotonic()

    # ------------------------------------------------------------------ one step

    def _publish_poses(self, pos: Array) -> None:
        ids = self.physics.ids
        n = len(ids)
        t = self.step * self.w.dt_s
        inv_dt = 1.0 / self.w.dt_s
        sw = self.cfg.swarm
        for k, rid in enumerate(ids):
            x, y = float(pos[k, 0]), float(pos[k, 1])
            px, py = self._prev_pos.get(rid, (x, y))
            payload = encode_pose(Pose(rid, self.step, t, x, y, (x - px) * inv_dt,
                                       (y - py) * inv_dt, n))
            self._pose_pubs[rid].put(payload)
            if self.rec is not None:
                self.rec.write_wire(keys.pose_key(sw, rid), payload)

    def _exchange(self, pos: Array, first: bool) -> tuple[Array, list[int]]:
        """Publish poses, collect commands: (velocities in ids order, robots that missed)."""
        ids = self.physics.ids
        lockstep = self.cfg.mode == "lockstep"
        with self._cond:
            self._collect_step = self.step
            self._expect = set(ids)
            self._cmds = {}
            self._cmd_t = {}
        t0 = time.monotonic()
        self._publish_poses(pos)
        self._t_publish = t0
        if lockstep:
            wait_s = (self.cfg.first_step_deadline_ms if first else self.cfg.step_deadline_ms)
            deadline = t0 + wait_s / 1000.0
        else:
            deadline = t0 + 1.0 / self.cfg.rate_hz
        with self._cond:
            while not self.stop_event.is_set():
                if lockstep and self._expect - self._gone <= self._cmds.keys():
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            cmds = dict(self._cmds)
            arrived = dict(self._cmd_t)
            latest = dict(self._latest)
            self._collect_step = -1
        self.latencies_ms.extend((t - t0) * 1000.0 for t in arrived.values())
        v = np.zeros((len(ids), 2))
        missed: list[int] = []
        for k, rid in enumerate(ids):
            cmd = cmds.get(rid)
            if cmd is None and not lockstep:
                c = latest.get(rid)
                cmd = c if c is not None and c.step >= self.step - 2 else None
            if cmd is None:
                missed.append(rid)
            else:
                v[k] = (cmd.vx, cmd.vy)
        return v, missed

    # ------------------------------------------------------------------ phases

    def _measure(self, pos: Array, C: Array) -> tuple[float, float]:
        """(formation error, farthest robot from its slot) in metres.

        The centred optimal assignment (formation.assign_slots, no hysteresis): the
        error is its RMS slot distance, "formed" is its largest within tolerance.
        """
        slots = assign_slots(pos, C)
        d = np.linalg.norm(centred(pos) - centred(C)[slots], axis=1)
        return float(np.sqrt(np.mean(d * d))), float(d.max())

    def _run_phase(self, index: int, name: str) -> PhaseResult:
        cfg, w = self.cfg, self.w
        t_start = time.monotonic()
        self._swap_brains(name)
        C = self._publish_pattern(name, "phase")
        pos = self.physics.positions()
        lb_travel, lb_steps = lower_bounds(pos, C, w.v_max_mps, w.dt_s)
        choice = cfg.brains.get(name) if cfg.brains else None
        self._event("phase_start", phase=index, pattern=pattern_label(name),
                    n=len(self.physics.ids), lower_bound_steps=lb_steps,
                    lower_bound_travel_m=round(lb_travel, 6),
                    brain=choice.label if choice else "robots' own")
        self._say(f"pattern {index + 1}/{len(cfg.patterns)}: {pattern_label(name)} with "
                 f"{len(self.physics.ids)} robots (lower bound {lb_steps} steps)", True)
        start_step = self.step
        phase_step, travel = 0, 0.0
        collisions = contacts = misses = joins = leaves = 0
        late0 = self._late
        min_sep = math.inf
        brain_ids: set[str] = set()
        colliding: set[tuple[int, int]] = set()
        err, far = self._measure(pos, C)
        formed = far <= w.formed_tol_m
        while not formed and phase_step < cfg.max_steps and not self.stop_event.is_set():
            j, lv = self._apply_membership()
            if j or lv:
                joins += j
                leaves += lv
                if len(self.physics.ids) < 2:
                    self._say("fewer than 2 robots left: the phase cannot go on")
                    break
                C = self._publish_pattern(name, "resize")
            elif time.monotonic() - self._pattern_sent >= cfg.pattern_republish_s:
                self._send_pattern()
            ids = list(self.physics.ids)
            pos = self.physics.positions()
            t_step = time.monotonic()
            cpu_step = time.thread_time()
            v, missed = self._exchange(pos, first=self.step == 0 or bool(j))
            if self.stop_event.is_set():
                break
            res = self.physics.step(v)
            self._prev_pos = {rid: (float(x), float(y)) for rid, (x, y) in zip(ids, pos,
                                                                               strict=True)}
            new_pos = res.positions
            self.step += 1
            phase_step += 1
            # --- measures
            travel += float(np.linalg.norm(new_pos - pos, axis=1).sum())
            pairs = {(ids[a], ids[b]) for a, b in collision_pairs(pos, new_pos, w)}
            new_pairs = sorted(pairs - colliding)
            colliding = pairs
            collisions += len(new_pairs)
            contacts += len(res.new_contacts)
            misses += len(missed)
            sep = float(min_separation(new_pos)) if len(ids) > 1 else math.inf
            min_sep = min(min_sep, sep)
            err, far = self._measure(new_pos, C)
            formed = far <= w.formed_tol_m
            with self._cond:
                brain_ids.update(self._brain_of.get(r, "") for r in ids)
            if new_pairs:
                self._event("collision", pairs=[list(p) for p in new_pairs])
            if res.new_contacts:
                self._event("contact", pairs=[list(p) for p in res.new_contacts])
            if missed:  # the step those robots did not answer in time
                self._event("deadline_miss", robots=missed, for_step=self.step - 1)
            self._record_step(index, name, phase_step, ids, new_pos, C, err, far, sep,
                              len(pairs), len(res.new_contacts), len(missed), t_step)
            self.stepping_wall_s += time.monotonic() - t_step
            self.stepping_cpu_s += time.thread_time() - cpu_step
            if self.on_progress is not None:
                self.on_progress(Progress(index, len(cfg.patterns), pattern_label(name),
                                          self.step, phase_step, err, len(ids), misses))
        seen = sorted(b for b in brain_ids if b)
        if choice is None:  # say what the robots ran
            brain = ", ".join(b if b.startswith("rule:") else b[:8] for b in seen) or "unknown"
        elif any(b != choice.brain_id[:64] for b in seen):
            brain = f"{choice.label} (not in every robot)"
        else:
            brain = choice.label
        result = PhaseResult(
            index=index, pattern=pattern_label(name), n_robots=len(self.physics.ids),
            formed=bool(formed), steps=phase_step, step_limit=cfg.max_steps,
            lower_bound_steps=int(lb_steps), travel_m=round(travel, 6),
            lower_bound_travel_m=round(lb_travel, 6), collisions=collisions, contacts=contacts,
            min_separation_m=round(min_sep, 6) if math.isfinite(min_sep) else -1.0,
            deadline_misses=misses, late_commands=self._late - late0,
            final_error_m=round(err, 6), brain=brain, brain_ids=seen, joins=joins, leaves=leaves,
            start_step=start_step, end_step=self.step,
            wall_s=round(time.monotonic() - t_start, 3),
        )
        self._event("phase_end", **asdict(result))
        verdict = "formed" if formed else "NOT formed"
        self._say(f"{pattern_label(name)}: {verdict} in {phase_step} steps "
                 f"(lower bound {lb_steps}), error {err:.3f} m")
        return result

    def _record_step(self, phase: int, name: str, phase_step: int, ids: list[int], pos: Array,
                     C: Array, err: float, far: float, sep: float, n_coll: int, n_contacts: int,
                     n_missed: int, t_step: float) -> None:
        if self.rec is None:
            return
        now_ns = time.time_ns()
        self.rec.metrics({
            "step": self.step, "time_s": round(self.step * self.w.dt_s, 6), "phase": phase,
            "pattern": pattern_label(name), "pattern_version": self.version,
            "phase_step": phase_step, "n_live": len(ids),
            "formation_error_m": round(err, 6), "max_slot_distance_m": round(far, 6),
            "min_separation_m": round(sep, 6) if math.isfinite(sep) else -1.0,
            "collisions": n_coll, "contacts": n_contacts, "deadline_misses": n_missed,
            "wall_ms": round((time.monotonic() - t_step) * 1000.0, 3),
        }, now_ns)
        targets = centred(C) + pos.mean(axis=0)
        robots = [(rid, float(x), float(y)) for rid, (x, y) in zip(ids, pos, strict=True)]
        self.rec.scene(scene_update(now_ns, robots, targets, self._removed_since_scene,
                                    self.arena_m, self.w), now_ns)
        self._removed_since_scene = []

    # ------------------------------------------------------------------ run

    def run(self) -> RunResult:
        """Wait for the robots, play every pattern, finish; never raises for a robot's fault."""
        cfg = self.cfg
        t0 = time.monotonic()
        phases: list[PhaseResult] = []
        outcome = "done"
        self.open()
        try:
            self._event("run_start", swarm=cfg.swarm, robots=cfg.robots, patterns=cfg.patterns,
                        mode=cfg.mode, seed=cfg.seed, step_deadline_ms=cfg.step_deadline_ms,
                        max_steps=cfg.max_steps, rate_hz=cfg.rate_hz, arena_m=self.arena_m,
                        world=asdict(self.w),
                        brains={k: asdict(v) for k, v in (cfg.brains or {}).items()})
            if not self._wait_for_robots():
                outcome = "interrupted" if self.stop_event.is_set() else "no robots"
            else:
                self._place_start()
                for k, name in enumerate(cfg.patterns):
                    if self.stop_event.is_set():
                        break
                    phases.append(self._run_phase(k, name))
                    if len(self.physics.ids) < 2:
                        outcome = "no robots"
                        break
                if self.stop_event.is_set():
                    outcome = "interrupted"
                if self.physics.ids:  # the final state, on the wire and on the log
                    with self._cond:
                        self._collect_step = -1
                    self._publish_poses(self.physics.positions())
        finally:
            wall = time.monotonic() - t0
            self._event("run_end", outcome=outcome, steps=self.step, wall_s=round(wall, 3),
                        formed=[p.formed for p in phases], malformed=self.malformed,
                        contacts_total=self.physics.contacts_total)
            self._close()
        return RunResult(phases, outcome, self.step, round(wall, 3),
                         str(self.rec.path) if self.rec else None, self.latencies_ms)


# --------------------------------------------------------------------------- CLI


def add_world_arguments(p: argparse.ArgumentParser, record_help: str = "write the MCAP log here"
                        ) -> None:
    """Options the world shares with ``patternrl launch``."""
    p.add_argument("--robots", type=int, default=10, help="team size N (default 10)")
    p.add_argument("--patterns", default=DEFAULT_PATTERNS,
                   help=f"comma-separated, built-ins or files (default {DEFAULT_PATTERNS})")
    p.add_argument("--record", type=Path, default=None, metavar="RUN.mcap", help=record_help)
    p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                   help="lockstep: wait for every command (reproducible); realtime: fixed rate")
    p.add_argument("--seed", type=int, default=0, help="seed of the start positions (default 0)")
    p.add_argument("--step-deadline-ms", type=float, default=250.0,
                   help="lockstep: a robot not answered by then holds still (default 250)")
    p.add_argument("--max-steps", type=int, default=DEFAULT_WORLD.step_limit,
                   help=f"step limit per pattern (default {DEFAULT_WORLD.step_limit})")
    p.add_argument("--rate-hz", type=float, default=1.0 / DEFAULT_WORLD.dt_s,
                   help="realtime step rate (default 1/dt = 10)")
    p.add_argument("--brain-kind", choices=("general", "paper"), default="general",
                   help="with a brains directory, which observation to prefer (default general)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--swarm", default="demo", help="swarm name ([A-Za-z0-9_-]+, default demo)")
    add_world_arguments(p)
    p.add_argument("--brains", default="none",
                   help="none (robots keep theirs), rule:assign, a brain file (.onnx: one brain "
                        "for every pattern), or a directory of brains: the world swaps each "
                        "pattern's brain in at every pattern change")
    p.add_argument("--wait-robots-s", type=float, default=30.0,
                   help="start when --robots are alive, or after this long with >= 2")
    add_zenoh_arguments(p)


def config_from_args(args: argparse.Namespace, brains: dict[str, BrainChoice] | None) -> SimConfig:
    """Check the world's options; raises :class:`InputError` with a one-line reason."""
    try:
        keys.validate_swarm(args.swarm)
    except ValueError as e:
        raise InputError(str(e)) from None
    if args.robots < 2:
        raise InputError(f"--robots must be >= 2, got {args.robots}")
    patterns = [p.strip() for p in str(args.patterns).split(",") if p.strip()]
    if not patterns:
        raise InputError("--patterns names no pattern")
    for p in patterns:
        try:
            make_pattern(p, args.robots)
        except PatternError as e:
            raise InputError(str(e)) from None
    for name in ("step_deadline_ms", "rate_hz"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"--{name.replace('_', '-')} must be > 0, got {v}")
    if args.max_steps < 1:
        raise InputError(f"--max-steps must be >= 1, got {args.max_steps}")
    return SimConfig(
        swarm=args.swarm, robots=args.robots, patterns=patterns, mode=args.mode, seed=args.seed,
        step_deadline_ms=args.step_deadline_ms, max_steps=args.max_steps, rate_hz=args.rate_hz,
        brains=brains, wait_robots_s=getattr(args, "wait_robots_s", 30.0),
    )


def file_choice(path: str | Path, n_robots: int) -> BrainChoice:
    """One brain file (``.onnx``, manifest beside it or inside) as a choice for any pattern.

    Raises :class:`InputError` when the file or its manifest cannot be read, or when
    its observation cannot drive ``n_robots`` (a paper brain made for another n).
    """
    from runtime.swap import read_brain

    try:
        manifest_json, _, brain_id = read_brain(str(path))
        m = BrainManifest.from_json(manifest_json)
    except BrainError as e:
        raise InputError(f"--brains {path}: {e}") from None
    if not m.observation.accepts_team(n_robots):
        raise InputError(f"--brains {path}: the brain reads the '{m.observation.name}' "
                         f"observation of {m.observation.n_robots} robots, not {n_robots}")
    name = Path(path).name
    return BrainChoice(str(path), brain_id, m.observation.name, f"{name} ({brain_id[:8]})")


def brains_from_arg(value: str, patterns: list[str], n: int, prefer: str
                    ) -> dict[str, BrainChoice] | None:
    """``none`` -> None; ``rule:...`` -> that rule for every pattern; a brain file (``.onnx``)
    -> that brain for every pattern; a directory -> scan it."""
    if value == "none":
        return None
    if value.startswith("rule:"):
        if value != RULE_ASSIGN:
            raise InputError(f"unknown rule brain '{value}' (known: {RULE_ASSIGN})")
        return {p: rule_choice(value) for p in patterns}
    d = Path(value)
    if d.is_file():
        choice = file_choice(d, n)
        return {p: choice for p in patterns}
    if not d.is_dir():
        raise InputError(f"--brains {value}: not a directory, a brain file, 'rule:assign' "
                         "or 'none'")
    chosen, missing = choose_brains(d, patterns, n, prefer)
    if missing:
        raise InputError(f"--brains {value} has no brain for {', '.join(missing)} with {n} robots")
    return chosen


def result_dict(res: RunResult) -> dict[str, Any]:
    return {"outcome": res.outcome, "all_formed": res.all_formed, "steps": res.steps,
            "wall_s": res.wall_s, "record": res.record,
            "phases": [asdict(p) for p in res.phases]}


def run(args: argparse.Namespace) -> int:
    patterns = [p.strip() for p in str(args.patterns).split(",") if p.strip()]
    try:
        brains = brains_from_arg(args.brains, patterns, args.robots, args.brain_kind)
        cfg = config_from_args(args, brains)
    except InputError as e:
        print(f"patternrl sim: error: {e}", file=sys.stderr)
        return 2
    try:
        session = open_session_from_args(args, "world", cfg.swarm)
    except ZenohSetupError as e:
        print(f"patternrl sim: error: {e}", file=sys.stderr)
        return 2
    rec = Recorder(args.record) if args.record is not None else None
    world = SimWorld(cfg, session, rec)

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        world.stop_event.set()
        with world._cond:
            world._cond.notify_all()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        res = world.run()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if rec is not None:
            rec.close()
        session.close()  # type: ignore[no-untyped-call]
    if args.json:
        print(json.dumps(result_dict(res)))
    else:
        for p in res.phases:
            print(f"{p.pattern:<10} {'formed' if p.formed else 'NOT formed':<10} "
                  f"{p.steps:>4} steps (lower bound {p.lower_bound_steps}), "
                  f"travel {p.travel_m:.2f} m (lower bound {p.lower_bound_travel_m:.2f}), "
                  f"{p.collisions} collisions, min sep {p.min_separation_m:.3f} m, "
                  f"{p.deadline_misses} deadline misses")
        print(f"{res.outcome}: {res.steps} steps in {res.wall_s:.1f} s"
              + (f", log {res.record}" if res.record else ""))
    if res.outcome == "interrupted":
        return 130
    return 0 if res.all_formed else 1
