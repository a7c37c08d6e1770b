"""``patternrl --version``: the installed package's version, or the source tree's."""

from __future__ import annotations

import importlib.metadata
import tomllib

from support import ROOT

from patternrl import cli

SOURCE_VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_version_is_the_installed_metadata_else_pyproject(monkeypatch, capsys) -> None:
    monkeypatch.setattr(importlib.metadata, "version", lambda name: "9.8.7")
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out == "patternrl 9.8.7\n"

    def not_installed(name: str) -> str:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    assert cli.main(["-V"]) == 0
    assert capsys.readouterr().out == f"patternrl {SOURCE_VERSION}\n"
