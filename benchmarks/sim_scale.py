"""How the world scales: physics step cost, lockstep rate and pose-to-command latency.

Part 1, world step (pymunk) for N = 10, 50, 100, 500 robots: every robot heads
straight for its slot of a circle at up to v_max (the rule brain without the
safety filter, so crossings do produce contacts), decided outside the timed
region. Timed: :meth:`sim_bridge.world.physics.PhysicsWorld.step` (velocities in
through ``pymunk.batch``, one space step, positions and contacts out). Side by
side, in the same run: the same physics driven by a Python loop over bodies
(set each velocity, step, read each position), the baseline the budget quotes.
Side by side too: bare ``pymunk.batch`` (velocities in, one space step,
positions out: the floor, what the budget's 33 us anchor measured). Also timed,
separately: the world's per-step measures (formation error under the
centred optimal assignment, min separation, swept collision check).

Part 2, the whole loop with N = 10 and N = 20 robot processes (``patternrl
robot``, ``rule:assign``, ORCA on) on loopback, lockstep: the world runs in this
process and plays patterns until ``--steps`` steps have passed. Reported: steps
per second (wall time inside steps: pattern changes, with their lower-bound
computation and brain swaps, left out) and pose-to-command latency (from the moment the
world starts publishing a step's poses to each command's arrival), p50 and p99;
beside them, what the robots report as their decision time (observation,
brain, safety filter) and the CPU time all robot processes together spent per
step (receiving the step's poses, deciding, answering), and the world's own CPU time
per step (its thread: publishing, collecting, physics, measures; no log is
written here; the whole process, Zenoh's threads and pattern changes included,
in the JSON): on a machine with few cores
that CPU time, divided by the cores, is a floor under the latency.

Budgets (DESIGN.md section 5): world step <= 50 us at N = 100; pose-to-command
p99 <= 5 ms at N = 20.

    .venv/bin/python benchmarks/sim_scale.py [--json] [--steps 400] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pymunk
import pymunk.batch as pb

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.decision.formation import (  # noqa: E402 -- after the path set-up above
    assign_slots,
    centred,
    collision_pairs,
    min_separation,
    slot_distances,
)
from runtime.decision.patterns import make_pattern  # noqa: E402
from runtime.world_config import DEFAULT_WORLD  # noqa: E402
from sim_bridge.world.physics import PhysicsWorld, arena_for_patterns, sample_starts  # noqa: E402

W = DEFAULT_WORLD


def _to_slots(pos: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Straight to the slot, clamped to v_max (what rule:assign asks before the filter)."""
    slots = assign_slots(pos, C)
    target = centred(C)[slots] + pos.mean(axis=0)
    v = (target - pos) / W.dt_s
    sp = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(sp > W.v_max_mps, v * (W.v_max_mps / np.maximum(sp, 1e-12)), v)


class LoopWorld:
    """Baseline 1: the same space driven one body at a time from Python."""

    def __init__(self, starts: np.ndarray, arena_m: float) -> None:
        self.pw = PhysicsWorld(arena_m)
        for i, (x, y) in enumerate(starts):
            self.pw.add_robot(i, float(x), float(y))
        self.bodies = [self.pw._bodies[i] for i in self.pw.ids]

    def step(self, v: np.ndarray) -> np.ndarray:
        for b, (vx, vy) in zip(self.bodies, v.tolist(), strict=True):
            b.velocity = (vx, vy)
        self.pw.space.step(W.dt_s)
        return np.array([tuple(b.position) for b in self.bodies])


class RawBatchWorld:
    """Baseline 2: bare ``pymunk.batch`` (velocities in, one space step, positions out),
    no clamp, no contact bookkeeping: the floor the world step is built on."""

    def __init__(self, starts: np.ndarray, arena_m: float) -> None:
        self.pw = PhysicsWorld(arena_m)
        for i, (x, y) in enumerate(starts):
            self.pw.add_robot(i, float(x), float(y))
        self.n = len(starts)
        self.vbuf = np.zeros((self.pw._n_bodies, 2))
        self.setb, self.getb = pb.Buffer(), pb.Buffer()
        self.setb.set_float_buf(self.vbuf.reshape(-1))

    def step(self, v: np.ndarray) -> np.ndarray:
        self.vbuf[: self.n] = v
        pb.set_space_bodies(self.pw.space, pb.BodyFields.VELOCITY, self.setb)
        self.pw.space.step(W.dt_s)
        self.getb.clear()
        pb.get_space_bodies(self.pw.space, pb.BodyFields.POSITION, self.getb)
        return np.frombuffer(self.getb.float_buf(), dtype=np.float64).reshape(-1, 2)[
            : self.n
        ].copy()


