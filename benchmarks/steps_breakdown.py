"""Where a team's steps go under real-world conditions: the way in, the last centimetres, the frame.

For each case (a condition of ``runtime.conditions``, named as in ``benchmarks/conditions.py``)
it runs a brain on the same shapes, seeds and starts as ``benchmarks/conditions.py`` (episode
e of shape s is env e of a world seeded ``--seed + index(s)``) and follows every episode step
by step through ground truth. Per case, over the formed episodes, in units of each episode's
steps lower bound:

* ``steps`` -- steps to the first passage (formed), as ``benchmarks/conditions.py`` prints it;
* ``20 cm`` / ``10 cm`` / ``5 cm`` -- the first step at which every robot lies within that of its
  slot (the team's assignment, in its centroid frame: the world's own test, with a wider
  tolerance);
* ``last 5 cm`` -- steps from the 5 cm mark to formed (the world's 2.5 cm), not over the bound;
* ``plan: enclosing / balanced / centroid`` -- the steps the synchronised plan would take from
  the episode's start in the frame of the smallest enclosing circle, the frame of
  `rule:frame-balanced` (a quarter of the way to the centroid) and the team's centroid frame
  (where the plans land under noise, see docs/conditions.md), at full speed, no one in the way:
  what each frame's geometry costs before any condition does.

On a terminal a bar shows each case and shape as it runs; ``--json`` prints one object (with
each case's curve: the worst way, mean over the formed episodes, on a grid of steps over the
bound), ``--png FILE`` draws those curves.

    .venv/bin/python benchmarks/steps_breakdown.py [--robots 50] [--episodes 10]
        [--cases perfect,combined] [--brain rule:frame-balanced+est] [--from PATTERN] [--json]

``--from PATTERN`` starts every episode with that pattern just formed: a transition from one
pattern of a sequence to the next, as ``patternrl launch`` (the demo) runs them, where the
way is short and every step over the bound weighs more.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.conditions import CASES, SHAPES, split_cases  # noqa: E402 -- path set-up
from runtime.brain.brain import load_brain  # noqa: E402
from runtime.conditions import parse_conditions  # noqa: E402
from runtime.decision.agreement import DEFAULT_AGREE, add_agree_argument  # noqa: E402
from runtime.decision.formation import (  # noqa: E402
    assign_slots,
    assign_slots_batch,
    lower_bounds,
    slot_distances,
)
from runtime.decision.rules import plan_targets  # noqa: E402
from runtime.errors import InputError  # noqa: E402
from runtime.types import Array, BoolArray  # noqa: E402
from trainer.evaluate import evaluate_brain  # noqa: E402

CURVE_X = tuple(round(0.02 * i, 2) for i in range(0, 201))
"""The grid of the curve (steps over the episode's lower bound, 0 to 4) the worst way is
averaged on for ``--png``."""
MARKS_M = (0.2, 0.1, 0.05)
"""The ways to the slot (m) whose first passage by the whole team is timed."""
FRAMES = {"enclosing": 0.0, "balanced": 0.25, "centroid": 1.0}
"""The plan frames whose geometry is counted: their travel weights
(:data:`runtime.decision.rules.FRAME_RULES`)."""


class Follow:
    """Each episode's worst way to a slot, step by step (the ``on_step`` of
    :func:`trainer.evaluate.evaluate_brain`), and its start."""

    def __init__(self) -> None:
        self.worst: list[Array] = []  # per step (E,) m
        self.start: tuple[Array, Array] | None = None  # positions, pattern at step 0

    def __call__(self, pos: Array, pattern: Array, running: BoolArray) -> None:
        if self.start is None:
            self.start = (pos.copy(), pattern.copy())
        slots = assign_slots_batch(pos, pattern)
        self.worst.append(slot_distances(pos, pattern, slots).max(axis=-1))

    def first_within(self, e: int, way_m: float, until: int) -> int:
        """The first step (<= ``until``) at which episode e's worst way is under ``way_m``."""
        for t in range(min(until + 1, len(self.worst))):
            if self.worst[t][e] < way_m:
                return t
        return until


