"""Every brain and rule against the efficiency frontier of the two lower bounds.

A team cannot both land in the fewest steps and travel the fewest metres: the
two lower bounds (DESIGN.md section 1) are met by different plans. This script
measures where each brain sits, as ``patternrl eval`` measures it
(:func:`trainer.evaluate.evaluate_brain`: the training world and the robot's
own :func:`runtime.decision.pipeline.decide_batch`, ORCA filter on with its defaults),
on 4 built-in patterns (circle, cross, heart, triangle) and random shapes, for
teams of 7, 13, 25 and 50. Episode ``e`` of a team size ``n`` is the first
episode of env ``e`` of a world seeded with ``--seed + n``: every brain sees
the same starts (and, for random shapes, the same shapes).

Per case and brain: success (formed, no collision), steps / lower bound and
travel / lower bound (means over formed episodes). Per brain: the mean of the
ratios over the cases, the worst success, the collisions.

The frontier. Straight-line plans in one frame fixed per pattern, every robot
arriving at the same step (:func:`runtime.decision.rules.frame_plan`), with the frame
slid from the one of fewest steps (``travel_weight`` 0, ``rule:frame``) to the
team's centroid (1, ``rule:frame-travel``), run on the same starts without the
filter: the curve they trace in (steps ratio, travel ratio) is the reference
frontier of the plot ``docs/figures/frontier.png``, where every brain's mean
point is marked.

Learned brains are compared with the best rule case by case: the rule whose
steps + travel ratios are least in that case (with the filter). A brain "holds"
a case when both its ratios are within 0.02 of that rule's. A brain whose
manifest names a built-in pattern (``exports/circle-10-general.onnx``) runs only
that pattern's cases: its summary is over those.

    .venv/bin/python benchmarks/frontier.py [--brain exports/general.onnx ...]
        [--episodes 6] [--quick] [--json] [--plot docs/figures/frontier.png]

A default run takes a few minutes on 2 cores (most of it the 50-robot cases);
``--quick``: n = 7 and 13, 3 episodes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.brain.brain import RULES, Brain, BrainError, load_brain  # noqa: E402 -- path set-up
from runtime.decision.rules import FrameRule  # noqa: E402
from runtime.decision.safety import OrcaParams  # noqa: E402
from trainer.evaluate import evaluate_brain  # noqa: E402

PATTERNS = ("circle", "cross", "heart", "triangle", "random")
TEAMS = (7, 13, 25, 50)
QUICK_TEAMS = (7, 13)
FRONTIER_WEIGHTS = (0.0, 0.25, 0.5, 0.75, 1.0)
DEFAULT_SEED = 424242
HOLD_TOL = 0.02
DEFAULT_PLOT = ROOT / "docs" / "figures" / "frontier.png"


@dataclass
class Cell:
    success: float
    steps: float
    travel: float
    collisions: int


def label(ref: str) -> str:
    return ref if ref.startswith("rule:") else Path(ref).stem


def run_case(brain: Brain, pattern: str, n: int, episodes: int, seed: int,
             safety: OrcaParams | None) -> Cell:
    r = evaluate_brain(brain, pattern, n, episodes, seed=seed + n, safety=safety, progress=False)
    return Cell(r.success_rate, r.steps_ratio, r.travel_ratio, r.collisions)


def own_pattern(brain: Brain) -> str | None:
    """The built-in pattern a brain's manifest carries, if it is one of :data:`PATTERNS`."""
    m = getattr(brain, "manifest", None)
    p = getattr(m, "pattern", None)
    return p if isinstance(p, str) and p in PATTERNS and p != "random" else None


def mean(xs: list[float]) -> float:
    ok = [x for x in xs if not math.isnan(x)]
    return float(np.mean(ok)) if ok else math.nan


