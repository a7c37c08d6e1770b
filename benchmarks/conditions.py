"""Brains and rules under real-world conditions: success, collisions, steps, and whether it holds.

Each case is one condition of ``runtime.conditions`` (noise, latency, local views, loss,
wheels, combined), run as ``patternrl eval --conditions`` runs it: every robot decides on
its own view (:class:`runtime.decision.local.LocalDecisions`), with its own assignment and
plan, the safety filter's margin widened for what it knows of its sensing, and the
world's ground truth judging. Per case and brain (rules alone, rules + estimator, the
shipped general brain), pooled over the shapes and episodes:

* ``success`` -- formed with no collision and held (>= 90 % of the next 20 steps formed), %;
* ``formed`` -- formed at least once (first passage), %;
* ``held`` -- of the formed, the share that held, %;
* ``coll/ep`` -- colliding pairs per episode, the hold window included;
* ``steps`` -- steps to the first passage over the lower bound (mean over formed);
* ``travel`` (``--json`` only) -- metres travelled over the least travel (mean over formed).

``adversary:charge`` (:mod:`trainer.adversary`) drives every robot at full speed at its
nearest peer: it never forms, and its column is the safety filter's alone (collisions).

A brain named ``X+naive`` runs as robots did before they knew their sensing: the safety
filter on the raw views and their frame differences, no widened margin, no damped landing
(the "before" of the README's table); ``X+est`` decides on the peer tracker's estimates.
The robots agree as ``patternrl robot`` does unless told otherwise (``--agree auto``: under
noise every plan goes in the leader's frame, and where views are local and imperfect the
robots tell their slots too, :mod:`runtime.decision.agreement`): ``X+agree`` has them agree
on their slots (``--agree slots``), ``X+frame`` only on the leader's frame (``--agree
frame``), ``X+alone`` tell each other nothing (``--agree off``). Suffixes combine
(``rule:frame-balanced+est+agree``).

Episode e of shape s is env e of a world seeded ``--seed + index(s)``: every brain sees
the same starts and the same sensing noise. A shape ``A>B`` starts every episode with
pattern A just formed and asks for B (``patternrl eval --from A --pattern B``: the demo's
short ways); ``--transitions`` runs the demo's four (circle>cross, cross>line, line>heart,
heart>circle).

    .venv/bin/python benchmarks/conditions.py [--robots 10] [--episodes 20]
        [--cases perfect,noise5,...] [--brains rule:frame-balanced,...] [--json]

``--safety orca-no-guard`` runs every robot's filter without its last-resort guard, and
``--safety off`` the brains raw: not how a robot runs, but where the steps go (the guard bounds
each pair from its last view, against a peer that may have stopped since; docs/conditions.md,
"Late views at n = 50: the guard is the rest").

``--quick``: 4 episodes, circle and heart only.
    .venv/bin/python benchmarks/conditions.py --robots 8 --transitions \
        --cases "realistic,k_nearest=4" --brains rule:frame-balanced+est
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runtime.brain.brain import load_brain  # noqa: E402 -- path set-up
from runtime.conditions import PRESETS, parse_conditions  # noqa: E402
from runtime.decision.agreement import DEFAULT_AGREE  # noqa: E402
from runtime.decision.safety import SAFETY_MODES, safety_params  # noqa: E402
from runtime.errors import InputError  # noqa: E402
from runtime.world_config import DEFAULT_WORLD, WorldConfig  # noqa: E402
from trainer.adversary import ADVERSARY, ChargeBrain  # noqa: E402
from trainer.evaluate import evaluate_brain  # noqa: E402

CASES: dict[str, str] = {
    "perfect": "perfect",
    "noise5": "noise_m=0.05",
    "noise10": "noise_m=0.1",
    "nearest6": "k_nearest=6",
    "range2m": "range_m=2",
    "late1": "latency_steps=1",
    "late2": "latency_steps=2",
    "late3": "latency_steps=3",
    "loss30": "loss=0.3",
    "wheels": "gain_noise=0.1,act_noise_mps=0.02",
    "diff": "kinematics=diff,turn_rate_rps=2",
    "combined": "realistic",
}
SHAPES = ("circle", "cross", "heart", "triangle", "random")
TRANSITIONS = ("circle>cross", "cross>line", "line>heart", "heart>circle")
"""The demo's sequence (``patternrl launch``), each pattern from the one before, formed."""
BRAINS = ("rule:assign", "rule:frame", "rule:frame-balanced", "rule:frame-balanced+est",
          "exports/general.onnx+est", ADVERSARY)


