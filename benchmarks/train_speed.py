"""Training speed: Pattern-RL vs standard PPO, and the paper's Fig. 5 learning curves.

Part 1, time to >= 95 % (DESIGN.md budget: <= 2 min on 2 cores, general observation)
    For each observation (``general``, ``paper``), each algorithm (``pattern-rl``,
    ``ppo``) and each seed, train a 10-robot circle from scratch with the
    default configuration until the held-out deterministic success rate (64
    fixed episodes, no safety filter) reaches the target, or the per-run
    budget runs out. Same seeds for both algorithms: same starts, same
    held-out set. Reported per run: reached or not, wall time (training and
    its held-out evaluations, all included), training episodes and
    agent-steps; where the target is not reached, the best success and when.

Part 2, Fig. 5 (``--fig5``)
    10 robots learn a pattern sequence (default circle then cross), each stage
    continuing from the last, for a fixed number of training episodes per
    stage; Pattern-RL vs PPO on the same seeds (default 4). The mean episode
    reward against episodes, mean and min-max spread over seeds, per stage,
    written as ``fig5.png``.

Prints a table and writes ``train_speed.json`` (and the PNG) to ``--out-dir``.

Examples::

    python benchmarks/train_speed.py --budget-s 180 --seeds 0,1,2
    python benchmarks/train_speed.py --skip-speed --fig5 --fig5-episodes 300 --fig5-seeds 4
    python benchmarks/train_speed.py --skip-speed --fig5 --fig5-conditions realistic \
        --fig5-hold-steps 20 --fig5-png fig5_realistic.png \
        --out-dir benchmarks/results/fig5_realistic
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from trainer.config import FRONT_END_NAMES, TrainConfig  # noqa: E402
from trainer.train import RunPlan, train  # noqa: E402


def _first_reach(curve: list[dict[str, Any]], target: float) -> dict[str, Any] | None:
    for r in curve:
        if not math.isnan(r["eval_success"]) and r["eval_success"] >= target:
            return r
    return None


def _best(curve: list[dict[str, Any]]) -> dict[str, Any] | None:
    ev = [r for r in curve if not math.isnan(r["eval_success"])]
    return max(ev, key=lambda r: r["eval_success"]) if ev else None  # first of the maxima


def speed_runs(args: argparse.Namespace) -> list[dict[str, Any]]:
    rows = []
    for obs in args.obs:
        for seed in args.seeds:
            for algo in args.algos:
                cfg = TrainConfig(algo=algo, obs=obs, n_robots=args.robots, seed=seed)
                plan = RunPlan(
                    patterns=[args.pattern],
                    out=Path(args.out_dir) / "unused.onnx",
                    until_success=args.target,
                    time_budget_s=args.budget_s,
                    progress=False,
                    write_files=False,
                )
                t0 = time.perf_counter()
                res = train(cfg, plan)
                wall = time.perf_counter() - t0
                hit = _first_reach(res.curve, args.target)
                best = _best(res.curve)
                row = {
                    "obs": obs,
                    "algo": algo,
                    "seed": seed,
                    "reached": hit is not None,
                    "wall_s": round(hit["wall_s"], 1) if hit else None,
                    "episodes": hit["episodes"] if hit else None,
                    "agent_steps": hit["agent_steps"] if hit else None,
                    "iterations": hit["iteration"] if hit else None,
                    "best_success": best["eval_success"] if best else 0.0,
                    "best_at_s": round(best["wall_s"], 1) if best else None,
                    "best_at_episodes": best["episodes"] if best else None,
                    "run_wall_s": round(wall, 1),
                }
                rows.append(row)
                print(_fmt_row(row), flush=True)
    return rows


def _fmt_row(r: dict[str, Any]) -> str:
    if r["reached"]:
        what = (
            f"reached in {r['wall_s']:6.1f} s, {r['episodes']:5d} episodes, "
            f"{r['agent_steps'] / 1e6:5.2f} M agent-steps"
        )
    else:
        what = (
            f"not reached; best {100 * r['best_success']:5.1f} % at {r['best_at_s']} s "
            f"({r['best_at_episodes']} episodes)"
        )
    return f"{r['obs']:<8} {r['algo']:<11} seed {r['seed']:<3} {what}"


def summarise(rows: list[dict[str, Any]], target: float) -> list[dict[str, Any]]:
    out = []
    keys = sorted({(r["obs"], r["algo"]) for r in rows})
    for obs, algo in keys:
        rs = [r for r in rows if r["obs"] == obs and r["algo"] == algo]
        hit = [r for r in rs if r["reached"]]
        out.append(
            {
                "obs": obs,
                "algo": algo,
                "runs": len(rs),
                "reached": len(hit),
                "median_wall_s": float(np.median([r["wall_s"] for r in hit])) if hit else None,
                "max_wall_s": max(r["wall_s"] for r in hit) if hit else None,
                "median_episodes": float(np.median([r["episodes"] for r in hit])) if hit else None,
                "median_agent_steps": float(np.median([r["agent_steps"] for r in hit]))
                if hit
                else None,
                "best_success": max(r["best_success"] for r in rs),
                "target": target,
            }
        )
    return out


def _fig5_run(algo: str, seed: int, args: argparse.Namespace) -> tuple[list[dict[str, Any]], str]:
    """One Fig. 5 run (a process of its own with ``--jobs``): its curve and a log line."""
    cfg = TrainConfig(algo=algo, obs=args.fig5_obs, n_robots=args.robots, seed=seed,
                      front_end=args.fig5_front_end, conditions=args.fig5_conditions,
                      hold_steps=args.fig5_hold_steps,
                      eval_every=10**6)  # the figure plots training rewards: no held-out runs
    plan = RunPlan(
        patterns=args.fig5_patterns,
        out=Path(args.out_dir) / "unused.onnx",
        episodes=args.fig5_episodes,
        progress=False,
        write_files=False,
    )
    t0 = time.perf_counter()
    res = train(cfg, plan)
    line = (f"fig5 {algo:<11} seed {seed}: {res.episodes} episodes in "
            f"{time.perf_counter() - t0:.0f} s")
    return res.curve, line


def fig5(args: argparse.Namespace) -> dict[str, Any]:
    curves: dict[str, list[list[dict[str, Any]]]] = {a: [] for a in args.algos}
    tasks = [(algo, seed) for algo in args.algos for seed in range(args.fig5_seeds)]
    if args.jobs > 1:  # independent runs side by side, one process each
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            results = list(pool.map(_fig5_run, *zip(*tasks, strict=True),
                                    [args] * len(tasks)))
    else:
        results = [_fig5_run(algo, seed, args) for algo, seed in tasks]
    for (algo, _), (curve, line) in zip(tasks, results, strict=True):
        curves[algo].append(curve)
        print(line, flush=True)
    png = Path(args.out_dir) / args.fig5_png
    title = args.fig5_obs if args.fig5_conditions == "perfect" else (
        f"{args.fig5_obs} observation, {args.fig5_conditions}")
    summary = plot_fig5(curves, args.fig5_patterns, args.fig5_episodes, png, title)
    return {"png": str(png), "final_reward": summary}


def plot_fig5(
    curves: dict[str, list[list[dict[str, Any]]]],
    patterns: list[str],
    episodes: int,
    png: Path,
    obs: str,
) -> dict[str, Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = np.linspace(0, episodes, 60)
    fig, axes = plt.subplots(1, len(patterns), figsize=(5.5 * len(patterns), 4), squeeze=False)
    summary: dict[str, Any] = {}
    for s, pattern in enumerate(patterns):
        ax = axes[0, s]
        for algo, runs in curves.items():
            ys = []
            for curve in runs:
                rows = [r for r in curve if r["stage"] == s and not math.isnan(r["mean_reward"])]
                if not rows:
                    continue
                start = min(r["episodes"] for r in curve if r["stage"] == s) if s else 0
                x = np.array([r["episodes"] - start for r in rows], float)
                y = np.array([r["mean_reward"] for r in rows], float)
                ys.append(np.interp(grid, x, y, left=np.nan))
            if not ys:
                continue
            arr = np.array(ys)
            with warnings.catch_warnings():  # grid points before any run's first episode
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(arr, 0)
                lo, hi = np.nanmin(arr, 0), np.nanmax(arr, 0)
            label = "Pattern-RL" if algo == "pattern-rl" else "standard PPO"
            ax.plot(grid, mean, label=f"{label} (mean of {len(ys)})")
            ax.fill_between(grid, lo, hi, alpha=0.2)
            summary[f"{pattern}/{algo}"] = float(mean[-1])
        what = obs if "observation" in obs else f"{obs} observation"
        ax.set_title(f"({chr(97 + s)}) {pattern}, 10 robots, {what}")
        ax.set_xlabel("training episodes (this pattern)")
        ax.set_ylabel("mean episode reward")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return summary


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--budget-s", type=float, default=180.0, help="per training run (180)")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--algos", default="pattern-rl,ppo")
    p.add_argument("--obs", default="general,paper")
    p.add_argument("--pattern", default="circle")
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--target", type=float, default=0.95)
    p.add_argument("--skip-speed", action="store_true")
    p.add_argument("--fig5", action="store_true", help="also run the Fig. 5 learning curves")
    p.add_argument("--fig5-patterns", default="circle,cross")
    p.add_argument("--fig5-episodes", type=int, default=300, help="per pattern stage (300)")
    p.add_argument("--fig5-seeds", type=int, default=4)
    p.add_argument("--fig5-obs", default="general")
    p.add_argument("--fig5-conditions", default="perfect",
                   help="the conditions the Fig. 5 runs train under (runtime.conditions: a "
                   "preset or spec, e.g. realistic; default perfect)")
    p.add_argument("--fig5-hold-steps", type=int, default=0,
                   help="the Fig. 5 runs' hold window (train --hold-steps; default 0)")
    p.add_argument("--fig5-png", default="fig5.png", help="the figure's file name in --out-dir")
    p.add_argument("--fig5-front-end", default="auto", choices=list(FRONT_END_NAMES),
                   help="the brain's front end for the Fig. 5 runs (trainer.ppo.front_end)")
    p.add_argument("--jobs", type=int, default=1,
                   help="Fig. 5 runs side by side, one process each (for machines with more "
                        "cores; each run uses one)")
    p.add_argument("--out-dir", default=str(ROOT / "benchmarks" / "results"))
    args = p.parse_args()
    args.seeds = [int(s) for s in args.seeds.split(",") if s]
    args.algos = [a for a in args.algos.split(",") if a]
    args.obs = [o for o in args.obs.split(",") if o]
    args.fig5_patterns = [s for s in args.fig5_patterns.split(",") if s]
    Path(args.out_dir).mkdir(parents=True, exist_ok=True)

    report: dict[str, Any] = {
        "machine": f"{platform.processor() or platform.machine()}, {_cores()} cores",
        "budget_s": args.budget_s,
        "pattern": args.pattern,
        "robots": args.robots,
        "target": args.target,
    }
    if not args.skip_speed:
        rows = speed_runs(args)
        report["runs"] = rows
        report["summary"] = summarise(rows, args.target)
        print("\nobs      algo        reached  median s  max s  median episodes  best")
        for s in report["summary"]:
            med = "-" if s["median_wall_s"] is None else f"{s['median_wall_s']:.1f}"
            mx = "-" if s["max_wall_s"] is None else f"{s['max_wall_s']:.1f}"
            me = "-" if s["median_episodes"] is None else f"{s['median_episodes']:.0f}"
            print(
                f"{s['obs']:<9} {s['algo']:<11} {s['reached']}/{s['runs']:<6} {med:>8} "
                f"{mx:>6} {me:>16}  {100 * s['best_success']:.1f} %"
            )
    if args.fig5:
        report["fig5"] = fig5(args)
        print(f"fig5: {report['fig5']['png']}")
    out = Path(args.out_dir) / "train_speed.json"
    out.write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")
    print(json.dumps({k: v for k, v in report.items() if k != "runs"}, allow_nan=False))
    return 0


def _cores() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


if __name__ == "__main__":
    sys.exit(main())
