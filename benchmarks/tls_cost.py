"""What mutual TLS + access control cost: pose -> command latency, TLS against plain TCP.

    .venv/bin/python benchmarks/tls_cost.py [--robots 10] [--steps 300] [--rounds 3] [--json]

A world in this process and ``--robots`` robot processes (``patternrl robot``,
``rule:assign``, ORCA on) on loopback, lockstep, stepping as fast as the robots
answer; the same run with open TCP (``--insecure``) and with each process's own
certificate and the swarm's access rules (the default), rounds interleaved
(tcp, tls, tcp, tls, ...) so that the machine's load falls on both alike. Per
round: p50/p99 of pose -> command over every command after the first step;
reported: the median of the rounds' p50s per transport, and their ratio.
Budget (DESIGN.md section 5): TLS p50 within 10 % of TCP at 10 robots.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def one_round(n: int, steps: int, keys_dir: Path | None, swarm: str, seed: int) -> dict[str, Any]:
    """One lockstep run of ``steps`` steps; ``keys_dir`` None: open TCP."""
    from runtime.net.identity import load_identity
    from runtime.net.session import make_config, open_config
    from sim_bridge.launch.launch import Robots, free_port
    from sim_bridge.world.brain_choice import rule_choice
    from sim_bridge.world.sim_world import SimConfig, SimWorld

    patterns = ["circle", "line", "cross", "heart"] * 50
    port = free_port()
    cfg = SimConfig(swarm=swarm, robots=n, patterns=patterns, seed=seed,
                    brains={p: rule_choice() for p in patterns}, wait_robots_s=120.0,
                    first_step_deadline_ms=10_000.0)
    scheme = "tcp" if keys_dir is None else "tls"
    ident = None if keys_dir is None else load_identity(keys_dir / "world")
    session = open_config(make_config("peer", [], [f"{scheme}/127.0.0.1:{port}"],
                                      identity=ident))
    world = SimWorld(cfg, session, None, log=lambda msg, detail: None)

    def on_progress(p: Any) -> None:
        if p.step >= steps:
            world.stop_event.set()

    world.on_progress = on_progress
    robots = Robots()
    args = argparse.Namespace(mode="lockstep", safety="orca", rate_hz=10.0,
                              step_deadline_ms=cfg.step_deadline_ms)
    log = Path(tempfile.gettempdir()) / f"{swarm}.robots.log"
    try:
        robots.start(n, swarm, port, "rule:assign", args, log, keys_dir)
        res = world.run()
    finally:
        robots.stop()
        session.close()  # type: ignore[no-untyped-call]
        log.unlink(missing_ok=True)
    lat = np.asarray(res.latencies_ms[n:])  # the first step waits for start-up
    return {"transport": scheme, "steps": res.steps,
            "steps_per_s": round(res.steps / max(world.stepping_wall_s, 1e-9), 1),
            "p50_ms": round(float(np.percentile(lat, 50)), 3),
            "p99_ms": round(float(np.percentile(lat, 99)), 3),
            "deadline_misses": sum(p.deadline_misses for p in res.phases)}


def main() -> int:
    from sim_bridge.launch.swarm_keys import create_swarm_keys

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=10, help="robot processes (default 10)")
    ap.add_argument("--steps", type=int, default=300, help="steps per round (default 300)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds per transport (default 3)")
    ap.add_argument("--json", action="store_true", help="print JSON only")
    args = ap.parse_args()
    swarm = f"tlscost{os.getpid()}"
    rounds: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="patternrl-tlscost-") as tmp:
        made = create_swarm_keys(Path(tmp) / "keys", swarm, args.robots)
        for r in range(args.rounds):
            for keys_dir in (None, made.out):
                t0 = time.perf_counter()
                res = one_round(args.robots, args.steps, keys_dir, swarm, seed=r)
                res.update(round=r, wall_s=round(time.perf_counter() - t0, 1))
                rounds.append(res)
                if not args.json:
                    print(f"round {r} {res['transport']}: p50 {res['p50_ms']:.3f} ms, "
                          f"p99 {res['p99_ms']:.3f} ms, {res['steps_per_s']} steps/s, "
                          f"misses {res['deadline_misses']}", flush=True)
    med = {t: statistics.median(x["p50_ms"] for x in rounds if x["transport"] == t)
           for t in ("tcp", "tls")}
    med99 = {t: statistics.median(x["p99_ms"] for x in rounds if x["transport"] == t)
             for t in ("tcp", "tls")}
    ratio = med["tls"] / med["tcp"] if med["tcp"] > 0 else float("nan")
    out = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                       "load_average_1min": round(os.getloadavg()[0], 2)},
           "robots": args.robots, "steps": args.steps, "rounds": rounds,
           "p50_ms": med, "p99_ms": med99, "tls_over_tcp_p50": round(ratio, 3),
           "budget": {"tls_over_tcp_p50_max": 1.10, "met": bool(ratio <= 1.10)}}
    if args.json:
        print(json.dumps(out))
        return 0
    load = out["machine"]["load_average_1min"]
    print(f"\npose -> command, {args.robots} robots, lockstep, loopback, median of "
          f"{args.rounds} rounds each ({os.cpu_count()} cpus, load {load})")
    print(f"{'transport':<28} {'p50 ms':>8} {'p99 ms':>8}")
    print(f"{'tcp (--insecure)':<28} {med['tcp']:>8.3f} {med99['tcp']:>8.3f}")
    print(f"{'tls + access control':<28} {med['tls']:>8.3f} {med99['tls']:>8.3f}")
    print(f"tls / tcp p50: {ratio:.3f}x (budget <= 1.10x: "
          f"{'met' if ratio <= 1.10 else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
