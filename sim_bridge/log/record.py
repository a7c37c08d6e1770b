"""``patternrl record``: record a running swarm into an MCAP log, like ``ros2 bag record``.

Subscribes to every key of ``--swarm`` (``patternrl/<swarm>/**``) and to the
robots' liveliness, and writes what comes through the world's own recorder
(:class:`sim_bridge.log.recorder.Recorder`): the same channels and schemas as a
world's log (:mod:`sim_bridge.log.layout`), so ``patternrl replay`` reports it
the same way (phases from the pattern messages on the wire; a robot's arrival or
departure as ``join``/``leave`` events). It works for a simulated swarm and for
real robots alike; ``log_time`` is the wall clock as the samples arrived.

Each key may cost the log only so much per second (:mod:`sim_bridge.log.budget`):
a flood is dropped, counted (the summary line, the ``run_end`` event) and said once
per key (an ``over_budget`` event).

The output is refused if it exists (``--force`` overwrites). Ctrl-C (SIGINT) or
SIGTERM finishes the file (summary and index); so does ``--duration-s``.
Zenoh: the standard options (:func:`runtime.net.session.add_zenoh_arguments`);
by default the recorder connects to the swarm's world on this machine.

A recording that heard nothing of the swarm (no sample on its keys, e.g. the
swarm runs on another port: ``patternrl launch`` prints the flags that reach it)
is not kept: one line says so, the file is removed and the exit code is 1.

Exit codes: 0 when the file is finished; 1 when nothing was heard (no file); 2 on bad
input or when Zenoh cannot open.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
from contextlib import ExitStack
from pathlib import Path
from types import FrameType

import zenoh

from runtime.errors import InputError
from runtime.net.session import (
    ZenohSetupError,
    add_zenoh_arguments,
    open_session_from_args,
    world_endpoint,
)
from runtime.wire import keys
from sim_bridge.log.budget import Budget, KeyBudget
from sim_bridge.log.recorder import Recorder, check_output


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--swarm", default="demo", help="swarm to record ([A-Za-z0-9_-]+, default demo)")
    p.add_argument("--out", type=Path, required=True, metavar="RUN.mcap",
                   help="the MCAP log to write (refused if it exists, unless --force)")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    p.add_argument("--duration-s", type=float, default=0.0,
                   help="stop after this many seconds (default 0: until Ctrl-C)")
    add_zenoh_arguments(p)


class SwarmRecorder:
    """Zenoh samples of one swarm into a :class:`Recorder`, while the ``with`` block lasts."""

    def __init__(self, session: zenoh.Session, swarm: str, rec: Recorder) -> None:
        self.session = session
        self.swarm = swarm
        self.rec = rec
        self.samples = 0
        self.last_step = 0
        self.budget = KeyBudget(self._over_budget)
        """What each key may cost the log per second (:mod:`sim_bridge.log.budget`)."""
        self._lock = threading.Lock()
        self._stack = ExitStack()

    def __enter__(self) -> SwarmRecorder:
        s = self.session
        self.rec.event("run_start", 0, 0.0, swarm=self.swarm, recorder="patternrl record")
        self._stack.enter_context(s.declare_subscriber(keys.swarm_root(self.swarm),
                                                       self._on_sample))
        self._stack.enter_context(s.liveliness().declare_subscriber(
            keys.all_alive(self.swarm), self._on_alive, history=True))
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()
        self.rec.event("run_end", self.last_step, 0.0, outcome="recorded",
                       steps=self.last_step, samples=self.samples,
                       over_budget=self.budget.dropped)

    def _over_budget(self, key: str, budget: Budget) -> None:
        self.rec.event("over_budget", self.last_step, 0.0, key=key,
                       messages_per_s=budget.messages, bytes_per_s=budget.bytes)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        if not self.budget.allow(key, len(payload)):  # a flood: dropped, counted
            return
        k = keys.parse_key(key)
        if k is not None and k.kind == keys.POSE and len(payload) >= 14:
            step = int.from_bytes(payload[6:14], "little")  # the pose's step (wire layout)
            with self._lock:
                if self.last_step < step <= self.last_step + 1000:  # forged steps ignored
                    self.last_step = step
        with self._lock:
            self.samples += 1
        self.rec.write_wire(key, payload)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        k = keys.parse_key(str(sample.key_expr))
        if k is None or k.robot_id is None:
            return
        joined = sample.kind == zenoh.SampleKind.PUT
        self.rec.event("join" if joined else "leave", self.last_step, 0.0, robot=k.robot_id)


def run(args: argparse.Namespace) -> int:
    def err(msg: str) -> int:
        print(f"patternrl record: error: {msg}", file=sys.stderr)
        return 2

    try:
        keys.validate_swarm(args.swarm)
    except ValueError as e:
        return err(str(e))
    if not (math.isfinite(args.duration_s) and args.duration_s >= 0):
        return err(f"--duration-s must be >= 0, got {args.duration_s}")
    try:
        check_output(args.out, args.force)
    except InputError as e:
        return err(str(e))
    try:
        session = open_session_from_args(args, "tool", args.swarm)
    except ZenohSetupError as e:
        return err(str(e))
    stop = threading.Event()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            rec = Recorder(args.out, overwrite=args.force)
        except InputError as e:
            return err(str(e))
        with rec, SwarmRecorder(session, args.swarm, rec) as sr:
            print(f"patternrl record: recording swarm {args.swarm} to {args.out} "
                  "(Ctrl-C to finish)", file=sys.stderr, flush=True)
            stop.wait(args.duration_s or None)
    finally:
        session.close()  # type: ignore[no-untyped-call]
        for s, h in old.items():
            signal.signal(s, h)
    if sr.samples == 0:  # an empty log would read as a swarm that did nothing
        Path(args.out).unlink(missing_ok=True)
        print(f"patternrl record: error: heard nothing from swarm {args.swarm} at "
              f"{_where(args)}: is it running there? (patternrl launch prints the flags that "
              f"reach its swarm); no log written", file=sys.stderr)
        return 1
    over = (f", {sr.budget.dropped} dropped over their key's budget"
            if sr.budget.dropped else "")
    print(f"patternrl record: {sr.samples} samples, {rec.messages_written} messages, "
          f"last step {sr.last_step}{over}: {args.out}", file=sys.stderr)
    return 0


def _where(args: argparse.Namespace) -> str:
    """Where the recorder looked for the swarm, in the user's terms."""
    if args.connect:
        return ", ".join(args.connect)
    try:
        return world_endpoint(args.swarm, args.zenoh_port).split("/", 1)[1]
    except ZenohSetupError:
        return "its default port"
