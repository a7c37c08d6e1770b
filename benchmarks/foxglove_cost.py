"""What the live Foxglove view (``--foxglove``) costs the world per step, at 10 and 50 robots.

Each step does what the world's step does for its log: every robot's pose and
command through :meth:`sim_bridge.log.recorder.Recorder.write_wire` (decoded, written as
protobuf, a ``PoseInFrame`` per robot and the step's ``/tf``), one metrics row and
one ``foxglove.SceneUpdate``. Configurations, measured in the same run, rounds
interleaved, each the median of the per-step wall times:

* ``log``: the recorder writing the MCAP file (the world with ``--record``);
* ``log + live``: the same with the live server
  (:class:`sim_bridge.live.foxglove_live.FoxgloveLive`) and one WebSocket client subscribed to
  every channel, reading as fast as it can
  (:class:`sim_bridge.live.foxglove_client.FoxgloveClient`, in this process: its CPU is
  on this machine too, as a viewer's would be);
* ``live only``: the live server and client without a file (``--foxglove`` alone).

``x log`` is each row's median over the ``log`` row's. The server's own thread and
the client run beside the world's thread (2 cores here, shared): what the world
pays is the recorder's work plus a queue append per message.

Usage: ``python benchmarks/foxglove_cost.py [--robots 10,50] [--steps 300] [--rounds 3] [--json]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from runtime.wire import keys
from runtime.wire.messages import Command, Pose, encode_command, encode_pose
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.live.foxglove_client import FoxgloveClient
from sim_bridge.live.foxglove_live import FoxgloveLive
from sim_bridge.live.scene import scene_update
from sim_bridge.log.recorder import Recorder, SimTime


class Viewer:
    """A client subscribed to every channel, draining messages on its own thread."""

    def __init__(self, port: int) -> None:
        self.client = FoxgloveClient("127.0.0.1", port)
        self.received = 0
        self._subscribed: set[int] = set()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        c = self.client
        while not self._stop.is_set():
            try:
                c.poll(0.05)
            except (ConnectionError, OSError):
                return
            new = [cid for cid in c.channels if cid not in self._subscribed]
            if new:
                c.subscribe(new)
                self._subscribed.update(new)
            self.received += len(c._messages)
            c._messages.clear()

    def close(self) -> None:
        self._stop.set()
        self._t.join(timeout=5)
        self.client.close()


def steps(rec: Recorder, n: int, count: int, first: int, rng: np.random.Generator) -> list[float]:
    """``count`` steps of ``n`` robots through ``rec``: wall seconds of each."""
    w = DEFAULT_WORLD
    pos = rng.uniform(1.0, 9.0, (n, 2))
    targets = rng.uniform(1.0, 9.0, (n, 2))
    out = []
    for step in range(first, first + count):
        t = time.perf_counter()
        for r in range(n):
            rec.write_wire(keys.pose_key("bench", r), encode_pose(Pose(
                r, step, step * w.dt_s, float(pos[r, 0]), float(pos[r, 1]), 0.1, 0.0, n)))
        for r in range(n):
            rec.write_wire(keys.cmd_key("bench", r), encode_command(Command(
                r, step, 0.1, 0.0, "rule:assign", False, 0.0, 20.0)))
        lt = rec.log_time(step + 1)
        rec.metrics({"step": step + 1, "time_s": round((step + 1) * w.dt_s, 6), "phase": 0,
                     "pattern": "circle", "pattern_version": 1, "phase_step": step + 1,
                     "n_live": n, "formation_error_m": 0.5, "max_slot_distance_m": 0.7,
                     "min_separation_m": 0.3, "collisions": 0, "contacts": 0,
                     "deadline_misses": 0, "wall_ms": 1.0}, lt)
        robots = [(r, float(x), float(y)) for r, (x, y) in enumerate(pos)]
        rec.scene(scene_update(lt, robots, targets, (), 10.0, w), lt)
        out.append(time.perf_counter() - t)
        pos = pos + rng.normal(0.0, 0.01, pos.shape)
    return out


def measure(config: str, n: int, count: int, tmp: Path, seed: int) -> tuple[list[float], int]:
    """Per-step seconds of one configuration; messages the viewer received."""
    live = FoxgloveLive("127.0.0.1", 0) if config != "log" else None
    viewer = Viewer(live.port) if live is not None else None
    step = 0
    path = None if config == "live only" else tmp / f"{n}-{config.replace(' ', '')}.mcap"
    rec = Recorder(path, live=live, sim_time=SimTime(time.time_ns(), 100_000_000, lambda: step))
    rng = np.random.default_rng(seed)
    try:
        if viewer is not None:  # the viewer sees the channels before the timed steps
            steps(rec, n, 5, 0, rng)
            deadline = time.monotonic() + 10
            while len(viewer._subscribed) < 2 * n + 3 and time.monotonic() < deadline:
                time.sleep(0.01)
        steps(rec, n, 20, 5, rng)  # warm-up
        out = steps(rec, n, count, 25, rng)
    finally:
        rec.close()
        if viewer is not None:
            time.sleep(0.2)  # what is still in flight reaches the viewer's count
            viewer.close()
        if live is not None:
            live.close()
    return out, viewer.received if viewer is not None else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", default="10,50", help="team sizes (default 10,50)")
    ap.add_argument("--steps", type=int, default=300, help="timed steps per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    configs = ("log", "log + live", "live only")
    sizes = [int(x) for x in args.robots.split(",")]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            per: dict[str, list[float]] = {c: [] for c in configs}
            received: dict[str, int] = {c: 0 for c in configs}
            for k in range(args.rounds):
                for c in configs:
                    t, got = measure(c, n, args.steps, Path(tmp), seed=k)
                    per[c] += t
                    received[c] += got
            base = statistics.median(per["log"])
            for c in configs:
                med = statistics.median(per[c])
                rows.append({"robots": n, "config": c, "median_ms": round(med * 1e3, 3),
                             "p90_ms": round(float(np.percentile(per[c], 90)) * 1e3, 3),
                             "x_log": round(med / base, 3),
                             "viewer_messages": received[c]})
    if args.json:
        print(json.dumps({"rows": rows, "cpus": os.cpu_count(),
                          "load_1min": os.getloadavg()[0]}))
        return 0
    print(f"live view cost per step ({args.rounds} rounds x {args.steps} steps; "
          f"{os.cpu_count()} CPUs, 1-min load {os.getloadavg()[0]:.2f})")
    print(f"{'robots':>6}  {'config':<11} {'median ms':>9} {'p90 ms':>8} {'x log':>6} "
          f"{'viewer msgs':>11}")
    for r in rows:
        print(f"{r['robots']:>6}  {r['config']:<11} {r['median_ms']:>9.3f} {r['p90_ms']:>8.3f} "
              f"{r['x_log']:>6.2f} {r['viewer_messages']:>11}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
