"""README's "Run robots by hand" block, run as written in order (real processes), with 3 robots.

The block is read from the README; only what a test must change is changed: the team size,
the swarm's name (its own port, beside other runs), and where keys and the log go."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from support import ROOT

from sim_bridge.log.report import report_log

pytestmark = pytest.mark.timeout(240)
N = 3


def readme_block() -> str:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("### Run robots by hand"):]
    start = section.index("```sh\n") + len("```sh\n")
    return section[start:section.index("\n```", start)]


def test_the_readme_block_runs_in_order(tmp_path: Path) -> None:
    block = readme_block()
    assert block.count("--robots 10") == 2 and "seq 0 9" in block and "--robots 0-9" in block
    swarm = f"byhand{os.getpid()}"
    script = (block.replace(".venv/bin/", f"{Path(sys.executable).parent}/")
              .replace("--robots 10", f"--robots {N}").replace("seq 0 9", f"seq 0 {N - 1}")
              .replace("--robots 0-9", f"--robots 0-{N - 1}")
              .replace("--swarm demo", f"--swarm {swarm}")
              .replace("keys/demo", str(tmp_path / "keys" / "demo"))
              .replace("runs/by-hand.mcap", str(tmp_path / "runs" / "by-hand.mcap")))
    # after the block: the world's exit code; the robots (which would wait 30 s for a world
    # that has gone) are sent home
    script += "\nworld=$?\nkill -INT $(jobs -p) 2>/dev/null\nwait\nexit $world\n"
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    env.pop("PATTERNRL_ZENOH_PORT", None)
    r = subprocess.run(["bash", "-c", script], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=200)
    assert r.returncode == 0, r.stdout + r.stderr[-3000:]
    swapped = re.findall(r"^(\d+)\s+\S+\s+\S+\s+accepted", r.stdout, re.M)
    assert sorted(map(int, swapped)) == list(range(N)), r.stdout  # every robot swapped
    assert "Traceback" not in r.stderr
    rep = report_log(tmp_path / "runs" / "by-hand.mcap")
    assert [(p.pattern, p.formed) for p in rep.phases] == [("circle", True), ("heart", True)]
    heart = (ROOT / "exports" / "heart-10-general.json").read_text()
    swapped_in = [b for p in rep.phases for b in p.brains if b and b[:12] in heart]
    assert swapped_in, [p.brains for p in rep.phases]  # the new brain drove while it ran