def _physics_round(n: int, steps: int, seed: int) -> dict[str, list[float]]:
    """One round: the world, the loop and the bare batch stepped side by side from one start.

    Times are wall (perf_counter) and, for the world step, CPU of this thread too.
    """
    C = make_pattern("circle", n)
    arena = arena_for_patterns([C])
    starts = sample_starts(n, arena, np.random.default_rng(seed))
    world = PhysicsWorld(arena)
    for i, (x, y) in enumerate(starts):
        world.add_robot(i, float(x), float(y))
    loop = LoopWorld(starts, arena)
    raw = RawBatchWorld(starts, arena)
    t: dict[str, list[float]] = {k: [] for k in ("world", "world_cpu", "loop", "raw", "measures")}
    substepped = 0
    pos, lpos, rpos = world.positions(), starts.copy(), starts.copy()
    for k in range(steps):
        v = _to_slots(pos, C)
        c0, t0 = time.thread_time(), time.perf_counter()
        res = world.step(v)
        t["world"].append(time.perf_counter() - t0)
        t["world_cpu"].append(time.thread_time() - c0)
        substepped += res.substepped
        new = res.positions
        if k < 50:  # the world's per-step measures, timed apart (O(N^2): a sample will do)
            t2 = time.perf_counter()
            d = slot_distances(new, C, assign_slots(new, C))
            _ = (float(np.sqrt(np.mean(d * d))), float(min_separation(new)),
                 collision_pairs(pos, new))
            t["measures"].append(time.perf_counter() - t2)
        pos = new
        lv = _to_slots(lpos, C)
        t3 = time.perf_counter()
        lpos = loop.step(lv)
        t["loop"].append(time.perf_counter() - t3)
        rv = _to_slots(rpos, C)
        t4 = time.perf_counter()
        rpos = raw.step(rv)
        t["raw"].append(time.perf_counter() - t4)
    t["contact_steps"] = [float(substepped)]
    t["contacts"] = [float(world.contacts_total)]
    t["arena_m"] = [arena]
    return t


