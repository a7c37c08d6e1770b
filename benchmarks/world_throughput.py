"""Agent-steps per second of the training world (trainer/world/training_world.py), with reward
and termination.

DESIGN.md budget: >= 1 M agent-steps/s at E = 64 envs x N = 10 robots. Each row
times ``BatchWorld.step`` alone (the policy's actions are made outside the
timer), E x N agent-steps per call: the median over ``--repeats`` runs of
``--steps`` steps, in wall time and in this thread's CPU time (the two differ
when other processes share the machine). Rows:

* ``obs=general`` builds the general observation every step (what the trainer
  uses); ``obs=none`` skips it (``build_obs=False``): the world's own cost.
* ``step=compiled``: the world's one step (its move, assignment and observation
  compiled at install from their one source, :mod:`trainer.world.contacts` and
  :mod:`runtime.core`).
* ``policy=random``: uniform random velocities in the v_max disc, like an
  untrained policy. ``policy=to-slot``: full speed straight at the slot, with
  a little noise and no avoidance: robots collide and jam all the time, the
  contact-heavy worst case.

Side by side, after every run and on the same world state, the benchmark times
``assign_slots_batch(previous=...)`` over all E envs (the numpy assignment:
the batched proof, scipy where it fails): ``x_assign`` is the step's cost in
units of it, a ratio that carries over between machines and loads.

Usage: ``python benchmarks/world_throughput.py [--envs 64] [--robots 10 20] [--json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from dataclasses import asdict, dataclass

import numpy as np

from runtime.decision.formation import assign_slots_batch
from runtime.decision.observation import ObservationSpec
from runtime.types import Array
from trainer.world.training_world import BatchWorld

PATTERNS = ("circle", "line", "cross", "heart", "triangle")


@dataclass(frozen=True)
class Row:
    n_envs: int
    n_robots: int
    step: str
    obs: str
    policy: str
    wall_us_per_step: float
    agent_steps_per_s: int  # from wall time
    cpu_us_per_step: float
    agent_steps_per_cpu_s: int
    assign_us: float  # assign_slots_batch over all envs, wall, same runs
    x_assign: float  # wall step / wall assignment, median of paired runs


def _policy(name: str, w: BatchWorld, rng: np.random.Generator) -> Array:
    E, N = w.n_envs, w.n_robots
    v = w.world.v_max_mps
    if name == "random":
        ang = rng.uniform(0.0, 2.0 * np.pi, (E, N))
        r = np.sqrt(rng.uniform(0.0, 1.0, (E, N))) * v
        return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=-1)
    g = w.goals - w.positions
    d = np.linalg.norm(g, axis=-1, keepdims=True)
    step = g / np.maximum(d, w.world.max_step_m) * v
    out: Array = step + rng.normal(0.0, 0.05 * v, (E, N, 2))
    return out


def time_world(
    n_envs: int, n_robots: int, obs: str, policy: str, steps: int, repeats: int, seed: int = 0,
    step: str = "compiled",
) -> Row:
    w = BatchWorld(
        n_envs, n_robots, PATTERNS, ObservationSpec("general"), seed=seed,
        build_obs=obs != "none",
    )
    rng = np.random.default_rng(seed)
    for _ in range(100):  # warm up into mid-episode states
        w.step(_policy(policy, w, rng))
    wall, cpu, assign, ratio = [], [], [], []
    for _ in range(repeats):
        acts = [_policy(policy, w, rng) for _ in range(steps)]
        t0, c0 = time.perf_counter(), time.thread_time()
        for a in acts:
            w.step(a)
        wall.append((time.perf_counter() - t0) / steps)
        cpu.append((time.thread_time() - c0) / steps)
        P, C, s = w.positions, w.pattern, w.slots
        t0 = time.perf_counter()
        for _ in range(10):
            assign_slots_batch(P, C, previous=s)
        assign.append((time.perf_counter() - t0) / 10)
        ratio.append(wall[-1] / assign[-1])
    n = n_envs * n_robots
    med_wall, med_cpu = statistics.median(wall), statistics.median(cpu)
    return Row(
        n_envs,
        n_robots,
        step,
        obs,
        policy,
        round(med_wall * 1e6, 1),
        round(n / med_wall),
        round(med_cpu * 1e6, 1),
        round(n / med_cpu),
        round(statistics.median(assign) * 1e6, 1),
        round(statistics.median(ratio), 2),
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--robots", type=int, nargs="+", default=[10, 20])
    ap.add_argument("--steps", type=int, default=100, help="steps per timed run")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per row (median)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = ap.parse_args(argv)

    load0 = os.getloadavg()[0]
    rows = [
        time_world(args.envs, n, obs, policy, args.steps, args.repeats)
        for n in args.robots
        for obs in ("none", "general")
        for policy in ("random", "to-slot")
    ]
    load1 = os.getloadavg()[0]
    meta = {
        "benchmark": "world_throughput",
        "budget_agent_steps_per_s": 1_000_000,
        "cpus": os.cpu_count(),
        "load_avg_1min_before_after": [round(load0, 2), round(load1, 2)],
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "steps": args.steps,
        "repeats": args.repeats,
    }
    if args.json:
        print(json.dumps({**meta, "rows": [asdict(r) for r in rows]}, indent=2))
        return 0
    print(
        f"world throughput, E={args.envs}, median of {args.repeats} x {args.steps} steps; "
        f"{os.cpu_count()} CPUs, 1-min load {load0:.2f} -> {load1:.2f}"
    )
    hdr = (
        f"{'N':>3} {'step':>8} {'obs':>8} {'policy':>8} | {'us/step':>8} {'agent-steps/s':>14} | "
        f"{'CPU us':>8} {'per CPU-s':>12} | {'assign us':>9} {'x assign':>8}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(
            f"{r.n_robots:>3} {r.step:>8} {r.obs:>8} {r.policy:>8} | {r.wall_us_per_step:>8.0f} "
            f"{r.agent_steps_per_s:>14,} | {r.cpu_us_per_step:>8.0f} "
            f"{r.agent_steps_per_cpu_s:>12,} | {r.assign_us:>9.0f} {r.x_assign:>8.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
