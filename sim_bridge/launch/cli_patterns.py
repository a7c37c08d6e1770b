"""``patternrl patterns``: list the built-ins, or draw one to check a pattern file; ``show
--spacing M --save FILE.csv`` writes a pattern spaced wider, for ``--pattern FILE.csv``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from runtime.decision.patterns import PatternError, describe_builtins, make_pattern, min_spacing
from runtime.world_config import DEFAULT_WORLD, MAX_PATTERN_COORD_M

MAX_SHOW_ROBOTS = 10_000
"""Largest team ``show`` resamples and draws (the same bound as ``patternrl keys``)."""

LABELLED_ROBOTS = 200
"""Above this many points the drawing leaves out the index labels: they would overlap."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    listing = sub.add_parser("list", help="list the built-in patterns")
    show = sub.add_parser(
        "show", help="print a pattern's points (and draw it with --out)",
        description="Resample a built-in or a pattern file to N robots and show it.",
    )
    show.add_argument("pattern", help="a built-in name (see 'list') or a CSV/JSON file of points")
    show.add_argument("--robots", type=int, default=10, help="team size N (default 10)")
    show.add_argument("--out", type=Path, help="draw the targets with their 2R discs to this PNG")
    show.add_argument("--spacing", type=float, metavar="M",
                      help="scale the pattern so that its closest pair is M metres apart (the "
                      f"built-ins: {DEFAULT_WORLD.pattern_spacing_m:g}); wider than the safety "
                      "guard's distance, neighbours land freely under noisy sensing "
                      "('patternrl eval' notes when a pattern is inside it)")
    show.add_argument("--save", type=Path, metavar="FILE.csv",
                      help="write the points as CSV (x,y per line), for --pattern FILE.csv")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    for q in (listing, show):
        # Also after the action; SUPPRESS keeps a --json given before it from being reset.
        q.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                       help="print JSON instead of text")


def run(args: argparse.Namespace) -> int:
    if args.action == "list":
        d = describe_builtins()
        if args.json:
            print(json.dumps(d))
        else:
            for name, doc in d.items():
                print(f"{name:<10} {doc}")
        return 0
    if not 2 <= args.robots <= MAX_SHOW_ROBOTS:
        print(f"patternrl patterns: --robots must be in 2..{MAX_SHOW_ROBOTS}, got {args.robots}",
              file=sys.stderr)
        return 2
    spacing = args.spacing
    if spacing is not None and not (math.isfinite(spacing)
                                    and spacing >= DEFAULT_WORLD.min_separation_m):
        print(f"patternrl patterns: --spacing must be at least 2R = "
              f"{DEFAULT_WORLD.min_separation_m:g} m, got {spacing}", file=sys.stderr)
        return 2
    try:
        pts = make_pattern(args.pattern, args.robots)
        if spacing is not None:
            pts = pts * (spacing / min_spacing(pts))
            if np.abs(pts).max() > MAX_PATTERN_COORD_M:
                raise PatternError(f"spaced {spacing:g} m, a coordinate is "
                                   f"{np.abs(pts).max():.1f} m, beyond the pattern files' "
                                   f"{MAX_PATTERN_COORD_M:g} m")
    except PatternError as e:
        print(f"patternrl patterns: {e}", file=sys.stderr)
        return 2
    if args.save is not None:
        try:
            args.save.write_text("x,y\n" + "".join(f"{x:.6f},{y:.6f}\n" for x, y in pts),
                                 encoding="utf-8")
        except OSError as e:
            print(f"patternrl patterns: cannot write {args.save}: {e.strerror or e}",
                  file=sys.stderr)
            return 2
    info = {
        "pattern": args.pattern,
        "robots": args.robots,
        "min_spacing_m": round(min_spacing(pts), 4),
        "extent_m": [round(float(v), 3) for v in pts.max(0) - pts.min(0)],
        "points": pts.round(4).tolist(),
    }
    if args.out is not None:
        _draw(pts, args.out, f"{args.pattern} ({args.robots} robots)")
        info["png"] = str(args.out)
    if args.save is not None:
        info["saved"] = str(args.save)
    if args.json:
        print(json.dumps(info))
    else:
        print(f"{args.pattern}: {args.robots} points, closest pair {info['min_spacing_m']} m, "
              f"extent {info['extent_m'][0]} x {info['extent_m'][1]} m")
        for i, (x, y) in enumerate(pts):
            print(f"  {i:>3}  {x:8.3f} {y:8.3f}")
        if args.out is not None:
            print(f"drawn to {args.out}")
        if args.save is not None:
            print(f"saved to {args.save}")
    return 0


def _draw(pts: object, out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.collections import EllipseCollection

    p = np.asarray(pts)
    fig, ax = plt.subplots(figsize=(5, 5))
    # One collection for all discs (one patch per robot takes minutes for thousands).
    diameter = 2.0 * DEFAULT_WORLD.radius_m
    ax.add_collection(EllipseCollection(
        diameter, diameter, 0.0, units="xy", offsets=p, offset_transform=ax.transData,
        facecolors="tab:blue", alpha=0.35,
    ))
    ax.scatter(p[:, 0], p[:, 1], s=6, color="tab:red", zorder=3)
    if len(p) <= LABELLED_ROBOTS:
        for i, (x, y) in enumerate(p):
            ax.annotate(str(i), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal")
    ax.margins(0.15)
    ax.set_title(title)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