def plan_steps(pos: Array, pattern: Array, weight: float) -> float:
    """Steps the synchronised plan takes from ``pos`` (n, 2) to ``pattern`` in the frame of
    travel weight ``weight``, the squared-distance assignment, nobody in the way."""
    slots = assign_slots(pos, pattern)
    _, k = plan_targets(pos[None], pattern[None], slots[None], weight)
    return float(k[0])


def run_case(brain_name: str, case: str, n: int, episodes: int, seed: int,
             shapes: tuple[str, ...], start: str | None = None, agree: bool | str = DEFAULT_AGREE
             ) -> dict[str, Any]:
    """One case's row (see the module docstring); ``start``: every episode starts with that
    pattern just formed (None: random starts); ``agree``: what the robots tell each other
    (:data:`runtime.decision.agreement.AGREE_MODES`, ``patternrl eval --agree``)."""
    estimator = brain_name.endswith("+est")
    path = brain_name.removesuffix("+est")
    brain = load_brain(str(ROOT / path) if path.endswith(".onnx") else path)
    cond = parse_conditions(CASES.get(case, case))
    sums: dict[str, float] = {"steps": 0.0, "last": 0.0, **{f"{m}": 0.0 for m in MARKS_M},
                              **{k: 0.0 for k in FRAMES}}
    formed_count = total = 0
    curve = np.zeros(len(CURVE_X))
    for k, shape in enumerate(shapes):
        follow = Follow()
        r = evaluate_brain(brain, shape, n, episodes, seed=seed + k, conditions=cond,
                           estimator=estimator, progress=None, label=f"{case} {shape}",
                           on_step=follow, start_pattern=start,
                           agree=agree)  # a bar on a terminal only
        st = r.episode_stats
        assert follow.start is not None
        pos0, pat0 = follow.start
        for e in range(episodes):
            total += 1
            if not st["formed"][e]:
                continue
            formed_count += 1
            steps, lb = int(st["steps"][e]), float(st["lower_bound_steps"][e])
            sums["steps"] += steps / lb
            marks = [follow.first_within(e, m, steps) for m in MARKS_M]
            for m, t in zip(MARKS_M, marks, strict=True):
                sums[f"{m}"] += t / lb
            sums["last"] += steps - marks[-1]
            way = [float(follow.worst[t][e]) for t in range(steps + 1)]
            curve += np.interp(CURVE_X, np.arange(steps + 1) / lb, way, right=way[-1])
            _, bound = lower_bounds(pos0[e], pat0[e])
            for name, w in FRAMES.items():
                sums[name] += plan_steps(pos0[e], pat0[e], w) / max(bound, 1)
    f = max(formed_count, 1)
    row: dict[str, Any] = {
        "brain": brain_name, "case": case, "conditions": cond.name(), "robots": n,
        "start": start or "random", "episodes": total, "formed": formed_count / max(total, 1),
        "steps_ratio": sums["steps"] / f if formed_count else math.nan,
        "within_m": {f"{m}": sums[f"{m}"] / f if formed_count else math.nan
                     for m in MARKS_M},
        "last_5cm_steps": sums["last"] / f if formed_count else math.nan,
        "plan_frames": {k: sums[k] / f if formed_count else math.nan for k in FRAMES},
        "curve": {"x": list(CURVE_X),
                  "worst_way_m": (curve / f).round(4).tolist() if formed_count else []},
    }
    return row


