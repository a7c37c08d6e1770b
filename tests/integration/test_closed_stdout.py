"""Every command stops quietly when the reader of its output went away (``... | head -1``)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from patternrl.cli import EXIT_CLOSED_STDOUT


@pytest.mark.parametrize("argv", [["patterns", "list"], ["--help"], ["patterns", "--help"]])
def test_a_closed_stdout_ends_the_command_quietly(argv: list[str]) -> None:
    r, w = os.pipe()
    os.close(r)  # the reader is gone before the first byte: every write hits a closed pipe
    try:
        proc = subprocess.run([sys.executable, "-m", "patternrl.cli", *argv], stdout=w,
                              stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(w)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert "BrokenPipe" not in proc.stderr, proc.stderr
    assert proc.stderr == ""
    assert proc.returncode in (EXIT_CLOSED_STDOUT, 0), proc.returncode
