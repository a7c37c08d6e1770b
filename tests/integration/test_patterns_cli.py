"""``patternrl patterns show`` as a process: bad input in one line, a PNG drawn."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


def test_cli_bad_pattern_exits_2_with_one_line(tmp_path: Path) -> None:
    f = tmp_path / "bad.json"
    f.write_text("[[0, 0]]")
    for target in (str(f), "nope"):
        r = subprocess.run(
            [sys.executable, "-m", "patternrl.cli", "patterns", "show", target],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 2
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "Traceback" not in r.stderr


def test_cli_show_draws_png(tmp_path: Path) -> None:
    out = tmp_path / "heart.png"
    r = subprocess.run(
        [sys.executable, "-m", "patternrl.cli", "patterns", "show", "heart", "--robots", "10",
         "--out", str(out), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)
    assert len(info["points"]) == 10
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