def bench_physics(n: int, steps: int, rounds: int, seed: int = 0) -> dict[str, Any]:
    """Medians of the quietest of ``rounds`` rounds (the one whose world step median is
    lowest: on a shared machine the other rounds measure the neighbours too)."""
    runs = [_physics_round(n, steps, seed) for _ in range(rounds)]
    best = min(runs, key=lambda r: float(np.median(r["world"])))
    us = 1e6

    def med(key: str) -> float:
        return round(float(np.median(best[key])) * us, 1)

    return {
        "n": n, "arena_m": round(best["arena_m"][0], 2), "steps": steps, "rounds": rounds,
        "step_us_median": med("world"),
        "step_cpu_us_median": med("world_cpu"),
        "step_us_p99": round(float(np.percentile(best["world"], 99)) * us, 1),
        "step_us_median_all_rounds": round(
            float(np.median(np.concatenate([r["world"] for r in runs]))) * us, 1),
        "loop_us_median": med("loop"),
        "raw_batch_us_median": med("raw"),
        "speedup_vs_loop": round(med("loop") / med("world"), 2),
        "ratio_to_raw_batch": round(med("world") / med("raw"), 2),
        "contact_steps": int(best["contact_steps"][0]),
        "contacts": int(best["contacts"][0]),
        "measures_us_median": med("measures"),
    }


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc), 0 if unreadable."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def bench_lockstep(n: int, steps: int, seed: int = 0) -> dict[str, Any]:
    """A world in this process, n robot processes, lockstep, until ``steps`` steps ran."""
    from runtime.net.session import open_session
    from sim_bridge.launch.launch import Robots, free_port
    from sim_bridge.world.brain_choice import rule_choice
    from sim_bridge.world.sim_world import SimConfig, SimWorld

    patterns = ["circle", "line", "cross", "heart"] * 50
    swarm = f"bench-{n}-{os.getpid()}"
    port = free_port()
    cfg = SimConfig(swarm=swarm, robots=n, patterns=patterns, seed=seed,
                    brains={p: rule_choice() for p in patterns}, wait_robots_s=120.0,
                    first_step_deadline_ms=10_000.0)
    session = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    world = SimWorld(cfg, session, None, log=lambda msg, detail: None)

    cpu0: list[float] = []  # the robots' CPU time at step 1: start-up left out

    def on_progress(p: Any) -> None:
        if p.step == 1:
            cpu0.append(sum(_cpu_seconds(q.pid) for q in robots.procs.values()))
            cpu0.append(time.process_time())
        if p.step >= steps:
            world.stop_event.set()

    world.on_progress = on_progress
    robots = Robots()
    args = argparse.Namespace(mode="lockstep", safety="orca", rate_hz=10.0,
                              step_deadline_ms=cfg.step_deadline_ms)
    log = Path(os.environ.get("TMPDIR", "/tmp")) / f"{swarm}.robots.log"
    cpu_s = world_cpu_s = 0.0
    try:
        robots.start(n, swarm, port, "rule:assign", args, log)
        res = world.run()
        world_cpu_s = time.process_time() - cpu0[1]
        cpu_s = sum(_cpu_seconds(p.pid) for p in robots.procs.values())
    finally:
        robots.stop()
        session.close()  # type: ignore[no-untyped-call]
        log.unlink(missing_ok=True)
    lat = np.asarray(res.latencies_ms[n:])  # the very first step waits for start-up
    misses = sum(p.deadline_misses for p in res.phases)
    dec = np.asarray(world.decision_us[n:])
    return {
        "n": n, "steps": res.steps, "phases": len(res.phases),
        "steps_per_s": round(res.steps / world.stepping_wall_s, 1),
        "latency_ms_p50": round(float(np.percentile(lat, 50)), 3),
        "latency_ms_p99": round(float(np.percentile(lat, 99)), 3),
        "latency_ms_max": round(float(lat.max()), 3),
        "deadline_misses": misses,
        "robot_decision_us_p50": round(float(np.percentile(dec, 50)), 1),
        "robot_cpu_ms_per_step": round((cpu_s - cpu0[0]) * 1000.0 / max(res.steps - 1, 1), 2),
        "world_cpu_ms_per_step": round(world.stepping_cpu_s * 1000.0 / max(res.steps, 1), 3),
        "world_process_cpu_ms_per_step": round(world_cpu_s * 1000.0 / max(res.steps - 1, 1), 2),
        "formed": sum(p.formed for p in res.phases),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print JSON only")
    ap.add_argument("--steps", type=int, default=400, help="steps per measurement (default 400)")
    ap.add_argument("--sizes", default="10,50,100,500", help="physics team sizes")
    ap.add_argument("--processes", default="10,20", help="robot process counts (lockstep)")
    ap.add_argument("--rounds", type=int, default=3,
                    help="physics rounds per size; the quietest is reported (default 3)")
    ap.add_argument("--quick", action="store_true", help="fewer steps (a smoke run)")
    args = ap.parse_args()
    steps = 60 if args.quick else args.steps
    sizes = [int(x) for x in args.sizes.split(",") if x]
    procs = [int(x) for x in args.processes.split(",") if x]
    physics = [bench_physics(n, steps, 1 if args.quick else args.rounds) for n in sizes]
    loops = [bench_lockstep(n, steps) for n in procs]
    out = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "pymunk": pymunk.version, "platform": platform.platform(),
                    "load_average_1min": round(os.getloadavg()[0], 2)},
        "world_step": physics,
        "lockstep": loops,
        "budgets": {
            "world_step_us_at_100": {"budget": 50.0, "measured": next(
                (p["step_us_median"] for p in physics if p["n"] == 100), None)},
            "pose_to_command_p99_ms_at_20": {"budget": 5.0, "measured": next(
                (p["latency_ms_p99"] for p in loops if p["n"] == 20), None)},
        },
    }
    if args.json:
        print(json.dumps(out))
        return 0
    m = out["machine"]
    print(f"machine: {m['cpus']} cpus, python {m['python']}, pymunk {m['pymunk']}, "
          f"1-min load average {m['load_average_1min']} at the end")
    print("\nworld step (pymunk), robots heading straight for a circle's slots: medians over "
          f"{steps} steps, the quietest of {physics[0]['rounds'] if physics else 0} rounds")
    print(f"{'N':>5} {'world us':>9} {'cpu us':>7} {'p99 us':>8} {'raw batch us':>12} "
          f"{'loop us':>8} {'vs loop':>8} {'vs raw':>7} {'contact steps':>13} "
          f"{'measures us':>11}")
    for p in physics:
        print(f"{p['n']:>5} {p['step_us_median']:>9.1f} {p['step_cpu_us_median']:>7.1f} "
              f"{p['step_us_p99']:>8.1f} {p['raw_batch_us_median']:>12.1f} "
              f"{p['loop_us_median']:>8.1f} {p['speedup_vs_loop']:>7.2f}x "
              f"{p['ratio_to_raw_batch']:>6.2f}x {p['contact_steps']:>13} "
              f"{p['measures_us_median']:>11.1f}")
    print(f"\nlockstep with robot processes on loopback ({steps} steps)")
    print(f"{'robots':>6} {'steps/s':>8} {'p50 ms':>7} {'p99 ms':>7} {'max ms':>7} "
          f"{'misses':>6} {'decision us p50':>15} {'robots cpu ms/step':>18} "
          f"{'world cpu ms/step':>17}")
    for p in loops:
        print(f"{p['n']:>6} {p['steps_per_s']:>8.1f} {p['latency_ms_p50']:>7.3f} "
              f"{p['latency_ms_p99']:>7.3f} {p['latency_ms_max']:>7.2f} "
              f"{p['deadline_misses']:>6} {p['robot_decision_us_p50']:>15.1f} "
              f"{p['robot_cpu_ms_per_step']:>18.2f} {p['world_cpu_ms_per_step']:>17.2f}")
    b = out["budgets"]
    print(f"\nbudgets: world step at N=100 {b['world_step_us_at_100']['measured']} us "
          f"(<= 50); pose-to-command p99 at N=20 "
          f"{b['pose_to_command_p99_ms_at_20']['measured']} ms (<= 5)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
