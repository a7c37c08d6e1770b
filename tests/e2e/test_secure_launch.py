"""The demo as a user runs it: secure by default, each pattern's brain swapped in between phases.

`patternrl launch` with no security option makes the run's certificates, so the world, every robot
and the operator speak mutual TLS under Zenoh access control; the world's brain swaps between
phases must pass that access control (the world may publish brains) and the robots' signature check
(the shipped brains are signed by the release key).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(300)
def test_secure_launch_swaps_each_patterns_brain(tmp_path: Path) -> None:
    log = tmp_path / "secure.mcap"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("PATTERNRL_ZENOH_PORT", None)
    proc = subprocess.run(
        [sys.executable, "-m", "patternrl.cli", "launch", "--robots", "4", "--patterns",
         "circle,cross", "--brains", "exports", "--record", str(log), "--no-plot", "--json",
         "--swarm", f"secure{os.getpid()}"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=280, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "mutual TLS" in proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    phases = result["phases"]
    assert [p["pattern"] for p in phases] == ["circle", "cross"]
    assert all(p["formed"] and p["collisions"] == 0 for p in phases), phases
    # every robot ran the cross brain in the cross phase: the swap went through
    assert phases[1]["brain"].startswith("cross-10-general.onnx"), phases[1]
    assert "not in every robot" not in phases[1]["brain"]