def split_cases(text: str) -> list[str]:
    """The cases of ``--cases``: separated by ';' (``"realistic,loss=0;late3"``), or by ','
    where every part is a case name or a preset (``"late1,late2,combined"``); anything else is
    one condition spec (``"noise_m=0.05,latency_steps=1"``)."""
    if ";" in text:
        return [c.strip() for c in text.split(";") if c.strip()]
    parts = [c.strip() for c in text.split(",") if c.strip()]
    if all(c in CASES or c in PRESETS for c in parts):
        return parts
    return [text.strip()]


def run_case(brain_name: str, case: str, n: int, episodes: int, seed: int,
             shapes: tuple[str, ...], world: WorldConfig = DEFAULT_WORLD,
             safety: str = "orca") -> dict[str, Any]:
    path, *flags = brain_name.split("+")
    unknown = set(flags) - {"est", "naive", "agree", "alone", "frame"}
    if unknown:
        raise SystemExit(f"conditions: unknown suffix +{sorted(unknown)[0]} in {brain_name!r} "
                         "(est, agree, frame, alone, naive)")
    estimator, naive = "est" in flags, "naive" in flags
    agree = ("slots" if "agree" in flags else "off" if "alone" in flags
             else "frame" if "frame" in flags else DEFAULT_AGREE)
    brain = ChargeBrain() if path == ADVERSARY else load_brain(
        str(ROOT / path) if path.endswith(".onnx") else path)
    cond = parse_conditions(CASES.get(case, case))
    tot: dict[str, float] = {"episodes": 0, "ok": 0, "formed": 0, "held": 0, "coll": 0,
                             "steps": 0.0, "travel": 0.0, "wall": 0.0}
    for k, shape in enumerate(shapes):
        start, _, target = shape.rpartition(">")
        r = evaluate_brain(brain, target, n, episodes, seed=seed + k, conditions=cond,
                           estimator=estimator, progress=False, naive=naive, world=world,
                           agree=agree, start_pattern=start or None,
                           safety=safety_params(safety))
        st = r.episode_stats
        formed = [f > 0 for f in st["formed"]]
        held = [h >= 0.9 for h in st["held"]]
        tot["episodes"] += episodes
        tot["ok"] += r.success_rate * episodes
        tot["formed"] += sum(formed)
        tot["held"] += sum(f and h for f, h in zip(formed, held, strict=True))
        tot["coll"] += r.collisions
        tot["steps"] += sum(s / lb for s, lb, f in zip(st["steps"], st["lower_bound_steps"],
                                                      formed, strict=True) if f)
        tot["travel"] += sum(m / lb for m, lb, f in zip(st["travel_m"], st["lower_bound_travel_m"],
                                                        formed, strict=True) if f)
        tot["wall"] += r.wall_s
    e, f = tot["episodes"], tot["formed"]
    return {
        "brain": brain_name, "case": case, "conditions": cond.name(), "robots": n,
        "safety": safety,
        "episodes": int(e),
        "success": tot["ok"] / e, "formed": f / e,
        "held": tot["held"] / f if f else math.nan,
        "collisions_per_episode": tot["coll"] / e,
        "steps_ratio": tot["steps"] / f if f else math.nan,
        "travel_ratio": tot["travel"] / f if f else math.nan,
        "wall_s": tot["wall"],
    }


