"""``patternrl --version`` as a process."""

from __future__ import annotations

import subprocess
import sys

import pytest
from support import ROOT

from patternrl import cli


@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_version_prints_and_exits_0(flag: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "patternrl.cli", flag], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == f"patternrl {cli.version()}\n"
    assert proc.stderr == ""
