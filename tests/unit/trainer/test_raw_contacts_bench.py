"""benchmarks/raw_contacts.py: where a brain's raw contacts happen, and how the pair moves."""

from __future__ import annotations

import json
import subprocess
import sys
from types import ModuleType

import numpy as np
import pytest
from support import ROOT, load_benchmark

from runtime.world_config import DEFAULT_WORLD

TWO_R = DEFAULT_WORLD.min_separation_m
REACH = DEFAULT_WORLD.max_step_m


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_benchmark("raw_contacts")


def test_a_pair_in_contact_travelling_together_is_side_by_side(bench: ModuleType) -> None:
    """Three pairs of two robots (one env each): travelling together in contact, meeting head
    on, and passing apart."""
    step = np.array([REACH, 0.0])
    P0 = np.array([[[0.0, 0.0], [0.0, TWO_R]],  # side by side, both at full speed along x
                   [[0.0, 0.0], [TWO_R + 2 * REACH, 0.0]],  # head on
                   [[0.0, 0.0], [0.0, 1.0]]])  # far apart
    P1 = P0.copy()
    P1[0] += step
    P1[1, 0] += step
    P1[1, 1] -= step
    P1[2] += step
    touch, side = bench.classify(P0, P1, np.ones(3, bool))
    assert touch[:, 0].tolist() == [True, True, False]
    assert side[:, 0].tolist() == [True, False, False]
    assert not bench.classify(P0, P1, np.zeros(3, bool))[0].any()  # episodes over: not counted


def test_the_shipped_line_brain_raw_and_a_bad_brain_in_one_line() -> None:
    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, str(ROOT / "benchmarks" / "raw_contacts.py"),
                               *args], capture_output=True, text=True, timeout=600, check=False)

    out = run("--brain", str(ROOT / "exports" / "line-10-paper.onnx"), "--episodes", "4",
              "--json")
    assert out.returncode == 0, out.stderr
    row = json.loads(out.stdout)["rows"][0]
    assert row["pattern"] == "line" and row["robots"] == 10 and row["episodes"] == 4
    assert 0 <= row["side_by_side"] <= row["touching_pair_steps"]
    assert row["episodes_with_contact"] <= 4
    bad = run("--brain", "no-such-brain.onnx", "--episodes", "1")
    assert bad.returncode == 2
    assert bad.stderr.strip().count("\n") == 0 and "no-such-brain.onnx" in bad.stderr