def plot(path: Path, frontier: list[tuple[float, float, float]],
         points: dict[str, tuple[float, float]], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    xs = [f[1] for f in frontier]
    ys = [f[2] for f in frontier]
    ax.plot(xs, ys, "-", color="0.5", lw=1.5, label="straight-line plans, fixed frame (no filter)")
    for w, x, y in frontier:
        ax.annotate(f"w={w:g}", (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7,
                    color="0.4")
    markers = "osD^v<>p*h"
    for k, (name, (x, y)) in enumerate(points.items()):
        ax.plot([x], [y], markers[k % len(markers)], ms=8, label=f"{name} + ORCA")
    ax.plot([1.0], [1.0], "k+", ms=10, label="both lower bounds (unreachable)")
    ax.set_xlabel("steps / lower bound (mean over cases)")
    ax.set_ylabel("travel / lower bound (mean over cases)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best", framealpha=0.9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--brain", action="append", default=None,
                    help="a brain (.onnx or rule:NAME) to add; repeatable "
                         "(default: every rule and exports/general.onnx)")
    ap.add_argument("--episodes", type=int, default=6, help="episodes per case (default 6)")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED,
                    help=f"world seed; team size n uses seed + n (default {DEFAULT_SEED})")
    ap.add_argument("--quick", action="store_true", help="n = 7 and 13, 3 episodes")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--plot", default=str(DEFAULT_PLOT),
                    help=f"where to write the plot (default {DEFAULT_PLOT.relative_to(ROOT)}; "
                         "'none' for no plot)")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        print("frontier: --episodes must be >= 1", file=sys.stderr)
        return 2
    episodes = 3 if args.quick else args.episodes
    teams = QUICK_TEAMS if args.quick else TEAMS
    refs = list(RULES)
    general = ROOT / "exports" / "general.onnx"
    if args.brain:
        refs += [b for b in args.brain if b not in refs]
    elif general.is_file():
        refs.append(str(general.relative_to(ROOT)))
    try:
        brains = {label(r): load_brain(r) for r in refs}
    except BrainError as e:
        print(f"frontier: {e}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    cases = [(p, n) for n in teams for p in PATTERNS]
    safety = OrcaParams()
    table: dict[str, dict[str, Cell]] = {name: {} for name in brains}
    own = {name: own_pattern(b) for name, b in brains.items()}
    for p, n in cases:
        for name, b in brains.items():
            if own[name] in (None, p):
                table[name][f"{p}-{n}"] = run_case(b, p, n, episodes, args.seed, safety)
    frontier = []
    for w in FRONTIER_WEIGHTS:
        rule = FrameRule("rule:frame", travel_weight=w)
        cells = [run_case(rule, p, n, episodes, args.seed, None) for p, n in cases]
        frontier.append((w, mean([c.steps for c in cells]), mean([c.travel for c in cells])))
    all_keys = [f"{p}-{n}" for p, n in cases]
    rules = [k for k in brains if k.startswith("rule:")]
    best_rule = {
        k: min(rules, key=lambda r: table[r][k].steps + table[r][k].travel) for k in all_keys
    }
    summary: dict[str, dict[str, Any]] = {}
    for name in brains:
        row = table[name]
        keys = [k for k in all_keys if k in row]
        s: dict[str, Any] = {
            "steps_ratio": mean([row[k].steps for k in keys]),
            "travel_ratio": mean([row[k].travel for k in keys]),
            "worst_success": min(row[k].success for k in keys),
            "collisions": sum(row[k].collisions for k in keys),
        }
        if not name.startswith("rule:"):
            lost = [k for k in keys
                    if not (row[k].steps <= table[best_rule[k]][k].steps + HOLD_TOL
                            and row[k].travel <= table[best_rule[k]][k].travel + HOLD_TOL)]
            s["holds_best_rule"] = f"{len(keys) - len(lost)}/{len(keys)}"
            s["loses_on"] = lost
        summary[name] = s
    wall = time.perf_counter() - t0
    title = (f"{len(cases)} cases (n = {', '.join(map(str, teams))}), {episodes} episodes each, "
             f"seed {args.seed}")
    if args.plot != "none":
        plot(Path(args.plot), frontier,
             {(k if own[k] is None else f"{k} (its {own[k]} cases)"):
              (v["steps_ratio"], v["travel_ratio"]) for k, v in summary.items()}, title)
    if args.json:
        print(json.dumps({
            "episodes": episodes, "seed": args.seed, "teams": list(teams),
            "patterns": list(PATTERNS), "safety": "orca (defaults)",
            "cases": {name: {k: c.__dict__ for k, c in row.items()}
                      for name, row in table.items()},
            "best_rule": best_rule, "summary": summary,
            "frontier": [{"travel_weight": w, "steps_ratio": x, "travel_ratio": y}
                         for w, x, y in frontier],
            "wall_s": wall,
        }, allow_nan=False, default=lambda x: None))
        return 0
    names = list(brains)
    print(f"Frontier: {title}, ORCA on (defaults); steps / travel as ratios to the lower bounds\n")
    print("| case | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for k in all_keys:
        cells = []
        for name in names:
            if k not in table[name]:
                cells.append("-")
                continue
            c = table[name][k]
            mark = "*" if name == best_rule[k] else ""
            ok = "" if c.success == 1.0 else f" ({100 * c.success:.0f} %)"
            cells.append(f"{c.steps:.3f} / {c.travel:.3f}{mark}{ok}")
        print(f"| {k} | " + " | ".join(cells) + " |")
    print("\n(* the best rule of the case; a percentage: success below 100 %)\n")
    print("| brain | steps / lb | travel / lb | worst success | collisions | holds the best rule |")
    print("|---|---|---|---|---|---|")
    for name, s in summary.items():
        print(f"| {name} | {s['steps_ratio']:.3f} | {s['travel_ratio']:.3f} "
              f"| {100 * s['worst_success']:.0f} % | {s['collisions']} "
              f"| {s.get('holds_best_rule', '-')} |")
    print("\nFrontier of straight-line plans (no filter), frame weight w from fewest steps "
          "(0) to the centroid (1):")
    print("  " + ", ".join(f"w={w:g}: {x:.3f} / {y:.3f}" for w, x, y in frontier))
    if args.plot != "none":
        print(f"plot: {args.plot}")
    print(f"wall time {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
