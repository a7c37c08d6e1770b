"""Run one benchmark on two revisions, interleaved, and print their figures side by side.

    .venv/bin/python benchmarks/compare.py --base REV -- benchmarks/runtime_latency.py --quick

The benchmark runs ``--rounds`` times on each side, alternating (base, this tree, base, ...),
so both see the same machine load; every numeric leaf of its ``--json`` output is reported as
the median over rounds, base beside this tree, with the ratio. ``REV`` is checked out into a
temporary git worktree (removed afterwards) and run with this tree's Python, with
``PYTHONPATH`` pointing at that worktree, its compiled extensions built there first
(``setup.py build_ext --inplace``). The benchmark must accept ``--json`` and print one
JSON object on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def _leaves(obj: Any, prefix: str = "") -> dict[str, float]:
    """Flatten a JSON value to {dotted.path: number} for every int/float leaf."""
    out: dict[str, float] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.update(_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.update(_leaves(v, f"{prefix}[{i}]"))
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        out[prefix] = float(obj)
    return out


def _run(tree: Path, argv: list[str], timeout_s: float) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONHASHSEED="0")
    script, rest = argv[0], argv[1:]
    proc = subprocess.run(
        [sys.executable, str(tree / script), *rest, "--json"],
        cwd=tree, env=env, capture_output=True, text=True, timeout=timeout_s, check=False,
    )
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        raise SystemExit(f"compare: {script} failed in {tree}: {tail[0]}")
    start = proc.stdout.find("{")
    if start < 0:
        raise SystemExit(f"compare: {script} printed no JSON object in {tree}")
    return _leaves(json.loads(proc.stdout[start:]))


def _build(tree: Path) -> None:
    """Compile the revision's extensions in place, as its install would, so that both sides
    run what users run (a checkout alone would run any compiled part as Python, or not at all)."""
    if not (tree / "setup.py").is_file():
        return
    built = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"],
                           cwd=tree, capture_output=True, text=True, check=False)
    if built.returncode != 0:
        print("compare: the base's extensions did not build: it runs without them",
              file=sys.stderr)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--base", required=True, help="git revision to compare against (e.g. HEAD~5)")
    p.add_argument("--rounds", type=int, default=3, help="runs per side, interleaved (default 3)")
    p.add_argument("--timeout-s", type=float, default=900.0, help="per run (default 900)")
    p.add_argument("--match", default="", help="only report figures whose path contains this")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("benchmark", nargs=argparse.REMAINDER,
                   help="-- SCRIPT [ARGS]: the benchmark, relative to the repository root")
    args = p.parse_args()
    bench = [a for a in args.benchmark if a != "--"]
    if not bench:
        p.error("give the benchmark after --, e.g. -- benchmarks/replay_speed.py")
    if args.rounds < 1:
        p.error("--rounds must be >= 1")
    with tempfile.TemporaryDirectory(prefix="patternrl-base-") as tmp:
        base = Path(tmp) / "base"
        add = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base),
                              args.base], capture_output=True, text=True, check=False)
        if add.returncode != 0:
            raise SystemExit(f"compare: cannot check out {args.base}: {add.stderr.strip()}")
        _build(base)
        try:
            runs: dict[str, list[dict[str, float]]] = {"base": [], "this": []}
            for r in range(args.rounds):
                for side, tree in (("base", base), ("this", ROOT)):
                    print(f"round {r + 1}/{args.rounds}: {side}", file=sys.stderr)
                    runs[side].append(_run(tree, bench, args.timeout_s))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)],
                           capture_output=True, check=False)
    keys = [k for k in runs["this"][0] if k in runs["base"][0] and args.match in k]
    rows = []
    for k in keys:
        b = statistics.median(x[k] for x in runs["base"] if k in x)
        t = statistics.median(x[k] for x in runs["this"] if k in x)
        rows.append({"figure": k, "base": b, "this": t, "ratio": (t / b) if b else None})
    if args.json:
        print(json.dumps({"base": args.base, "rounds": args.rounds, "benchmark": bench,
                          "figures": rows}, indent=2))
        return 0
    width = max((len(r["figure"]) for r in rows), default=10)
    print(f"{'figure':<{width}}  {'base ' + args.base:>16}  {'this tree':>12}  {'ratio':>7}")
    for r in rows:
        ratio = f"{r['ratio']:.2f}x" if r["ratio"] is not None else "-"
        print(f"{r['figure']:<{width}}  {r['base']:>16.4g}  {r['this']:>12.4g}  {ratio:>7}")
    print(f"medians of {args.rounds} interleaved runs per side")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
