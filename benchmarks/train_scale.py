"""Training that scales: the world's throughput, and training on Ray workers vs in-process.

Rows, all measured in one run, side by side:

* ``world``: ``BatchWorld.step`` at E envs x N robots (median of
  ``--repeats`` runs of ``--steps`` steps, random actions in the v_max disc,
  the three worlds timed in turn within each repeat so they share the load),
  with and without the general observation, for two steps giving the same
  assignments: *former* (scipy's Hungarian per env every step, the observation
  built through the batch entry point) and *compiled* (the world's step: its
  move, assignment and observation compiled at install from their one source,
  :mod:`trainer.world.contacts` and :mod:`runtime.core`). Each figure in wall time and
  in this thread's CPU time (the two differ when other processes share the
  cores).
* ``train``: agent-steps/s of whole iterations (rollout + update + held-out
  evaluation) for ``--train-s`` seconds: in-process, 1 and 2 Ray workers on
  a local instance, in turn for ``--rounds`` rounds (median; Ray's own start
  is not counted, the actors' is, and the rate after the first iteration
  leaves it out too).
* ``to-95``: seconds until the held-out success on a 10-robot circle
  (general observation) reaches 95 %, per mode, bounded by ``--ttf-budget-s``
  (a run that does not get there reports its best success instead).

A model of scaling (why the figures look as they do)
    One iteration costs ``t = t_roll / K + t_comm(K) + t_learn``: the rollout
    (world steps + policy forward passes, ``E x T`` steps) splits over K
    workers, each worker adds a fixed cost per iteration (the agent's
    weights out, ~100 KB, and E_k x T x N samples back, a few MB, plus Ray's
    scheduling, ~5-20 ms on one machine), and the update (``P + M + B``
    gradient steps on the whole batch) stays in the driver. Throughput is
    ``E T N / t``: it grows with K until ``t_roll / K`` falls to the size of
    ``t_learn + t_comm``; past that point the learner is the bottleneck and
    more workers add nothing (the limit is ``E T N / (t_learn + t_comm)``).
    Measured with the defaults (E = 48, T = 32, N = 10: 15,360 agent-steps
    an iteration; cProfile of a 20 s in-process run, load ~5): t_learn
    (``trainer.ppo.update.update``) ~1.3 s, the held-out evaluation ~0.2 s, the
    rollout ~0.13 s, of which the compiled world ~0.09 s. The learner is
    ~75 % of an iteration and the world ~5 %: training runs at ~9 k
    agent-steps/s however fast the world is, the limit for unlimited workers
    is ~10 k/s, and Ray workers can only add their overhead. They pay when
    the rollout dominates: larger E x T per update, heavier worlds or teams,
    or a learner on a GPU. On a 2-core machine shared with other work, K
    workers also compete with the driver for the same cores.

Usage: ``python benchmarks/train_scale.py [--json] [--train-s 30] [--ttf-budget-s 300]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from runtime.decision.formation import _sq_cost, assign_slots_batch, keeps_previous
from runtime.decision.observation import ObservationSpec, observe
from runtime.types import Array, F32Array, IntArray
from trainer.config import TrainConfig
from trainer.rollout import IN_PROCESS, RolloutMode
from trainer.train import RunPlan, train
from trainer.world.training_world import BatchWorld

PATTERNS = ("circle", "line", "cross", "heart", "triangle")
SPEC = ObservationSpec("general")


class FormerWorld(BatchWorld):
    """The step as it was: scipy per env every step, the observation in the (E, N) layout."""

    def _assign(self, X: Array) -> tuple[IntArray, Array, Array]:
        P = np.ascontiguousarray(X.transpose(2, 1, 0))
        slots = assign_slots_batch(P, self.pattern)  # every env solved, then the rule
        cost = _sq_cost(P, self.pattern)
        new = np.take_along_axis(cost, slots[..., None], -1)[..., 0].sum(-1)
        old = np.take_along_axis(cost, self.slots[..., None], -1)[..., 0].sum(-1)
        keep = keeps_previous(new, old)
        slots[keep] = self.slots[keep]
        out = slots.T.copy()
        Q = np.take_along_axis(self._C, out[None], axis=1)
        G = Q + X.sum(axis=1, keepdims=True) * (1.0 / self.n_robots)
        gap = X - G
        return out, G, gap[0] * gap[0] + gap[1] * gap[1]

    def _observe(self, ids: IntArray | None = None) -> F32Array:
        if not self.build_obs:
            return super()._observe(ids)
        sel = slice(None) if ids is None else ids
        goals = self._G.transpose(2, 1, 0)[sel]
        return observe(self.obs_spec, self.frames[sel], goals, None, self.world).astype(np.float32)


def world_rates(E: int, N: int, obs: bool, steps: int, repeats: int) -> dict[str, dict[str, int]]:
    """Median agent-steps/s (wall and thread CPU) of each step, timed in turn (random actions)."""
    worlds = {
        "former": FormerWorld(E, N, PATTERNS, SPEC, seed=0, build_obs=obs),
        "compiled": BatchWorld(E, N, PATTERNS, SPEC, seed=0, build_obs=obs),
    }
    rng = np.random.default_rng(0)

    def acts() -> list[Array]:
        out = []
        for _ in range(steps):
            ang = rng.uniform(0.0, 2.0 * np.pi, (E, N))
            r = np.sqrt(rng.uniform(0.0, 1.0, (E, N)))
            out.append(np.stack([r * np.cos(ang), r * np.sin(ang)], axis=-1))
        return out

    for a in acts():  # warm up into mid-episode states (and compile)
        for w in worlds.values():
            w.step(a)
    wall: dict[str, list[float]] = {k: [] for k in worlds}
    cpu: dict[str, list[float]] = {k: [] for k in worlds}
    for _ in range(repeats):
        A = acts()
        for name, w in worlds.items():
            t0, c0 = time.perf_counter(), time.thread_time()
            for a in A:
                w.step(a)
            wall[name].append((time.perf_counter() - t0) / steps)
            cpu[name].append((time.thread_time() - c0) / steps)
    return {k: {"wall": round(E * N / statistics.median(wall[k])),
                "cpu": round(E * N / statistics.median(cpu[k]))} for k in worlds}


def train_rate(mode: RolloutMode, seconds: float, cfg: TrainConfig) -> dict[str, Any]:
    """Agent-steps/s over whole iterations for ``seconds``, in ``mode`` (Ray's own start excluded).

    ``agent_steps_per_s`` counts every iteration, the first (with the actors'
    start: a new process importing torch) included; ``steady_agent_steps_per_s``
    the iterations after the first, what a long run sees.
    """
    res = train(cfg, RunPlan(patterns=["circle"], out=Path("unused.onnx"), time_budget_s=seconds,
                             write_files=False, progress=False, rollouts=mode))
    first, last = res.curve[0], res.curve[-1]
    rate = last["agent_steps"] / max(last["wall_s"], 1e-9)
    out = {"iterations": len(res.curve), "agent_steps_per_s": round(rate)}
    if len(res.curve) > 1:
        steps = last["agent_steps"] - first["agent_steps"]
        out["steady_agent_steps_per_s"] = round(steps / max(last["wall_s"] - first["wall_s"], 1e-9))
    return out


def time_to_95(mode: RolloutMode, budget_s: float, cfg: TrainConfig) -> dict[str, Any]:
    res = train(cfg, RunPlan(patterns=["circle"], out=Path("unused.onnx"), until_success=0.95,
                             time_budget_s=budget_s, write_files=False, progress=False,
                             rollouts=mode))
    reached = res.stopped == "success"
    return {"reached": reached, "seconds": round(res.curve[-1]["wall_s"], 1),
            "best_success": res.best_eval_success}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--envs", type=int, default=64)
    ap.add_argument("--robots", type=int, default=10)
    ap.add_argument("--steps", type=int, default=50, help="world steps per timed run")
    ap.add_argument("--repeats", type=int, default=7, help="timed world runs (median)")
    ap.add_argument("--train-s", type=float, default=30.0, help="seconds of training per mode")
    ap.add_argument("--ttf-budget-s", type=float, default=300.0,
                    help="time-to-95 %% budget per mode; 0 skips")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="Ray workers to try")
    ap.add_argument("--no-ray", action="store_true", help="in-process rows only")
    ap.add_argument("--no-world", action="store_true", help="skip the world rows")
    ap.add_argument("--rounds", type=int, default=3,
                    help="training runs per mode, the modes in turn (median)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)

    load_world = round(os.getloadavg()[0], 2)
    world = {("general" if obs else "none"): world_rates(args.envs, args.robots, obs, args.steps,
                                                         args.repeats)
             for obs in (False, True)} if not args.no_world else {}
    cfg = TrainConfig()
    modes = [("in-process", IN_PROCESS)]
    if not args.no_ray:
        modes += [(f"ray x{k}", RolloutMode(ray=True, workers=k)) for k in args.workers]
    runs: dict[str, list[dict[str, Any]]] = {label: [] for label, _ in modes}
    for _ in range(args.rounds):  # the modes in turn, so a burst of load hits all of them
        for label, mode in modes:
            row = train_rate(mode, args.train_s, cfg)
            row["load_avg_1min"] = round(os.getloadavg()[0], 2)
            runs[label].append(row)
    training: dict[str, dict[str, Any]] = {}
    for label, rows in runs.items():
        training[label] = {k: statistics.median(r[k] for r in rows if k in r)
                           for k in rows[0] if k != "iterations"}
        training[label]["runs"] = rows
    for label, mode in modes:
        if args.ttf_budget_s > 0:
            ttf = time_to_95(mode, args.ttf_budget_s, cfg)
            ttf["load_avg_1min"] = round(os.getloadavg()[0], 2)
            training[label]["to_95"] = ttf
    base = training["in-process"]
    for row in training.values():  # Ray's cost against in-process, same config and cores
        for key, name in (("agent_steps_per_s", "overhead_vs_in_process"),
                          ("steady_agent_steps_per_s", "steady_overhead_vs_in_process")):
            if key in row and key in base:
                row[name] = round(1.0 - row[key] / max(base[key], 1), 3)
    out = {"benchmark": "train_scale", "cpus": os.cpu_count(),
           "load_avg_1min_world": load_world, "E": args.envs, "N": args.robots,
           "world_agent_steps_per_s": world, "training": training}
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    print(f"world, E={args.envs} N={args.robots}, agent-steps/s (median of {args.repeats}; "
          f"wall / thread CPU), {os.cpu_count()} CPUs, 1-min load {load_world}")
    for obs, rates in world.items():
        f, c = rates["former"], rates["compiled"]
        cells = "  ".join(f"{k} {v['wall']:>10,} / {v['cpu']:>10,}" for k, v in rates.items())
        print(f"  obs={obs:8} {cells}  compiled/former x{c['wall'] / f['wall']:.2f} wall, "
              f"x{c['cpu'] / f['cpu']:.2f} CPU")
    print(f"training, {cfg.n_envs} envs x {cfg.n_robots} robots, general observation")
    for label, row in training.items():
        ttf = row.get("to_95")
        t = ("" if ttf is None else f"  to 95 %: {ttf['seconds']} s" if ttf["reached"]
             else f"  not 95 % in {ttf['seconds']} s (best {100 * ttf['best_success']:.0f} %)")
        t += "" if ttf is None else f" (load {ttf['load_avg_1min']})"
        steady = row.get("steady_agent_steps_per_s", 0)
        over = 100 * row.get("steady_overhead_vs_in_process", float("nan"))
        print(f"  {label:11} {row['agent_steps_per_s']:>9,} agent-steps/s, {steady:>9,} after "
              f"the first iteration (overhead {over:+.0f} %, load {row['load_avg_1min']}){t}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
