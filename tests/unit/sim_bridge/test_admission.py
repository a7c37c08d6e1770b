"""Who the world lets in, and a Ctrl-C while a command starts."""

from __future__ import annotations

import threading
from typing import Any

import pytest

import sim_bridge.world.membership as membership
from sim_bridge.world.membership import Roster


def test_once_running_a_token_joins_only_when_its_robot_speaks(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    roster = Roster(threading.Condition(threading.Lock()))
    roster.saw(0, joined=True)  # before the start: the world waits for its team by tokens
    assert roster.alive_ids() == [0]
    roster.started = True
    roster.saw(77, joined=True)  # a phantom: no word from robot 77
    roster.saw(3, joined=True)
    assert roster.alive_ids() == [0]
    roster.heard(3)  # robot 3's first status
    assert roster.alive_ids() == [0, 3]
    assert list(roster.changes()) == [(True, 0), (True, 3)]
    monkeypatch.setattr(membership, "UNHEARD_S", 0.0)
    assert roster.unheard() == [0, 77]  # robot 0 never spoke either: taken out
    assert roster.unheard() == []  # counted once
    assert roster.ignored == 2 and roster.alive_ids() == [3]
    assert list(roster.changes()) == [(False, 0)]
    roster.heard(0)  # it was a robot after all
    assert roster.alive_ids() == [0, 3]
    roster.saw(77, joined=False)
    assert list(roster.changes()) == [(True, 0)]


def test_ctrl_c_while_a_command_starts_is_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from patternrl import cli

    def interrupted(name: str) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted)
    assert cli.main(["robot", "--help"]) == 130
    err = capsys.readouterr().err
    assert err == "patternrl: interrupted\n"
