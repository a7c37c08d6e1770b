"""Ctrl-C while the launcher waits for its robots: said as an interruption, exit 130, no orphans."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path


def _processes_naming(word: str) -> list[str]:
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            args = (Path("/proc") / pid / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if word in args:
            found.append(f"{pid}: {args}")
    return found


def test_sigint_during_start_up_is_an_interruption(tmp_path: Path) -> None:
    swarm = f"sigint{os.getpid()}"
    p = subprocess.Popen(
        [sys.executable, "-m", "patternrl.cli", "launch", "--robots", "8", "--swarm", swarm,
         "--no-plot", "--record", str(tmp_path / "run.mcap")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert p.stderr is not None
    first = p.stderr.readline()  # the launcher is up: it starts the robots next
    assert first.startswith("brains:"), first
    p.send_signal(signal.SIGINT)
    out, err = p.communicate()
    assert p.returncode == 130, (out, err)
    assert "alive after" not in err, err
    assert "interrupted" in err + out
    assert "Traceback" not in err
    assert _processes_naming(swarm) == []
