"""benchmarks/agreement.py: its parts on a small budget, and its one-line refusal."""

from __future__ import annotations

import subprocess
import sys

from support import ROOT, load_benchmark


def test_the_decision_cost_rises_with_the_team_and_the_leaders_message_with_it() -> None:
    bench = load_benchmark("agreement")
    rows = bench.decision_cost(calls=30)
    sizes = [10, 25, 50, 100]
    assert [(r["mode"], r["n"]) for r in rows] == [(m, n) for m in ("frame", "slots")
                                                   for n in sizes]
    assert all(r["median_us"] > 0 for r in rows)
    assert [r["deliveries_per_step"] for r in rows] == [9, 24, 49, 99, 90, 600, 2450, 9900]
    assert [r["leader_bytes"] for r in rows] == [30 + 6 * n + 16 for n in sizes] * 2


def test_transitions_run_each_way_on_the_same_episodes() -> None:
    bench = load_benchmark("agreement")
    rows = bench.transitions(episodes=1)
    assert len(rows) == len(bench.BRAINS) * len(bench.CASES) * len(bench.TRANSITIONS)
    for r in rows:
        for way in ("off", "frame", "slots"):
            assert 0.0 <= r[way]["success"] <= 1.0 and r[way]["collisions"] >= 0


def test_bad_options_are_refused_in_one_line() -> None:
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "agreement.py"),
                        "--episodes", "0"], capture_output=True, text=True, timeout=120,
                       check=False)
    assert p.returncode == 2 and p.stderr.strip().count("\n") == 0
    assert "--episodes must be >= 1" in p.stderr
