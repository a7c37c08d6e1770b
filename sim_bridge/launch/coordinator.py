"""``patternrl coordinate``: a real swarm's coordinator, with no simulated world.

Robots that know where they are (``patternrl robot --ros2 ...``: odometry or motion capture)
publish their own poses on their Zenoh pose keys and decide from each other's. The coordinator
plays what the world plays for a simulated swarm, without owning the robots' positions:

* it follows the live robots (a pose fresher than ``--stale-s``), publishes the pattern of
  each phase at the live team's size on the swarm's ``pattern`` key (again about once a second,
  and as a new version when the team's size changes);
* it judges a phase formed when every live robot is within the world's tolerance of its slot
  (the centred optimal assignment, :func:`runtime.decision.formation.is_formed`), held for
  ``--hold-s``, and goes on to the next pattern; a phase not formed within
  ``--phase-timeout-s`` is logged as not formed;
* with ``--record`` it writes the swarm's traffic and its own events (run, patterns, phases)
  to an MCAP log like a world's (``patternrl replay`` reports it; ``--to-rosbag2`` converts it).

Steps are the robots' (the UTC day's wall clock / dt). Exit codes: 0 when every pattern formed;
1 when one did not or no robots came; 2 on bad input; 130 when interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import signal
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import zenoh

from runtime.decision.formation import is_formed
from runtime.decision.patterns import PatternError, make_pattern, pattern_label
from runtime.errors import InputError
from runtime.net.session import ZenohSetupError, add_zenoh_arguments, open_session_from_args
from runtime.wire import keys
from runtime.wire.messages import MessageError, PatternMsg, decode_pose, encode_pattern
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.recorder import Recorder, check_output

W = DEFAULT_WORLD
DAY_S = 86_400.0


def day_step() -> int:
    """The step of the UTC day's wall clock (what robots on ROS 2 stamp their poses with)."""
    return int((time.time() % DAY_S) / W.dt_s)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--swarm", default="demo", help="swarm name ([A-Za-z0-9_-]+, default demo)")
    p.add_argument("--patterns", default="circle,cross,line,heart",
                   help="the sequence, comma-separated built-in names or files")
    p.add_argument("--robots", type=int, default=2,
                   help="start once this many robots are live (default 2)")
    p.add_argument("--wait-robots-s", type=float, default=60.0,
                   help="give up when they are not live by then (default 60)")
    p.add_argument("--phase-timeout-s", type=float, default=120.0,
                   help="a pattern not formed by then is not formed (default 120)")
    p.add_argument("--hold-s", type=float, default=0.3,
                   help="formed must hold this long (default 0.3)")
    p.add_argument("--stale-s", type=float, default=1.0,
                   help="a robot whose pose is older is not live (default 1)")
    p.add_argument("--record", type=Path, default=None, metavar="RUN.mcap",
                   help="write the swarm's traffic and the phases to this log")
    p.add_argument("--force", action="store_true", help="overwrite --record if it exists")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    add_zenoh_arguments(p)


