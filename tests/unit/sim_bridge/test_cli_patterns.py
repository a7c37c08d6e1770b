"""``patternrl patterns`` in process: big teams bounded and drawn, ``--json`` after the action."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from patternrl.cli import main
from sim_bridge.launch.cli_patterns import MAX_SHOW_ROBOTS


def test_show_refuses_more_than_the_maximum_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["patterns", "show", "circle", "--robots", str(MAX_SHOW_ROBOTS + 1)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip().splitlines() == [
        f"patternrl patterns: --robots must be in 2..{MAX_SHOW_ROBOTS}, got {MAX_SHOW_ROBOTS + 1}"
    ]


def test_show_draws_thousands_of_robots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "big.png"
    argv = ["patterns", "show", "circle", "--robots", "5000", "--out", str(out), "--json"]
    assert main(argv) == 0
    info = json.loads(capsys.readouterr().out)
    assert len(info["points"]) == 5000 and info["png"] == str(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("argv", [
    ["patterns", "list", "--json"],
    ["patterns", "--json", "list"],
])
def test_list_json_before_or_after_the_action(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 0
    assert "circle" in json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("argv", [
    ["patterns", "show", "line", "--robots", "4", "--json"],
    ["patterns", "--json", "show", "line", "--robots", "4"],
])
def test_show_json_before_or_after_the_action(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 0
    assert len(json.loads(capsys.readouterr().out)["points"]) == 4