def _cell(r: dict[str, Any]) -> str:
    """One row's cell: shares as % to a tenth (99.5 stays 99.5, not 100) and steps to a
    thousandth (1.304 stays over a 1.3 goal)."""
    def pct(x: float) -> str:
        return "-" if math.isnan(x) else f"{100 * x:.1f}".removesuffix(".0")

    steps = "-" if math.isnan(r["steps_ratio"]) else f"{r['steps_ratio']:.3f}"
    return (f"{pct(r['success'])} / {pct(r['formed'])} / {pct(r['held'])} / "
            f"{r['collisions_per_episode']:.2f} / {steps}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=10, help="team size (default 10)")
    p.add_argument("--episodes", type=int, default=20, help="episodes per shape (default 20)")
    p.add_argument("--seed", type=int, default=3_000_000, help="world seed (default 3000000)")
    p.add_argument("--cases", default=",".join(CASES),
                   help=f"case names or presets separated by ',' or ';', or condition specs "
                   f"separated by ';' (\"realistic,loss=0;late3\"; default all: "
                   f"{', '.join(CASES)})")
    p.add_argument("--brains", default=",".join(BRAINS),
                   help="comma-separated brains; '+est' adds the estimator, '+agree' the slot "
                   "agreement (--agree slots), '+frame' the leader's frame only (--agree frame), "
                   "'+alone' no agreement (--agree off), "
                   "'+naive' runs the "
                   "robot as before it knew its sensing (filter on the raw views and their "
                   "frame differences, no widened margin, no damped landing)")
    p.add_argument("--shapes", default=",".join(SHAPES),
                   help="comma-separated shapes; A>B starts from pattern A formed")
    p.add_argument("--transitions", action="store_true",
                   help=f"the demo's transitions as the shapes ({','.join(TRANSITIONS)})")
    p.add_argument("--spacing", type=float, default=DEFAULT_WORLD.pattern_spacing_m,
                   metavar="M", help="the shapes' closest pair (m; default "
                   f"{DEFAULT_WORLD.pattern_spacing_m:g}, the built-ins')")
    p.add_argument("--safety", choices=SAFETY_MODES, default="orca",
                   help="the robots' filter (default 'orca', as they run), the raw brains "
                   "('off'), or ORCA without its last-resort guard ('orca-no-guard': not safe on "
                   "imperfect views; it measures what the guard costs)")
    p.add_argument("--quick", action="store_true", help="4 episodes, circle and heart")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)
    episodes = 4 if args.quick else args.episodes
    shapes = (("circle", "heart") if args.quick else TRANSITIONS if args.transitions
              else tuple(args.shapes.split(",")))
    brains = args.brains.split(",")
    cases = split_cases(args.cases)
    for case in cases:
        try:
            parse_conditions(CASES.get(case, case))
        except InputError as exc:
            p.error(f"--cases {case!r}: {exc}")
    if not (math.isfinite(args.spacing) and args.spacing >= DEFAULT_WORLD.min_separation_m):
        p.error(f"--spacing must be at least 2R = {DEFAULT_WORLD.min_separation_m:g} m")
    world = replace(DEFAULT_WORLD, pattern_spacing_m=args.spacing)
    t0 = time.perf_counter()
    rows = []
    for case in cases:
        for b in brains:
            rows.append(run_case(b, case, args.robots, episodes, args.seed, shapes, world,
                                 args.safety))
            if not args.json:
                print(f"  {case:<10} {b:<28} {_cell(rows[-1])}", file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps({"robots": args.robots, "episodes_per_shape": episodes,
                          "safety": args.safety,
                          "shapes": shapes, "pattern_spacing_m": args.spacing, "rows": rows,
                          "wall_s": time.perf_counter() - t0},
                         default=lambda x: None))
        return 0
    print(f"\nn = {args.robots}, {episodes} episodes x {len(shapes)} shapes "
          f"({', '.join(shapes)}, closest pair {args.spacing:g} m); cell: success % / "
          f"formed % / held % of formed / collisions per episode / steps over the lower bound"
          + ("" if args.safety == "orca" else f"; safety filter: {args.safety}"))
    w = max(len(b) for b in brains)
    print(f"| case | {' | '.join(f'{b:<{w}}' for b in brains)} |")
    print("|---" * (len(brains) + 1) + "|")
    for case in cases:
        cells = [_cell(r) for r in rows if r["case"] == case]
        print(f"| {case} | {' | '.join(cells)} |")
    print(f"\nwall {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