class Coordinator:
    """The live robots' poses from Zenoh; patterns out; formed judged."""

    def __init__(self, session: zenoh.Session, swarm: str, stale_s: float,
                 rec: Recorder | None) -> None:
        self.session, self.swarm, self.stale_s, self.rec = session, swarm, stale_s, rec
        self.cond = threading.Condition()
        self.poses: dict[int, tuple[float, float, float]] = {}  # rid -> x, y, monotonic s
        self.version = 0
        self._pub = session.declare_publisher(keys.pattern_key(swarm), express=True)
        self._sub = session.declare_subscriber(keys.all_poses(swarm), self._on_pose)
        self._rec_sub = None if rec is None else session.declare_subscriber(
            keys.swarm_root(swarm), self._on_sample, allowed_origin=zenoh.Locality.REMOTE)
        self._payload = b""
        self.sent_s = 0.0

    def close(self) -> None:
        if self._rec_sub is not None:
            self._rec_sub.undeclare()  # type: ignore[no-untyped-call]
        self._sub.undeclare()  # type: ignore[no-untyped-call]
        self._pub.undeclare()  # type: ignore[no-untyped-call]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self.rec is not None:  # everything of the swarm, as it came
            self.rec.write_wire(str(sample.key_expr), sample.payload.to_bytes())

    def _on_pose(self, sample: zenoh.Sample) -> None:
        k = keys.parse_key(str(sample.key_expr))
        try:
            p = decode_pose(sample.payload.to_bytes())
        except MessageError:
            return
        if k is None or k.robot_id != p.robot_id:
            return
        with self.cond:
            self.poses[p.robot_id] = (p.x, p.y, time.monotonic())
            self.cond.notify_all()

    def live(self) -> tuple[list[int], np.ndarray]:
        now = time.monotonic()
        with self.cond:
            fresh = sorted(r for r, (_, _, t) in self.poses.items() if now - t <= self.stale_s)
            xy = np.array([self.poses[r][:2] for r in fresh], dtype=np.float64).reshape(-1, 2)
        return fresh, xy

    def wait(self, pred: Any, timeout: float, stop: threading.Event) -> bool:
        end = time.monotonic() + timeout
        with self.cond:
            while not stop.is_set():
                if pred():
                    return True
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(min(left, 0.1))
        return False

    def publish(self, name: str, n: int, reason: str) -> np.ndarray:
        pts = make_pattern(name, n, W)
        self.version += 1
        self._payload = encode_pattern(PatternMsg(self.version, pattern_label(name), pts,
                                                  W.formed_tol_m))
        self.put()
        self.event("pattern", version=self.version, name=pattern_label(name), n=n,
                   reason=reason, points=np.round(pts, 6).tolist(), formed_tol_m=W.formed_tol_m)
        return pts

    def put(self) -> None:
        self._pub.put(self._payload)
        if self.rec is not None:
            self.rec.write_wire(keys.pattern_key(self.swarm), self._payload)
        self.sent_s = time.monotonic()

    def event(self, kind: str, **fields: Any) -> None:
        if self.rec is not None:
            s = day_step()
            self.rec.event(kind, s, round(s * W.dt_s, 3), **fields)

    def phase(self, index: int, name: str, timeout_s: float, hold_s: float,
              stop: threading.Event) -> dict[str, Any]:
        ids, _ = self.live()
        C = self.publish(name, len(ids), "phase")
        start, t0 = day_step(), time.monotonic()
        self.event("phase_start", phase=index, pattern=pattern_label(name), n=len(ids))
        formed_since: float | None = None
        formed = False
        while not stop.is_set() and time.monotonic() - t0 < timeout_s:
            ids, xy = self.live()
            if len(ids) >= 2 and len(ids) != len(C):
                C = self.publish(name, len(ids), "resize")
                formed_since = None
            elif time.monotonic() - self.sent_s >= 1.0:
                self.put()
            ok = len(ids) >= 2 and len(ids) == len(C) and is_formed(xy, C, W.formed_tol_m)
            now = time.monotonic()
            if not ok:
                formed_since = None
            elif formed_since is None:
                formed_since = now
            elif now - formed_since >= hold_s:
                formed = True
                break
            with self.cond:
                self.cond.wait(0.05)
        end = day_step()
        res = {"index": index, "pattern": pattern_label(name), "n_robots": len(ids),
               "formed": formed, "steps": end - start, "start_step": start, "end_step": end,
               "wall_s": round(time.monotonic() - t0, 3)}
        self.event("phase_end", **res)
        return res


def run(args: argparse.Namespace) -> int:
    def err(msg: str) -> int:
        print(f"patternrl coordinate: error: {msg}", file=sys.stderr)
        return 2

    patterns = [p.strip() for p in str(args.patterns).split(",") if p.strip()]
    try:
        keys.validate_swarm(args.swarm)
        if not patterns:
            raise InputError("--patterns names no pattern")
        for p in patterns:
            make_pattern(p, max(args.robots, 2), W)
        if args.robots < 2:
            raise InputError(f"--robots must be >= 2, got {args.robots}")
        for name in ("wait_robots_s", "phase_timeout_s", "stale_s"):
            v = getattr(args, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"--{name.replace('_', '-')} must be > 0, got {v}")
        if args.record is not None:
            check_output(args.record, args.force)
    except (InputError, PatternError, ValueError) as e:
        return err(str(e))
    try:
        session = open_session_from_args(args, "tool", args.swarm)
    except ZenohSetupError as e:
        return err(str(e))
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    phases: list[dict[str, Any]] = []
    outcome = "done"
    try:
        with contextlib.ExitStack() as stack:
            rec = None
            if args.record is not None:
                rec = stack.enter_context(Recorder(args.record, overwrite=args.force))
            co = Coordinator(session, args.swarm, args.stale_s, rec)
            stack.callback(co.close)
            co.event("run_start", swarm=args.swarm, robots=args.robots, patterns=patterns,
                     mode="realtime", world=asdict(W), coordinator=True)
            print(f"patternrl coordinate: waiting for {args.robots} robots on swarm "
                  f"{args.swarm}", file=sys.stderr, flush=True)
            if not co.wait(lambda: len(co.live()[0]) >= args.robots, args.wait_robots_s, stop):
                outcome = "interrupted" if stop.is_set() else "no robots"
            else:
                for k, name in enumerate(patterns):
                    res = co.phase(k, name, args.phase_timeout_s, args.hold_s, stop)
                    phases.append(res)
                    print(f"patternrl coordinate: {res['pattern']}: "
                          f"{'formed' if res['formed'] else 'NOT formed'} in {res['wall_s']} s "
                          f"with {res['n_robots']} robots", file=sys.stderr, flush=True)
                    if stop.is_set():
                        outcome = "interrupted"
                        break
            co.event("run_end", outcome=outcome, steps=day_step(),
                     formed=[p["formed"] for p in phases])
    finally:
        session.close()  # type: ignore[no-untyped-call]
        for s, h in old.items():
            signal.signal(s, h)
    if args.json:
        print(json.dumps({"outcome": outcome, "phases": phases,
                          "record": str(args.record) if args.record else None}))
    if outcome == "interrupted":
        return 130
    return 0 if outcome == "done" and all(p["formed"] for p in phases) else 1
