"""``patternrl --version``: the installed package's version, or the source tree's."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from patternrl import cli

ROOT = Path(__file__).resolve().parents[2]
SOURCE_VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_version_prints_and_exits_0(flag: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "patternrl.cli", flag], cwd=ROOT,
                          capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == f"patternrl {cli.version()}\n"
    assert proc.stderr == ""


def test_version_is_the_installed_metadata_else_pyproject(monkeypatch, capsys) -> None:
    monkeypatch.setattr(importlib.metadata, "version", lambda name: "9.8.7")
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out == "patternrl 9.8.7\n"

    def not_installed(name: str) -> str:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    assert cli.main(["-V"]) == 0
    assert capsys.readouterr().out == f"patternrl {SOURCE_VERSION}\n"
