"""What recording costs the world per step, on its stepping path and in all, with and without
the recorder's writer thread.

Per step, at N robots, the benchmark does what the world process does with its log, without
Zenoh: the step's poses (one ``PoseBatch``, logged as N per-robot poses, their Foxglove
views and the step's ``/tf``), N commands (as Zenoh's receive callbacks hand them to the
recorder), the step's metrics row and its Foxglove scene (``WorldLog.record_step``), plus the
physics step and the formation measures that do not depend on the log. Rows:

* ``log=off``: no recorder (the physics and the measures alone);
* ``log=inline``: ``Recorder(threaded=False)``, as before: everything on the caller's thread;
* ``log=thread``: ``Recorder(threaded=True)``, what ``sim`` and ``launch`` use now: the
  caller only stamps and queues; a writer thread writes.

For each: the caller's CPU per step (``time.thread_time``: what the stepping thread and the
receive callbacks spend) and the process's CPU per step (``time.process_time``: the writer
included, measured after ``close`` has written everything), medians over ``--repeats``.
TLS and the router are not in it (they are Zenoh's, in its own threads and processes); see
``benchmarks/tls_cost.py`` and ``benchmarks/swarm_scale.py`` for the whole swarm.

    .venv/bin/python benchmarks/world_record_cost.py [--robots 100 200] [--steps 200] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.decision.patterns import make_pattern  # noqa: E402 -- after the path set-up above
from runtime.wire import keys  # noqa: E402
from runtime.wire.messages import Command, encode_command  # noqa: E402
from runtime.wire.pose_batch import PoseBatch, encode_poses  # noqa: E402
from runtime.world_config import DEFAULT_WORLD  # noqa: E402
from sim_bridge.log.recorder import Recorder  # noqa: E402
from sim_bridge.world.phase_tally import PhaseTally  # noqa: E402
from sim_bridge.world.physics import PhysicsWorld, arena_for_patterns, sample_starts  # noqa: E402
from sim_bridge.world.world_log import WorldLog  # noqa: E402

W = DEFAULT_WORLD


def run(n: int, steps: int, log: str, tmp: Path) -> dict[str, float]:
    rng = np.random.default_rng(0)
    C = make_pattern("circle", n, W)
    arena = arena_for_patterns([C], W)
    phys = PhysicsWorld(arena, W)
    for rid, (x, y) in enumerate(sample_starts(n, arena, rng, W).tolist()):
        phys.add_robot(rid, x, y)
    rec = None if log == "off" else Recorder(tmp / f"{log}-{n}.mcap", threaded=log == "thread")
    step = 0
    journal = WorldLog(rec, W, arena, lambda m, d: None, lambda: step)
    tally = PhaseTally()
    ids = list(phys.ids)
    swarm = "bench"
    cmd_keys = [keys.cmd_key(swarm, r) for r in ids]
    pkey = keys.poses_key(swarm)
    t0, p0 = time.thread_time(), time.process_time()
    for _ in range(steps):
        pos = phys.positions()
        if rec is not None:
            rec.write_wire(pkey, encode_poses(PoseBatch(step, step * W.dt_s, ids, pos,
                                                        np.zeros_like(pos))))
        v = np.clip((C - C.mean(0) + pos.mean(0) - pos) / W.dt_s, -0.7, 0.7)
        if rec is not None:  # the commands, as the receive callbacks hand them over
            for rid, key in enumerate(cmd_keys):
                rec.write_wire(key, encode_command(Command(rid, step, float(v[rid, 0]),
                                                           float(v[rid, 1]), "rule:assign",
                                                           False, 0.0, 10.0)))
        res = phys.step(v)
        step += 1
        m = tally.step(ids, pos, res.positions, C, res.new_contacts, [], W)
        journal.record_step(0, "circle", 1, step, ids, res.positions, C, m, time.monotonic())
    caller = time.thread_time() - t0
    if rec is not None:
        rec.close()
    total = time.process_time() - p0
    dropped = rec.dropped if rec is not None else 0
    return {"caller_ms_per_step": 1000.0 * caller / steps,
            "process_ms_per_step": 1000.0 * total / steps, "dropped": dropped}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[100, 200])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as d:
        for n in args.robots:
            for log in ("off", "inline", "thread"):
                runs = [run(n, args.steps, log, Path(d)) for _ in range(args.repeats)]
                rows.append({
                    "robots": n, "log": log,
                    "caller_ms_per_step": round(statistics.median(
                        r["caller_ms_per_step"] for r in runs), 3),
                    "process_ms_per_step": round(statistics.median(
                        r["process_ms_per_step"] for r in runs), 3),
                    "dropped": max(r["dropped"] for r in runs),
                    "load_average_1min": round(os.getloadavg()[0], 2)})
    if args.json:
        print(json.dumps({"cpus": os.cpu_count(), "rows": rows}))
        return 0
    print(f"{'robots':>6} {'log':<7} {'caller ms/step':>14} {'process ms/step':>15} "
          f"{'dropped':>7} {'load':>5}")
    for r in rows:
        print(f"{r['robots']:>6} {r['log']:<7} {r['caller_ms_per_step']:>14.3f} "
              f"{r['process_ms_per_step']:>15.3f} {r['dropped']:>7} {r['load_average_1min']:>5}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