def plot(rows: list[dict[str, Any]], path: Path, title: str) -> None:
    """Each case's worst way to a slot (mean over its formed episodes) against the steps over
    each episode's lower bound, the 20/10/5 cm marks and the bound, into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=120)
    last = 1.0
    for r in rows:
        y = r["curve"]["worst_way_m"]
        if not y:
            continue
        ax.plot(r["curve"]["x"], y, label=f"{r['case']} (formed at {r['steps_ratio']:.3f}x)")
        last = max(last, r["steps_ratio"])
    for m in MARKS_M:
        ax.axhline(m, color="grey", lw=0.6, ls=":")
    ax.axvline(1.0, color="black", lw=0.8, ls="--", label="the lower bound")
    ax.set_xlim(0.0, min(CURVE_X[-1], 1.15 * last))
    ax.set_yscale("log")
    ticks = [0.01, 0.025, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0]
    ax.set_yticks(ticks, [f"{t:g}" for t in ticks])
    ax.minorticks_off()
    ax.set_ylim(0.01, None)
    ax.set_xlabel("steps over the episode's lower bound")
    ax.set_ylabel("worst robot's way to its slot (m, mean)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def format_rows(rows: list[dict[str, Any]]) -> str:
    """The rows as a table (figures over each episode's steps lower bound)."""
    head = ("case", "formed", "steps", "20 cm", "10 cm", "5 cm", "last 5 cm",
            "plan: enclosing / balanced / centroid")
    lines = [head]
    for r in rows:
        w = r["within_m"]
        pf = r["plan_frames"]
        lines.append((
            r["case"], f"{100 * r['formed']:.0f} %", f"{r['steps_ratio']:.3f}",
            *(f"{w[f'{m}']:.3f}" for m in MARKS_M), f"{r['last_5cm_steps']:.2f} steps",
            " / ".join(f"{pf[k]:.3f}" for k in FRAMES)))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return "\n".join("  ".join(c.ljust(wd) for c, wd in zip(line, widths, strict=True)).rstrip()
                     for line in lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=50, help="team size (default 50)")
    p.add_argument("--episodes", type=int, default=10, help="episodes per shape (default 10)")
    p.add_argument("--seed", type=int, default=3_000_000, help="world seed (default 3000000)")
    p.add_argument("--cases", default="perfect,combined",
                   help="comma-separated case names of benchmarks/conditions.py or presets, "
                        "or ';'-separated condition specs (default perfect,combined)")
    p.add_argument("--brain", default="rule:frame-balanced+est",
                   help="a brain (rule or .onnx path); '+est' decides on the peer tracker's "
                        "estimates (default rule:frame-balanced+est)")
    p.add_argument("--shapes", default=",".join(SHAPES), help="comma-separated shapes")
    add_agree_argument(p)
    p.add_argument("--from", dest="start", metavar="PATTERN",
                   help="start every episode with this pattern just formed: the transition "
                        "from it, as in a launch's sequence (default: random starts)")
    p.add_argument("--png", type=Path, metavar="FILE",
                   help="also draw each case's worst way to a slot against the steps over the "
                        "lower bound into FILE")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    a = p.parse_args(argv)
    if a.robots < 2 or a.episodes < 1:
        print("steps_breakdown: --robots must be >= 2 and --episodes >= 1", file=sys.stderr)
        return 2
    shapes = tuple(s.strip() for s in a.shapes.split(",") if s.strip())
    try:
        rows = [run_case(a.brain, c, a.robots, a.episodes, a.seed, shapes, a.start, a.agree)
                for c in split_cases(a.cases)]
    except (InputError, ValueError, FileNotFoundError) as err:
        print(f"steps_breakdown: {err}", file=sys.stderr)
        return 2
    title = (f"{a.brain}, {a.robots} robots, {a.episodes} per shape ({', '.join(shapes)}), "
             f"{'from ' + a.start + ' formed' if a.start else 'random starts'}")
    if a.png is not None:
        plot(rows, a.png, title)
    if a.json:
        print(json.dumps({"robots": a.robots, "episodes_per_shape": a.episodes,
                          "seed": a.seed, "brain": a.brain, "start": a.start or "random",
                          "agree": a.agree,
                          "rows": rows}, indent=1))
    else:
        print(f"{a.brain}, {a.robots} robots, {a.episodes} episodes per shape "
              f"({', '.join(shapes)}), seed {a.seed}, "
              f"{'from ' + a.start + ' formed' if a.start else 'random starts'}"
              f"{'' if a.agree == DEFAULT_AGREE else f', --agree {a.agree}'}; figures over each "
              "episode's steps "
              f"lower bound")
        print(format_rows(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
