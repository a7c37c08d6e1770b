"""Messages per second that ``patternrl replay`` reads and analyses (goal: >= 100 k messages/s).

The log: 10,000 steps of 20 robots (``--steps``, ``--robots``), written through the
real recorder API (:class:`sim_bridge.log.recorder.Recorder`) with synthetic motion, so
it takes seconds to make instead of a real run's minutes. Per step, as the world
writes them: every robot's pose and command, one ``/world/metrics`` and one
``/world/scene`` (a full ``foxglove.SceneUpdate``); a status per robot every 10
steps; the world's events (run_start, joins, pattern, phase_start, phase_end,
run_end) and the pattern on the wire. Phases cycle through the built-in patterns;
in each, the robots drive straight to their slots (the pattern placed on the
team's centroid) and arrive after ``--phase-steps`` steps, so the log has
``steps / phase-steps`` phases (default 400: every phase as long as the world's
step limit, 25 phases).

Rows, each the median of ``--repeats`` runs over the same file:

* ``mcap NonSeekingReader``: mcap's own reader iterating every message (reference);
* ``log_file.iter_messages``: the replay's reader alone (:mod:`sim_bridge.log.file`);
* ``read_log``: reading and decoding (poses, commands, events, metrics columns;
  :mod:`sim_bridge.log.reader`);
* ``read_log + analyse``: the whole report, every figure recomputed
  (:mod:`sim_bridge.log.report`), the goal row;
* ``of which lower bounds``: the part of that spent in ``runtime.decision.formation.lower_bounds``
  (one call per phase, independent of the message count), from the same runs.

``x mcap`` is each row's speed over mcap's reader in the same run: the figure to
compare across machines and load (the issue quotes that reader at 248 k/s).

The log is in today's layout (protobuf: per pose also a Foxglove ``PoseInFrame``,
per step a ``/tf``), or with ``--layout wire`` in the layout of old logs, so the
two readers compare side by side.

Usage: ``python benchmarks/replay_speed.py [--steps 10000] [--robots 20] [--layout protobuf|wire]
[--json]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from runtime.decision.formation import assign_slots, centred
from runtime.decision.patterns import make_pattern
from runtime.wire import keys
from runtime.wire.messages import (
    Command,
    PatternMsg,
    Pose,
    Status,
    encode_command,
    encode_pattern,
    encode_pose,
    encode_status,
)
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.live.scene import scene_update
from sim_bridge.log.file import iter_messages
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder
from sim_bridge.log.report import analyse

PATTERNS = ("circle", "line", "cross", "heart", "triangle")
GOAL_MSGS_PER_S = 100_000.0


def write_log(path: Path, steps: int, n: int, phase_steps: int, seed: int = 0,
              layout: str = "protobuf") -> int:
    """A synthetic run through the recorder API; returns the number of messages.

    ``layout`` "wire" writes the layout of old logs (payloads as ``patternrl-wire``).
    """
    w = DEFAULT_WORLD
    rng = np.random.default_rng(seed)
    swarm = "bench"
    t0 = 1_700_000_000_000_000_000
    dt_ns = int(w.dt_s * 1e9)
    pos = rng.uniform(1.0, 9.0, (n, 2))
    with Recorder(path, flush_period_s=1e9, wire_layout=layout == "wire") as rec:
        rec.event("run_start", 0, 0.0, swarm=swarm, robots=n, patterns=list(PATTERNS),
                  mode="lockstep", seed=seed, world=asdict(w))
        for rid in range(n):
            rec.event("join", 0, 0.0, robot=rid, x=float(pos[rid, 0]), y=float(pos[rid, 1]),
                      n_live=rid + 1)
        step, phase, version = 0, 0, 0
        while step < steps:
            name = PATTERNS[phase % len(PATTERNS)]
            C = make_pattern(name, n, w)
            version += 1
            msg = PatternMsg(version, name, C, w.formed_tol_m)
            rec.write_wire(keys.pattern_key(swarm), encode_pattern(msg), t0 + step * dt_ns)
            rec.event("pattern", step, step * w.dt_s, version=version, name=name, n=n,
                      reason="phase", points=np.round(C, 6).tolist(), formed_tol_m=w.formed_tol_m)
            rec.event("phase_start", step, step * w.dt_s, phase=phase, pattern=name, n=n)
            slots = assign_slots(pos, C)
            goal = centred(C)[slots] + pos.mean(axis=0)
            start, length = pos.copy(), min(phase_steps, steps - step)
            for k in range(1, length + 1):
                t = t0 + step * dt_ns
                new = start + (goal - start) * (k / length)
                for rid in range(n):
                    x, y = float(pos[rid, 0]), float(pos[rid, 1])
                    v = (new[rid] - pos[rid]) / w.dt_s
                    rec.write_wire(keys.pose_key(swarm, rid), encode_pose(
                        Pose(rid, step, step * w.dt_s, x, y, float(v[0]), float(v[1]), n)), t + rid)
                for rid in range(n):
                    v = (new[rid] - pos[rid]) / w.dt_s
                    rec.write_wire(keys.cmd_key(swarm, rid), encode_command(Command(
                        rid, step, float(v[0]), float(v[1]), "rule:assign", False, 0.0, 20.0)),
                        t + 1000 + rid)
                if step % 10 == 0:
                    for rid in range(n):
                        rec.write_wire(keys.status_key(swarm, rid), encode_status(Status(
                            rid, step, "rule:assign", 20.0, 40.0, 0.1, 0, 0, 0, "", step * 0.1)),
                            t + 2000 + rid)
                pos = new
                step += 1
                rec.metrics({"step": step, "time_s": step * w.dt_s, "phase": phase,
                             "pattern": name, "n_live": n, "formation_error_m": 0.0,
                             "min_separation_m": 0.0}, t + 3000)
                rec.scene(scene_update(t + 3000, [(r, float(x), float(y)) for r, (x, y) in
                                                  enumerate(pos)], goal, (), w.arena_m, w),
                          t + 3000)
            rec.event("phase_end", step, step * w.dt_s, index=phase, pattern=name, formed=True,
                      steps=length, start_step=step - length, end_step=step)
            phase += 1
        for rid in range(n):  # the final poses, as the world publishes them
            rec.write_wire(keys.pose_key(swarm, rid), encode_pose(Pose(
                rid, step, step * w.dt_s, float(pos[rid, 0]), float(pos[rid, 1]), 0.0, 0.0, n)),
                t0 + step * dt_ns + rid)
        rec.event("run_end", step, step * w.dt_s, outcome="done", steps=step)
    return rec.messages_written  # after close: the last step's /tf is written then


@dataclass(frozen=True)
class Row:
    what: str
    seconds: float
    messages: int
    msgs_per_s: float
    x_mcap: float
    """speed relative to mcap's own reader in the same run"""


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--phase-steps", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--log", type=Path, default=None,
                    help="where to write the log (default: a temporary file, removed after)")
    ap.add_argument("--reuse", action="store_true",
                    help="with --log: read that file if it exists instead of writing it again")
    ap.add_argument("--layout", choices=("protobuf", "wire"), default="protobuf",
                    help="today's layout, or the old one (patternrl-wire payloads)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        path = args.log if args.log is not None else Path(tmp) / "bench.mcap"
        t = time.perf_counter()
        if args.reuse and path.is_file():
            total = sum(1 for _ in iter_messages(path))
        else:
            total = write_log(path, args.steps, args.robots, args.phase_steps,
                              layout=args.layout)
        write_s = time.perf_counter() - t

        def mcap_only() -> None:
            from mcap.reader import NonSeekingReader

            with open(path, "rb") as f:
                for _ in NonSeekingReader(f, record_size_limit=256 << 20).iter_messages(
                        log_time_order=False):
                    pass

        def reader_only() -> None:
            for _ in iter_messages(path):
                pass

        lb_runs: list[float] = []

        def full() -> None:
            rep = analyse(read_log(path))
            lb_runs.append(rep.timing["lower_bounds_s"])

        data = read_log(path)  # warm-up, and the facts
        report = analyse(data)
        assert report.messages == total, (report.messages, total)
        times = {}
        for what, fn in (("mcap NonSeekingReader", mcap_only),
                         ("log_file.iter_messages", reader_only),
                         ("read_log", lambda: read_log(path)),
                         ("read_log + analyse", full)):
            times[what] = _median_time(fn, args.repeats)
        times[f"of which lower bounds ({len(report.phases)} phases)"] = statistics.median(lb_runs)
        ref = times["mcap NonSeekingReader"]
        rows = [Row(what, s, total, total / s, ref / s) for what, s in times.items()]
        size = path.stat().st_size
    goal_row = rows[3]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    out = {
        "steps": args.steps, "robots": args.robots, "phases": len(report.phases),
        "messages": total, "file_bytes": size, "write_s": round(write_s, 3),
        "repeats": args.repeats, "cpus": os.cpu_count(), "load_1min": round(load, 2),
        "goal_msgs_per_s": GOAL_MSGS_PER_S, "goal_met": goal_row.msgs_per_s >= GOAL_MSGS_PER_S,
        "rows": [asdict(r) | {"msgs_per_s": round(r.msgs_per_s), "x_mcap": round(r.x_mcap, 2)}
                 for r in rows],
    }
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    made = "reused" if args.reuse and args.log is not None else f"written in {write_s:.1f} s"
    print(f"replay speed: {args.steps} steps x {args.robots} robots, {len(report.phases)} phases, "
          f"{total} messages, {size / 1e6:.1f} MB ({made})")
    print(f"median of {args.repeats}; {os.cpu_count()} CPUs, 1-min load average {load:.2f}")
    hdr = f"{'what':<36} {'seconds':>8} {'messages/s':>12} {'x mcap':>7}"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        if r.what.startswith("of which"):
            share = r.seconds / rows[3].seconds
            print(f"{r.what:<36} {r.seconds:>8.3f} {f'({share:.0%} of the row above)':>20}")
        else:
            print(f"{r.what:<36} {r.seconds:>8.3f} {r.msgs_per_s:>12,.0f} {r.x_mcap:>7.2f}")
    verdict = "met" if out["goal_met"] else "NOT met"
    print(f"goal >= {GOAL_MSGS_PER_S:,.0f} messages/s read and analysed: {verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
