"""``patternrl record`` on a swarm that is not there (another port): one line, exit 1, no file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from support import ROOT, free_port


def test_a_recording_that_heard_nothing_says_so_and_leaves_no_file(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("PATTERNRL_ZENOH_PORT", None)
    r = subprocess.run(
        [sys.executable, "-m", "patternrl.cli", "record", "--swarm", "nobody", "--out", str(out),
         "--duration-s", "1", "--insecure", "--zenoh-port", str(port)],
        capture_output=True, text=True, timeout=60, env=env, cwd=ROOT)
    assert r.returncode == 1, r.stderr
    errors = [line for line in r.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "heard nothing from swarm nobody" in errors[0], r.stderr
    assert f"127.0.0.1:{port}" in errors[0]
    assert "Traceback" not in r.stderr
    assert not out.exists()
