"""The paper's experiments (Section IV.C-E) rerun on this system; writes docs/results.md.

    .venv/bin/python benchmarks/paper_experiments.py [--quick] [--out docs]

Every number in the document it writes comes from this run (the learning curves
excepted: they are read from the trainer's benchmark output, named with its
path and date, see (b)). The document states the machine, the seeds, the
brains and how long the run took, and the command that regenerates it.

(a) n-regular polygons, n = 4, 6, ..., 20 (the paper's Fig. 4-6 setting, IV.D)
    The ``circle`` pattern with n robots is the regular n-gon (side 4R). Every
    method runs the same episodes through :func:`trainer.evaluate.evaluate_brain`
    (the training world, every decision through the robot's own pipeline,
    :func:`runtime.decision.pipeline.decide_batch`); episode ``e`` starts where env ``e``
    of ``BatchWorld(seed)`` starts, whatever the method. Methods:

    ================== ==========================================================
    rule, no filter    ``rule:assign --safety off``: shared assignment, straight
                       lines at v_max (the CAPT-style rule)
    rule + ORCA(tau)   ``rule:assign --safety orca``: the same slots reached
                       through ORCA, the holonomic stand-in for the paper's
                       NH-ORCA baseline, for each time horizon tau
    <brain> raw        a learned brain alone (the paper's setting)
    <brain> + ORCA(tau) the learned brain behind the safety filter (as shipped)
    ================== ==========================================================

    Reported per n and method: success (formed within the step limit with no
    collision), steps and travel as ratios to the lower bounds (mean over formed
    episodes), collisions per episode, the minimum separation (closest approach
    of two centres along the commanded moves), the filter's share of changed
    commands. Against the paper's claim (37.5-43.8 % less travel than NH-ORCA):
    the travel (and steps) reduction of each learned method against rule + ORCA,
    paired on the episodes both formed, with a 95 % bootstrap interval, for each
    ORCA time horizon.

(b) Learning curves, Pattern-RL vs standard PPO (Fig. 5, IV.C)
    Read from ``benchmarks/train_speed.py --fig5`` output (``train_speed.json``
    and ``fig5.png`` in ``--fig5-dir``); ``--fig5-run`` runs it here first
    (training: tens of minutes).

(c) Trajectories for circle, heart, line and triangle (Fig. 6, IV.E)
    Real runs: ``patternrl launch`` in a subprocess (the pymunk world and one
    ``patternrl robot`` process per robot over Zenoh on loopback, lockstep), one
    run per pattern from the same seeded starts, for the learned brain raw, with
    the filter, and the rule + ORCA baseline. The figure is drawn from the MCAP
    logs (:mod:`sim_bridge.log.plots`); the table comes from the world's results and
    the logged commands.

(d) Per-decision latency vs the paper's 1.2 ms (IV.B)
    :func:`benchmarks.runtime_latency.decision_latency`: each of 10 robots
    decides with its own :class:`runtime.decision.controller.Controller` while the team
    forms a circle (assignment + observation + brain + filter), wall clock.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from runtime.brain.brain import RULE_ASSIGN, Brain, BrainError, load_brain  # noqa: E402
from runtime.decision.safety import OrcaParams  # noqa: E402
from runtime.world_config import DEFAULT_WORLD  # noqa: E402
from trainer.evaluate import DEFAULT_EVAL_SEED, EvalResult, evaluate_brain  # noqa: E402

W = DEFAULT_WORLD
PAPER_TRAVEL_CLAIM = (0.375, 0.438)
"""IV.D: 37.5 % to 43.8 % less travel than NH-ORCA, n = 4 to 20 (the abstract says time steps)."""
PAPER_LATENCY_MS = 1.2
"""IV.B: "the response time of generating new actions for each step takes 1.2 ms on average"."""
FIG6_PATTERNS = ("circle", "heart", "line", "triangle")
DEFAULT_BRAINS = (
    "exports/circle-10-general.onnx",
    "exports/general.onnx",
    "exports/circle-10-paper.onnx",
)
"""Learned brains of (a) when ``--brains`` is not given (those that exist): the circle
brain on the general observation (any n), the any-pattern general brain, and the
paper-observation circle brain (its own n only)."""
DEFAULT_TAU = OrcaParams().time_horizon_s


# ------------------------------------------------------------------- helpers


def _bench(name: str) -> ModuleType:
    """Another benchmark script of benchmarks/ as a module (they are scripts, not a package)."""
    path = ROOT / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _rel(p: Path | str) -> str:
    p = Path(p).resolve()
    try:
        return str(p.relative_to(ROOT))
    except ValueError:
        return str(p)


def _pct(x: float | None, digits: int = 1) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    t = f"{100 * x:.{digits}f}"
    return f"{'0.' + '0' * digits if float(t) == 0 else t} %"


def _x(x: float | None, digits: int = 3) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}x"


def _num(x: float | None, digits: int = 3) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _tau(t: float) -> str:
    return f"{t:g} s"


def md_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def machine_info() -> dict[str, Any]:
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gb = float("nan")
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                mem_gb = int(line.split()[1]) / 1024**2
    except OSError:
        pass
    import numpy
    import onnxruntime

    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "cpu": model,
        "cpus": os.cpu_count(),
        "cpus_usable": affinity,
        "memory_gb": round(mem_gb, 1),
        "os": platform.platform(),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "onnxruntime": onnxruntime.__version__,
        "load_avg_start": [round(x, 2) for x in os.getloadavg()],
    }


def git_state() -> dict[str, Any]:
    def git(*a: str) -> str:
        r = subprocess.run(["git", *a], cwd=ROOT, capture_output=True, text=True, check=False)
        return r.stdout.strip()

    return {
        "commit": git("rev-parse", "HEAD")[:12],
        "dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
    }


def describe_brain(ref: str, brain: Brain) -> dict[str, Any]:
    if ref == RULE_ASSIGN:
        return {"ref": ref, "id": ref, "what": "rule: straight to the shared-assignment slot"}
    m = brain.manifest
    tr = m.training if m is not None else {}
    obs = brain.spec.name
    pats = tr.get("patterns") or ([m.pattern] if m is not None and m.pattern else [])
    n = m.n_robots if m is not None else None
    what = (
        f"{tr.get('algorithm', '?')}, {obs} observation, trained on "
        f"{', '.join(str(p) for p in pats) or '?'}"
        + (f" with {n} robots" if n else "")
        + (f", {tr['episodes']} episodes" if "episodes" in tr else "")
        + (f" in {tr['wall_time_s']:.0f} s" if "wall_time_s" in tr else "")
        + (f", fine-tuned from {str(tr['init_brain_id'])[:12]}" if tr.get("init_brain_id") else "")
    )
    return {"ref": _rel(ref), "id": brain.brain_id[:12], "what": what}


# ------------------------------------------------------------ (a) polygons


@dataclass(frozen=True)
class Method:
    key: str
    label: str
    brain: str
    tau: float | None
    """ORCA time horizon (s); None: no filter."""

    @property
    def learned(self) -> bool:
        return self.brain != RULE_ASSIGN


def methods_for(brains: Sequence[str], taus: Sequence[float]) -> list[Method]:
    out = [Method("rule-off", "rule, no filter", RULE_ASSIGN, None)]
    out += [Method(f"rule-orca-{t:g}", f"rule + ORCA({_tau(t)})", RULE_ASSIGN, t) for t in taus]
    for b in brains:
        stem = Path(b).stem
        out.append(Method(f"{stem}-raw", f"{stem} raw", b, None))
        out += [Method(f"{stem}-orca-{t:g}", f"{stem} + ORCA({_tau(t)})", b, t) for t in taus]
    return out


def run_polygons(
    ns: Sequence[int],
    methods: Sequence[Method],
    brains: dict[str, Brain],
    episodes: int,
    seed: int,
) -> dict[tuple[int, str], EvalResult]:
    out: dict[tuple[int, str], EvalResult] = {}
    todo = [(n, m) for n in ns for m in methods if brains[m.brain].spec.accepts_team(n)]
    for k, (n, m) in enumerate(todo, 1):
        safety = OrcaParams(time_horizon_s=m.tau) if m.tau is not None else None
        r = evaluate_brain(brains[m.brain], "circle", n, episodes, seed=seed, safety=safety,
                           progress=False)
        out[(n, m.key)] = r
        _say(f"  [{k}/{len(todo)}] n={n:<3} {m.label:<34} success {_pct(r.success_rate):>8}  "
             f"travel {_x(r.travel_ratio)}  steps {_x(r.steps_ratio)}  ({r.wall_s:.1f} s)")
    return out


def paired_reduction(
    a: EvalResult, b: EvalResult, key: str, boots: int = 2000, seed: int = 0
) -> dict[str, float]:
    """1 - sum(a) / sum(b) of ``key`` over the episodes both formed, and a 95 % bootstrap
    interval (episodes resampled in pairs). Positive: ``a`` needs less than ``b``."""
    fa = np.asarray(a.episode_stats["formed"], bool)
    fb = np.asarray(b.episode_stats["formed"], bool)
    common = fa & fb
    k = int(common.sum())
    if k == 0:
        return {"reduction": math.nan, "lo": math.nan, "hi": math.nan, "episodes": 0}
    xa = np.asarray(a.episode_stats[key], float)[common]
    xb = np.asarray(b.episode_stats[key], float)[common]
    red = 1.0 - xa.sum() / xb.sum()
    idx = np.random.default_rng(seed).integers(0, k, (boots, k))
    reds = 1.0 - xa[idx].sum(axis=1) / xb[idx].sum(axis=1)
    lo, hi = np.percentile(reds, [2.5, 97.5])
    return {"reduction": float(red), "lo": float(lo), "hi": float(hi), "episodes": k}


def comparisons(
    res: dict[tuple[int, str], EvalResult],
    ns: Sequence[int],
    methods: Sequence[Method],
    taus: Sequence[float],
) -> list[dict[str, Any]]:
    """Each learned method against the rule baselines, per n, on travel and on steps.

    Against rule + ORCA(tau): the learned brain raw, and behind the filter at the
    same tau. Against the rule without filter (``tau`` None): the learned brain raw
    and behind the filter at the default tau.
    """
    rows = []
    learned = [m for m in methods if m.learned]
    bases: list[tuple[str, float | None]] = [("rule-off", None)]
    bases += [(f"rule-orca-{t:g}", t) for t in taus]
    for n in ns:
        for base_key, t in bases:
            base = res.get((n, base_key))
            if base is None:
                continue
            for m in learned:
                if m.tau is not None and m.tau != (t if t is not None else DEFAULT_TAU):
                    continue
                r = res.get((n, m.key))
                if r is None:
                    continue
                rows.append({
                    "n": n, "baseline": base_key, "tau": t, "method": m.key, "label": m.label,
                    "filter": m.tau is not None,
                    "travel": paired_reduction(r, base, "travel_m"),
                    "steps": paired_reduction(r, base, "steps"),
                })
    return rows


def plot_polygons(
    res: dict[tuple[int, str], EvalResult],
    ns: Sequence[int],
    methods: Sequence[Method],
    png: Path,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [m for m in methods if m.tau is None or m.tau == DEFAULT_TAU]
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.3))
    for m in shown:
        style = "--" if not m.learned else "-"
        marker = "o" if m.tau is None else "s"
        for ax, what in zip(axes, ("travel_ratio", "steps_ratio", "success_rate"), strict=True):
            xs = [n for n in ns if (n, m.key) in res
                  and math.isfinite(getattr(res[(n, m.key)], what))]
            if not xs:
                continue
            ys = [getattr(res[(n, m.key)], what) for n in xs]
            ys = [100 * y if what == "success_rate" else y for y in ys]
            ax.plot(xs, ys, style, marker=marker, ms=4, label=m.label)
    for ax, title, yl in zip(
        axes,
        ("travel / lower bound", "steps / lower bound", "success (formed, no collision)"),
        ("ratio to the lower bound", "ratio to the lower bound", "%"),
        strict=True,
    ):
        ax.set_title(title)
        ax.set_xlabel("n (robots = polygon vertices)")
        ax.set_ylabel(yl)
        ax.set_xticks(list(ns))
        ax.grid(alpha=0.3)
        if "success" not in title:
            ax.axhline(1.0, color="k", lw=0.8)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"n-regular polygons, ORCA time horizon {_tau(DEFAULT_TAU)} where used")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def plot_horizon(comp: list[dict[str, Any]], taus: Sequence[float], png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    comp = [c for c in comp if c["tau"] is not None]
    labels = sorted({(c["method"].rsplit("-orca-", 1)[0], c["filter"]) for c in comp})
    fig, axes = plt.subplots(1, len(taus), figsize=(5 * len(taus), 4.2), squeeze=False,
                             sharey=True)
    for ax, t in zip(axes[0], taus, strict=True):
        lo, hi = PAPER_TRAVEL_CLAIM
        ax.axhspan(100 * lo, 100 * hi, color="tab:red", alpha=0.15, label="paper's claim")
        ax.axhline(0.0, color="k", lw=0.8)
        for stem, filt in labels:
            rows = [c for c in comp if c["tau"] == t and c["filter"] == filt
                    and c["method"].startswith(stem) and c["travel"]["episodes"]]
            if not rows:
                continue
            xs = [c["n"] for c in rows]
            y = [100 * c["travel"]["reduction"] for c in rows]
            err = [[100 * (c["travel"]["reduction"] - c["travel"]["lo"]) for c in rows],
                   [100 * (c["travel"]["hi"] - c["travel"]["reduction"]) for c in rows]]
            name = stem.removesuffix("-raw") + (" + ORCA" if filt else " raw")
            ax.errorbar(xs, y, yerr=err, marker="o", ms=4, capsize=2, label=name)
        ax.set_title(f"vs rule + ORCA, time horizon {_tau(t)}")
        ax.set_xlabel("n")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("travel reduction vs rule + ORCA (%)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------ (b) Fig. 5


def fig5_section(fig5_dir: Path, figures: Path, run_it: bool, quick: bool) -> dict[str, Any]:
    js = fig5_dir / "train_speed.json"
    out: dict[str, Any] = {"dir": _rel(fig5_dir)}
    if run_it:
        ts = _bench("train_speed")
        a = argparse.Namespace(
            algos=["pattern-rl", "ppo"], robots=10, fig5_seeds=1 if quick else 4,
            fig5_obs="paper", fig5_front_end="auto", fig5_patterns=["circle", "cross"],
            fig5_episodes=40 if quick else 150, out_dir=str(fig5_dir), jobs=os.cpu_count() or 1,
        )
        fig5_dir.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        rep = {"fig5": ts.fig5(a), "machine": machine_info()["cpu"]}
        js.write_text(json.dumps(rep, indent=2, allow_nan=False) + "\n")
        out["ran_here_s"] = time.perf_counter() - t0
    if not js.is_file():
        out["missing"] = f"no {_rel(js)}"
        return out
    rep = json.loads(js.read_text())
    f5 = rep.get("fig5")
    if not f5:
        out["missing"] = f"{_rel(js)} has no fig5 block (run with --fig5)"
        return out
    png = Path(f5.get("png", fig5_dir / "fig5.png"))
    if not png.is_absolute():
        png = ROOT / png
    if not png.is_file():
        png = fig5_dir / "fig5.png"
    out["json_mtime"] = datetime.fromtimestamp(js.stat().st_mtime, UTC).strftime(
        "%Y-%m-%d %H:%M UTC")
    out["report"] = {k: v for k, v in f5.items() if k != "png"}
    out["machine"] = rep.get("machine")
    shutil.copyfile(js, figures / "fig5_train_speed.json")  # the numbers quoted, kept beside
    if png.is_file():
        dst = figures / "fig5.png"
        shutil.copyfile(png, dst)
        out["png"] = dst
    else:
        out["missing"] = f"{_rel(js)} names {png}, which is not there"
    return out


# ------------------------------------------------------------ (c) Fig. 6


@dataclass(frozen=True)
class WorldRun:
    tag: str
    label: str
    brain: str
    safety: str


def launch_once(run: WorldRun, pattern: str, robots: int, seed: int, logs: Path) -> dict[str, Any]:
    """One ``patternrl launch`` (world + robot processes over Zenoh); its phase and log."""
    from sim_bridge.log.reader import read_log

    log = logs / f"fig6-{run.tag}-{pattern}.mcap"
    cmd = [sys.executable, "-m", "patternrl.cli", "launch", "--robots", str(robots),
           "--patterns", pattern, "--brains", run.brain, "--safety", run.safety,
           "--seed", str(seed), "--record", str(log), "--force", "--json", "--no-plot"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, check=False)
    wall = time.perf_counter() - t0
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"launch failed ({p.returncode}): {p.stderr.strip()[-600:]}")
    d = json.loads(lines[-1])
    (phase,) = d["phases"]
    cmds = read_log(log).commands
    total, changed = len(cmds.step), int(cmds.safety_changed.sum())
    return {"phase": phase, "log": log, "wall_s": wall, "exit": p.returncode,
            "commands": total, "filter_share": changed / max(total, 1),
            "brain": run.brain if run.brain == RULE_ASSIGN else _rel(run.brain),
            "brain_id": d["brains"][pattern]["brain_id"][:12]}


def fig6_brain(pattern: str, brains_dir: Path, fallback: str) -> str:
    """The per-pattern general brain ``<dir>/<pattern>-10-general.onnx`` if there, else
    ``fallback``."""
    p = brains_dir / f"{pattern}-10-general.onnx"
    return str(p) if p.is_file() else fallback


def run_fig6(
    fallback: str, brains_dir: Path, robots: int, seed: int, logs: Path, png: Path
) -> list[dict[str, Any]]:
    from sim_bridge.log.plots import draw_trajectories, phase_tracks
    from sim_bridge.log.reader import read_log
    from sim_bridge.log.report import analyse

    logs.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    tracks = []
    for tag, label, safety in (("learned", "learned, raw", "off"),
                               ("learned-orca", "learned + ORCA", "orca"),
                               ("rule-orca", "rule + ORCA", "orca")):
        for pattern in FIG6_PATTERNS:
            brain = RULE_ASSIGN if tag == "rule-orca" else fig6_brain(pattern, brains_dir,
                                                                      fallback)
            r = launch_once(WorldRun(tag, label, brain, safety), pattern, robots, seed, logs)
            r.update(tag=tag, label=label, pattern=pattern, safety=safety)
            rows.append(r)
            ph = r["phase"]
            _say(f"  fig6 {label:<15} {pattern:<9} formed={ph['formed']} steps {ph['steps']} "
                 f"(bound {ph['lower_bound_steps']}), collisions {ph['collisions']} "
                 f"({r['wall_s']:.1f} s)")
            data = read_log(r["log"])
            for tr in phase_tracks(analyse(data), data):
                tr.pattern = f"{pattern}, {label}"
                tracks.append(tr)
    draw_trajectories(tracks, png, title=f"{robots} robots from the same seeded starts "
                                         f"(seed {seed}); world over Zenoh, lockstep")
    return rows


# ------------------------------------------------------------ (d) latency


def run_latency(brain_ref: str, brain: Brain, samples: int) -> dict[str, Any]:
    rl = _bench("runtime_latency")
    from runtime.brain.brain import RuleBrain

    rows = []
    for name, b in ((Path(brain_ref).stem, brain), (RULE_ASSIGN, RuleBrain())):
        for safety in (None, OrcaParams()):
            r = rl.decision_latency(b, 10, samples, safety)
            r.update(brain=name, safety="orca" if safety else "off")
            rows.append(r)
            _say(f"  latency {name:<24} {r['safety']:<5} p50 {r['p50_us']:.1f} us  "
                 f"p99 {r['p99_us']:.1f} us  mean {r['mean_us']:.1f} us")
    x = np.zeros((1, brain.spec.dim), np.float32)
    ts = []
    for _ in range(samples):
        t = time.perf_counter_ns()
        brain.act(x)
        ts.append((time.perf_counter_ns() - t) / 1000.0)
    return {"rows": rows, "onnx_alone_p50_us": float(np.percentile(ts, 50)),
            "onnx_alone_p99_us": float(np.percentile(ts, 99)), "samples": samples}


# ------------------------------------------------------------ the document


def _span(v: Sequence[float], fmt: Callable[[float], str]) -> str:
    v = [x for x in v if math.isfinite(x)]
    if not v:
        return "-"
    lo, hi = fmt(min(v)), fmt(max(v))
    return lo if lo == hi else f"{lo} to {hi}"


def _headline(
    comp: list[dict[str, Any]],
    res: dict[tuple[int, str], EvalResult],
    ns: Sequence[int],
    methods: Sequence[Method],
    taus: Sequence[float],
    episodes: int,
) -> list[str]:
    lines: list[str] = []
    lo_c, hi_c = PAPER_TRAVEL_CLAIM
    stems = [m.key.removesuffix("-raw") for m in methods if m.learned and m.tau is None]
    if not stems:
        return ["- No learned brain was evaluated."]
    span_n = f"n = {ns[0]}..{ns[-1]}" if len(ns) > 1 else f"n = {ns[0]}"
    lines.append(f"Paper (IV.D): Pattern-RL travels {100 * lo_c:.1f} % to {100 * hi_c:.1f} % "
                 "less than its rule-based NH-ORCA baseline on n-regular polygons, n = 4 to 20 "
                 "(the abstract says time steps). Measured here on the same starts, "
                 f"{span_n}, {episodes} episodes per n: the learned brain's reduction against "
                 "each baseline, lowest to highest over n (positive = the learned brain needs "
                 "less; a brain behind the filter meets rule + ORCA at the same tau, and the rule "
                 f"without filter at {_tau(DEFAULT_TAU)}):")
    lines.append("")
    head = ["learned brain", "measure"] + [f"vs rule + ORCA({_tau(t)})" for t in taus]
    head.append("vs rule, no filter")
    rows, idle = [], []
    for stem in stems:
        if not any(c["travel"]["episodes"] for c in comp if c["method"].startswith(stem + "-")):
            idle.append(stem)
            continue
        for filt in (False, True):
            for what in ("travel", "steps"):
                row = [f"`{stem}`" + (" + ORCA" if filt else " raw"), what]
                for t in [*taus, None]:
                    v = [c[what]["reduction"] for c in comp if c["tau"] == t
                         and c["filter"] == filt and c["method"].startswith(stem + "-")]
                    row.append(_span(v, _pct))
                rows.append(row)
    if rows:
        lines += [md_table(head, rows), ""]
    reach = [c for c in comp if c["tau"] is not None
             and math.isfinite(c["travel"]["reduction"]) and c["travel"]["reduction"] >= lo_c]
    if reach:
        where = []
        for t in taus:
            for filt in (False, True):
                hit = sorted({c["n"] for c in reach if c["tau"] == t and c["filter"] == filt})
                if hit:
                    where.append(f"tau {_tau(t)}{' with the filter' if filt else ' raw'}: "
                                 f"n = {', '.join(map(str, hit))}")
        lines.append(f"- Travel reductions of {100 * lo_c:.1f} % or more (the paper's range) "
                     f"occur only against rule + ORCA at " + "; ".join(where) + ".")
    else:
        best = max((c for c in comp if c["tau"] is not None
                    and math.isfinite(c["travel"]["reduction"])),
                   key=lambda c: c["travel"]["reduction"], default=None)
        if best is not None:
            lines.append(f"- No comparison reaches the paper's range; the largest travel "
                         f"reduction is {_pct(best['travel']['reduction'])} ({best['label']} vs "
                         f"rule + ORCA({_tau(best['tau'])}), n = {best['n']}).")
    for stem in idle:
        evs = [r for (n, k), r in res.items() if k.startswith(stem + "-")]
        has = sorted({r.n_robots for r in evs})
        formed = sum(round(r.formed_rate * r.episodes) for r in evs)
        lines.append(f"- `{stem}` (n = {', '.join(map(str, has))}) formed {formed} of "
                     f"{sum(r.episodes for r in evs)} episodes over its {len(evs)} runs "
                     "(raw and filtered): nothing to compare.")
    lines.append("")
    lines.append(f"Against the physical limit (ORCA time horizon {_tau(DEFAULT_TAU)}), "
                 f"{span_n}, lowest to highest over n:")
    lines.append("")
    keys = [(f"{s}-raw", f"`{s}` raw") for s in stems if s not in idle]
    keys += [(f"{s}-orca-{DEFAULT_TAU:g}", f"`{s}` + ORCA") for s in stems if s not in idle]
    keys += [(f"rule-orca-{DEFAULT_TAU:g}", "rule + ORCA"), ("rule-off", "rule, no filter")]
    for key, what in keys:
        evs = [res[(n, key)] for n in ns if (n, key) in res]
        if not evs:
            continue
        coll = sum(r.collisions_per_episode for r in evs) / len(evs)
        lines.append(
            f"- {what}: travel {_span([r.travel_ratio for r in evs], _x)} the lower bound, "
            f"steps {_span([r.steps_ratio for r in evs], _x)}, success "
            f"{_span([r.success_rate for r in evs], _pct)}, "
            f"{_num(coll, 2)} collisions per episode, min separation "
            f"{min(r.min_separation_m for r in evs):.3f} m."
        )
    return lines


def write_doc(ctx: dict[str, Any], path: Path) -> None:
    res: dict[tuple[int, str], EvalResult] = ctx["polygons"]
    ns: list[int] = ctx["ns"]
    methods: list[Method] = ctx["methods"]
    taus: list[float] = ctx["taus"]
    comp: list[dict[str, Any]] = ctx["comparisons"]
    episodes, seed = ctx["episodes"], ctx["seed"]
    mach, L = ctx["machine"], []
    L += ["# Pattern-RL: the paper's experiments, rerun", ""]
    L += ["Written by `benchmarks/paper_experiments.py` (do not edit by hand); every number "
          "below comes from the run described under *How this was run*, except the learning "
          "curves of (b), read from the trainer's benchmark output named there.", ""]
    if ctx["quick"]:
        L += ["**This is a `--quick` run: few episodes and team sizes, for checking the script. "
              "Run without `--quick` for the figures to quote.**", ""]
    L += ["## Headline", ""]
    L += _headline(comp, res, ns, methods, taus, episodes)
    lat = ctx.get("latency")
    if lat:
        r = next(x for x in lat["rows"] if x["safety"] == "orca" and x["brain"] != RULE_ASSIGN)
        L.append("")
        L.append(f"One decision of the learned brain with the filter (10 robots): mean "
                 f"{r['mean_us']:.1f} us, p99 {r['p99_us']:.1f} us; the paper reports "
                 f"{PAPER_LATENCY_MS} ms on average.")
    L += [""]

    # ---- how
    L += ["## How this was run", ""]
    L += ["```sh", ctx["command"], "```", ""]
    load_end = ", ".join(f"{x:.2f}" for x in mach["load_avg_end"])
    load_start = ", ".join(f"{x:.2f}" for x in mach["load_avg_start"])
    L += [md_table(("", ""), [
        ("date", ctx["date"]),
        ("commit", f"{ctx['git']['commit']}" + (" (with local changes)" if ctx["git"]["dirty"]
                                                 else "")),
        ("machine", f"{mach['cpu']}, {mach['cpus']} CPUs ({mach['cpus_usable']} usable), "
                    f"{mach['memory_gb']} GB; {mach['os']}"),
        ("software", f"Python {mach['python']}, numpy {mach['numpy']}, onnxruntime "
                     f"{mach['onnxruntime']}"),
        ("load average (1, 5, 15 min)", f"{load_start} at start; {load_end} at end"),
        ("wall time", f"{ctx['wall_s']:.0f} s in all: " + ", ".join(
            f"{k} {v:.0f} s" for k, v in ctx["section_s"].items())),
        ("seeds", f"polygons: world seed {seed} (episode e = env e of BatchWorld({seed})), "
                  f"{episodes} episodes per n and method; trajectories: start seed "
                  f"{ctx['fig6_seed']}; bootstrap: seed 0, 2000 resamples"),
        ("world", f"R = {W.radius_m} m, v_max = {W.v_max_mps} m/s, dt = {W.dt_s} s, arena "
                  f"{W.arena_m} m, formed within {W.formed_tol_m} m of every slot, step limit "
                  f"{W.step_limit}"),
    ]), ""]
    L += ["Brains:", ""]
    L += [md_table(("brain", "id", "what it is"),
                   [(f"`{b['ref']}`", f"`{b['id']}`", b["what"]) for b in ctx["brains"]]), ""]

    # ---- (a)
    L += ["## (a) n-regular polygons (paper IV.D; Fig. 4-6 setting)", ""]
    L += [
        "n robots form the regular n-gon (the `circle` pattern, side 4R) from uniform random "
        "starts in the arena. Methods, all deciding through the robot's own pipeline "
        "(`runtime.decision.pipeline.decide_batch`, as `patternrl eval` runs them):", "",
        "- **rule, no filter**: `rule:assign --safety off`, straight to the shared-assignment "
        "slot at v_max (CAPT-style);",
        "- **rule + ORCA(tau)**: `rule:assign --safety orca`, the same slots reached through "
        "ORCA with time horizon tau: the holonomic stand-in for the paper's NH-ORCA "
        "baseline (the paper's problem is holonomic, eq. 2, as is this world);",
        "- **<brain> raw**: a learned brain alone, as in the paper;",
        "- **<brain> + ORCA(tau)**: the learned brain behind the safety filter, as shipped.",
        "",
        "Success = formed within the step limit with no collision. Steps and travel are means "
        "over formed episodes of the ratio to the episode's lower bounds (steps: bottleneck "
        "distance / (v_max dt); travel: min over translation and assignment of the summed "
        "straight distances). Min separation: the closest approach of two centres along the "
        "commanded straight moves over every step and episode (below 2R = "
        f"{2 * W.radius_m:g} m is a collision). Collisions: colliding pairs counted every step "
        "(a pair that stays in contact for k steps counts k times), per episode. Filter: share "
        "of robot-steps whose command the filter changed.", "",
    ]
    main = [m for m in methods if m.tau is None or m.tau == DEFAULT_TAU]
    metric_tables: list[tuple[str, Callable[[EvalResult], str]]] = [
        ("Success rate", lambda r: _pct(r.success_rate)),
        ("Travel / lower bound", lambda r: _x(r.travel_ratio)),
        ("Steps / lower bound", lambda r: _x(r.steps_ratio)),
        ("Collisions per episode", lambda r: _num(r.collisions_per_episode, 2)),
        ("Min separation (m)", lambda r: _num(r.min_separation_m, 3)),
        ("Filter changed the command (share of robot-steps)",
         lambda r: _pct(r.safety_interventions) if r.safety == "orca" else "-"),
    ]
    for title, fmt in metric_tables:
        rows = [[str(n)] + [fmt(res[(n, m.key)]) if (n, m.key) in res else "n/a" for m in main]
                for n in ns]
        L += [f"**{title}** (ORCA time horizon {_tau(DEFAULT_TAU)})", ""]
        L += [md_table(["n"] + [m.label for m in main], rows), ""]
    L += ["![polygons](figures/polygons.png)", ""]

    # ---- the paper's claim and the time horizon
    lo_c, hi_c = PAPER_TRAVEL_CLAIM
    L += ["### Against the paper's claim, and how ORCA's time horizon moves it", ""]
    L += [
        f"The paper reports {100 * lo_c:.1f} % to {100 * hi_c:.1f} % less travel than NH-ORCA "
        "for n = 4 to 20 (IV.D; the abstract says time steps). Below: 1 - (sum of the learned "
        "method's travel) / (sum of rule + ORCA's travel) over the episodes both formed, "
        "paired on the same starts, with a 95 % bootstrap interval; the same for steps. "
        "Positive means the learned brain needs less. A learned brain with the filter is "
        "compared at the baseline's own tau. Last, the same against the rule without "
        "filter.", "",
    ]
    for t in [*taus, None]:
        rows = []
        for n in ns:
            for c in (c for c in comp if c["n"] == n and c["tau"] == t):
                tv, sv = c["travel"], c["steps"]
                if not tv["episodes"]:
                    continue
                rows.append([str(n), c["label"],
                             f"{_pct(tv['reduction'])} [{_pct(tv['lo'])}, {_pct(tv['hi'])}]",
                             f"{_pct(sv['reduction'])} [{_pct(sv['lo'])}, {_pct(sv['hi'])}]",
                             str(tv["episodes"])])
        bkey = "rule-off" if t is None else f"rule-orca-{t:g}"
        bname = "rule, no filter (CAPT-style)" if t is None else f"rule + ORCA, tau = {_tau(t)}"
        base = [res.get((n, bkey)) for n in ns]
        L += [f"**Against {bname}**: its success "
              + ", ".join(f"n={n} {_pct(b.success_rate)}" for n, b in zip(ns, base, strict=True)
                          if b is not None)
              + "; travel / lower bound "
              + ", ".join(f"n={n} {_x(b.travel_ratio)}" for n, b in zip(ns, base, strict=True)
                          if b is not None), ""]
        L += [md_table(("n", "learned method", "travel reduction [95 %]",
                        "steps reduction [95 %]", "episodes"), rows), ""]
        gone = sorted({c["label"] for c in comp if c["tau"] == t and not c["travel"]["episodes"]})
        if gone:
            L += ["Left out (no episode formed by both): " + ", ".join(gone) + ".", ""]
    L += ["![ORCA time horizon](figures/orca_horizon.png)", ""]

    # ---- (b)
    f5 = ctx["fig5"]
    L += ["## (b) Learning curves, Pattern-RL vs standard PPO (paper IV.C, Fig. 5)", ""]
    regen = ("`.venv/bin/python benchmarks/train_speed.py --skip-speed --fig5 --fig5-obs paper "
             "--fig5-seeds 4 --fig5-episodes 150 --jobs 2 --out-dir benchmarks/results`, then "
             "this script with "
             "`--fig5-dir benchmarks/results` (or this script with `--fig5-run`)")
    if "png" in f5:
        L += [f"From `benchmarks/train_speed.py --fig5` (the trainer's benchmark), read from "
              f"`{f5['dir']}/train_speed.json` (copied to `figures/fig5_train_speed.json`; "
              f"written {f5['json_mtime']}"
              + (f", on {f5['machine']}" if f5.get("machine") else "") + "); this script did "
              + ("run it" if "ran_here_s" in f5 else "not run the training itself") + ".", ""]
        rep = f5["report"]
        fr = rep.get("final_reward", {})
        if fr:
            L += [md_table(("pattern / algorithm", "mean episode reward at the end"),
                           [(k, _num(v, 2)) for k, v in fr.items()]), ""]
            for pat in dict.fromkeys(k.split("/")[0] for k in fr):
                a, b = fr.get(f"{pat}/pattern-rl"), fr.get(f"{pat}/ppo")
                if a is None or b is None:
                    continue
                who = "Pattern-RL" if a > b else "standard PPO"
                L += [f"- {pat}: {who} ends higher ({_num(max(a, b), 2)} vs "
                      f"{_num(min(a, b), 2)}); the paper reports Pattern-RL higher in each "
                      "iteration."]
            L += [""]
        extra = {k: v for k, v in rep.items() if k != "final_reward"}
        if extra:
            L += ["Benchmark settings and figures as it reported them: `"
                  + json.dumps(extra, allow_nan=False)[:1500] + "`", ""]
        L += ["![Fig. 5](figures/fig5.png)", ""]
        L += [f"To regenerate: {regen}.", ""]
    else:
        L += [f"Not available in this run: {f5.get('missing')}. To produce it: {regen}.", ""]

    # ---- (c)
    L += ["## (c) Trajectories: circle, heart, line, triangle (paper IV.E, Fig. 6)", ""]
    f6 = ctx.get("fig6")
    if f6:
        L += [
            f"Real runs: `patternrl launch` (the pymunk world and {ctx['fig6_robots']} "
            "`patternrl robot` processes over Zenoh on loopback, lockstep), one run per "
            f"pattern and method, every run from the same seeded starts (seed "
            f"{ctx['fig6_seed']}). Figure and table are read from the runs' MCAP logs and the "
            "world's results. Colliding pairs and min separation are the world's, measured on "
            "the pymunk positions.", "",
        ]
        rows = []
        for r in f6:
            ph = r["phase"]
            bid = "" if r["brain"] == RULE_ASSIGN else f" ({r['brain_id'][:8]})"
            rows.append([ph["pattern"], r["label"], f"`{r['brain']}`{bid}",
                         "yes" if ph["formed"] else "NO",
                         f"{ph['steps']} / {ph['lower_bound_steps']}",
                         _x(ph["steps"] / max(ph["lower_bound_steps"], 1)),
                         f"{ph['travel_m']:.2f} / {ph['lower_bound_travel_m']:.2f}",
                         _x(ph["travel_m"] / max(ph["lower_bound_travel_m"], 1e-9)),
                         str(ph["collisions"]), f"{ph['min_separation_m']:.3f}",
                         _pct(r["filter_share"]) if r["safety"] == "orca" else "-"])
        L += [md_table(("pattern", "method", "brain", "formed", "steps / bound", "ratio",
                        "travel m / bound", "ratio", "collisions", "min sep m", "filter"),
                       rows), ""]
        L += ["![Fig. 6](figures/fig6.png)", ""]
        L += [f"The logs are in `{ctx['logs']}` (not committed); replay one with "
              "`patternrl replay --plot <log>`.", ""]
    else:
        L += ["Skipped in this run (`--skip-world`).", ""]

    # ---- (d)
    L += ["## (d) Per-decision latency (paper IV.B: 1.2 ms on average)", ""]
    if lat:
        L += [
            "`benchmarks/runtime_latency.py`'s `decision_latency`: 10 robots, each deciding "
            "with its own `Controller` (shared assignment + observation + brain + filter) "
            f"while the team forms a circle; {lat['samples']} decisions per row, wall clock, "
            "one thread, on the machine above under the load above.", "",
        ]
        rows = [[r["brain"], r["safety"], _num(r["mean_us"], 1), _num(r["p50_us"], 1),
                 _num(r["p99_us"], 1), _num(r["cpu_p50_us"], 1),
                 _num(r["best_round_p99_us"], 1),
                 f"{1000 * PAPER_LATENCY_MS / r['mean_us']:.0f}x"] for r in lat["rows"]]
        L += [md_table(("brain", "filter", "mean us", "p50 us", "p99 us", "CPU p50 us",
                        "quietest fifth p99 us", "paper's 1.2 ms / our mean"), rows), ""]
        L += [f"onnxruntime alone, one observation: p50 {lat['onnx_alone_p50_us']:.1f} us, "
              f"p99 {lat['onnx_alone_p99_us']:.1f} us.", ""]
    else:
        L += ["Skipped in this run.", ""]

    # ---- differences
    L += ["## What differs from the paper", "",
          "- Robots are holonomic discs (paper eq. 2), so the baseline is ORCA on the shared "
          "assignment, not NH-ORCA's differential-drive variant; its time horizon is a free "
          "parameter the paper does not give, hence the sweep.",
          "- The learned brains use this project's `general` observation (own slot from the "
          "shared assignment + nearest neighbours) unless the brains table says `paper`; "
          "the slot assignment is shared with the rule baselines, so the comparison isolates "
          "how each method moves to its slot.",
          "- The paper's polygon size and arena are not given; here polygons have side 4R and "
          f"starts are uniform in a {W.arena_m:g} m square, so most of the travel is the "
          "approach to the pattern, which every method does in nearly straight lines.",
          "- The paper's Webots simulation is replaced by the training world for (a) and by "
          "the pymunk world over Zenoh for (c).", ""]
    path.write_text("\n".join(L))


# ------------------------------------------------------------ main


def _ints(s: str) -> list[int]:
    return [int(x) for x in s.split(",") if x.strip()]


def _floats(s: str) -> list[float]:
    return [float(x) for x in s.split(",") if x.strip()]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="small run: n = 4,10,20, 12 episodes, fewer latency samples")
    ap.add_argument("--out", type=Path, default=ROOT / "docs",
                    help="where results.md, results.json and figures/ go (default docs/)")
    ap.add_argument("--brains", default=None,
                    help="learned brains, comma-separated .onnx files (default: those of "
                         f"{', '.join(DEFAULT_BRAINS)} that exist)")
    ap.add_argument("--ns", default=None, help="team sizes (default 4,6,...,20)")
    ap.add_argument("--episodes", type=int, default=None, help="per n and method (default 100)")
    ap.add_argument("--seed", type=int, default=DEFAULT_EVAL_SEED,
                    help=f"world seed of the polygon starts (default {DEFAULT_EVAL_SEED})")
    ap.add_argument("--taus", default="0.5,1,2,5",
                    help="ORCA time horizons, s (default 0.5,1,2,5; 1 is always in)")
    ap.add_argument("--fig5-dir", type=Path, default=ROOT / "benchmarks" / "results",
                    help="train_speed.py --fig5 output (default benchmarks/results)")
    ap.add_argument("--fig5-run", action="store_true", help="run the Fig. 5 training here first")
    ap.add_argument("--fig6-brains-dir", type=Path, default=ROOT / "exports",
                    help="per-pattern general brains <pattern>-10-general.onnx (default "
                         "exports/); missing ones fall back on the first learned brain")
    ap.add_argument("--fig6-seed", type=int, default=1, help="start seed of the world runs")
    ap.add_argument("--fig6-robots", type=int, default=10)
    ap.add_argument("--logs", type=Path, default=ROOT / "runs" / "paper_experiments",
                    help="where the world runs' MCAP logs go (default runs/paper_experiments)")
    ap.add_argument("--skip-world", action="store_true", help="no world runs (section c)")
    ap.add_argument("--latency-samples", type=int, default=None, help="default 6000 (quick 1000)")
    args = ap.parse_args(argv)

    t_start = time.perf_counter()
    cmd = ".venv/bin/python benchmarks/paper_experiments.py" + "".join(
        f" {shlex.quote(a)}" for a in (sys.argv[1:] if argv is None else argv))
    ns = _ints(args.ns) if args.ns else ([4, 10, 20] if args.quick else list(range(4, 21, 2)))
    episodes = args.episodes or (12 if args.quick else 100)
    taus = _floats(args.taus)
    if DEFAULT_TAU not in taus:
        taus = sorted([*taus, DEFAULT_TAU])
    samples = args.latency_samples or (1000 if args.quick else 6000)
    refs = ([b for b in args.brains.split(",") if b] if args.brains
            else [str(ROOT / b) for b in DEFAULT_BRAINS if (ROOT / b).is_file()])
    if not refs:
        print("paper_experiments: no learned brain (give --brains FILE.onnx)", file=sys.stderr)
        return 2
    brains: dict[str, Brain] = {RULE_ASSIGN: load_brain(RULE_ASSIGN)}
    try:
        for r in refs:
            brains[r] = load_brain(r)
    except BrainError as e:
        print(f"paper_experiments: {e}", file=sys.stderr)
        return 2
    general = [r for r in refs if brains[r].spec.needs_slots]
    out: Path = args.out
    figures = out / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    mach = machine_info()
    section_s: dict[str, float] = {}

    _say(f"(a) polygons: n = {ns}, {episodes} episodes, taus {taus}, brains {refs}")
    t0 = time.perf_counter()
    methods = methods_for(refs, taus)
    res = run_polygons(ns, methods, brains, episodes, args.seed)
    comp = comparisons(res, ns, methods, taus)
    plot_polygons(res, ns, methods, figures / "polygons.png")
    plot_horizon(comp, taus, figures / "orca_horizon.png")
    section_s["polygons"] = time.perf_counter() - t0

    _say("(b) Fig. 5")
    t0 = time.perf_counter()
    f5 = fig5_section(args.fig5_dir, figures, args.fig5_run, args.quick)
    section_s["learning curves"] = time.perf_counter() - t0

    f6 = None
    if not args.skip_world:
        _say("(c) Fig. 6: world runs over Zenoh")
        t0 = time.perf_counter()
        fallback = general[0] if general else refs[0]
        f6 = run_fig6(fallback, args.fig6_brains_dir, args.fig6_robots, args.fig6_seed,
                      args.logs, figures / "fig6.png")
        section_s["trajectories"] = time.perf_counter() - t0

    _say("(d) latency")
    t0 = time.perf_counter()
    lat_ref = general[0] if general else refs[0]
    lat = run_latency(lat_ref, brains[lat_ref], samples)
    section_s["latency"] = time.perf_counter() - t0

    mach["load_avg_end"] = [round(x, 2) for x in os.getloadavg()]
    used = dict.fromkeys(refs)  # the brains table: every learned brain that ran
    fig6_refs = sorted({fig6_brain(p, args.fig6_brains_dir, general[0] if general else refs[0])
                        for p in FIG6_PATTERNS}) if f6 else []
    for r in fig6_refs:
        used.setdefault(r)
        if r not in brains:
            brains[r] = load_brain(r)
    ctx: dict[str, Any] = {
        "quick": args.quick, "ns": ns, "episodes": episodes, "seed": args.seed, "taus": taus,
        "methods": methods, "polygons": res, "comparisons": comp, "fig5": f5, "fig6": f6,
        "fig6_seed": args.fig6_seed, "fig6_robots": args.fig6_robots, "logs": _rel(args.logs),
        "latency": lat, "machine": mach, "git": git_state(), "command": cmd,
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "brains": [describe_brain(RULE_ASSIGN, brains[RULE_ASSIGN])]
        + [describe_brain(r, brains[r]) for r in used],
        "section_s": section_s,
    }
    ctx["wall_s"] = time.perf_counter() - t_start
    write_doc(ctx, out / "results.md")
    raw = {
        "command": cmd, "date": ctx["date"], "machine": mach, "git": ctx["git"],
        "wall_s": ctx["wall_s"], "section_s": section_s, "seed": args.seed,
        "episodes": episodes, "brains": ctx["brains"],
        "polygons": [{"method": k, **res[(n, k)].to_dict()} for (n, k) in res],
        "comparisons": comp,
        "fig6": [{k: (str(v) if isinstance(v, Path) else v) for k, v in r.items()}
                 for r in (f6 or [])],
        "latency": lat,
    }
    raw["fig5"] = {k: v for k, v in f5.items() if k != "png"}
    (out / "results.json").write_text(
        json.dumps(_clean(raw), indent=1, allow_nan=False, default=_json_default) + "\n")
    _say(f"wrote {_rel(out / 'results.md')} in {ctx['wall_s']:.0f} s")
    return 0


def _clean(o: Any) -> Any:
    """Non-finite floats as null, recursively (JSON has no NaN)."""
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    return o


def _json_default(o: Any) -> Any:
    if isinstance(o, Path):
        return _rel(o)
    raise TypeError(type(o).__name__)


if __name__ == "__main__":
    sys.exit(main())
