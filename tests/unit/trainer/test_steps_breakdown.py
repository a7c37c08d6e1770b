"""benchmarks/steps_breakdown.py and ``evaluate_brain``'s ``on_step``: following episodes step
by step through ground truth."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from support import ROOT, load_benchmark

from runtime.brain.brain import load_brain
from runtime.conditions import parse_conditions
from runtime.decision.formation import is_formed
from trainer.evaluate import HOLD_STEPS, evaluate_brain


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_benchmark("steps_breakdown")


def test_on_step_sees_every_step_of_every_episode_as_the_world_has_it() -> None:
    seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def on_step(pos: np.ndarray, pattern: np.ndarray, running: np.ndarray) -> None:
        with pytest.raises(ValueError):
            pos[0, 0, 0] = 1e9  # read-only: a follower cannot move the world
        seen.append((pos.copy(), pattern.copy(), running.copy()))

    r = evaluate_brain(load_brain("rule:frame-balanced"), "circle", 7, 3, seed=11,
                       conditions=parse_conditions("latency_steps=1"), estimator=True,
                       progress=False, on_step=on_step)
    steps = [int(s) for s in r.episode_stats["steps"]]
    assert r.success_rate == 1.0
    assert len(seen) == max(steps) + HOLD_STEPS  # formed, then held for the hold window
    for e, s in enumerate(steps):
        end = s + HOLD_STEPS
        assert all(run[e] for _, _, run in seen[:end])
        assert not any(run[e] for _, _, run in seen[end:])
        assert is_formed(seen[s][0][e], seen[s][1][e])  # formed by that step's move
        pos, pattern, _ = seen[s - 1]  # the last step's positions, before its move
        assert not is_formed(pos[e], pattern[e])  # it formed on that step's move, not before


def test_the_breakdown_counts_the_way_in_and_each_frames_geometry(bench: ModuleType) -> None:
    row = bench.run_case("rule:frame-balanced+est", "perfect", 12, 3, 3_000_000,
                         ("circle", "heart"))
    assert row["formed"] == 1.0 and row["episodes"] == 6
    within = [row["within_m"][f"{m}"] for m in bench.MARKS_M]
    assert within == sorted(within)  # 20 cm, then 10, then 5
    assert within[-1] <= row["steps_ratio"]
    way = row["curve"]["worst_way_m"]
    assert len(way) == len(bench.CURVE_X)
    assert way[0] > 0.2 > way[-1]  # far off at the start, in at the end
    frames = row["plan_frames"]
    # the enclosing circle's frame brings the farthest robot nearest: never more steps
    assert frames["enclosing"] <= frames["balanced"] <= frames["centroid"]
    assert frames["enclosing"] >= 1.0  # none beats the lower bound


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(ROOT / "benchmarks" / "steps_breakdown.py"),
                           *args], capture_output=True, text=True, timeout=600, check=False)


def test_json_rows_per_case_a_figure_and_a_bad_case_a_one_line_error(tmp_path: Path) -> None:
    png = tmp_path / "ways.png"
    out = _run("--robots", "7", "--episodes", "1", "--shapes", "circle",
               "--cases", "perfect,late2", "--json", "--png", str(png))
    assert out.returncode == 0, out.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = json.loads(out.stdout)["rows"]
    assert [r["case"] for r in rows] == ["perfect", "late2"]
    assert rows[1]["conditions"].endswith("latency_steps=2")
    bad = _run("--cases", "noise_m=0.05,bogus=1", "--episodes", "1", "--robots", "7")
    assert bad.returncode == 2
    assert "bogus=1" in bad.stderr.strip().splitlines()[-1] and "Traceback" not in bad.stderr


def test_from_a_formed_pattern_the_way_is_short_and_the_start_named(bench: ModuleType) -> None:
    row = bench.run_case("rule:frame-balanced+est", "perfect", 10, 2, 3_000_000, ("cross",),
                         start="circle")
    assert row["start"] == "circle" and row["formed"] == 1.0
    assert row["plan_frames"]["enclosing"] >= 1.0
    assert row["within_m"]["0.2"] <= row["steps_ratio"]
