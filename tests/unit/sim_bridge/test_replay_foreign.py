"""``patternrl replay`` in process: a valid MCAP file another tool wrote is no Pattern-RL log."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer

from patternrl.cli import main


def write_foreign(path: Path, library: str = "some other tool") -> Path:
    with path.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library=library)
        sid = w.register_schema("Thing", "jsonschema", b"{}")
        ch = w.register_channel("/made/up/topic", "json", sid)
        for t in range(5):
            w.add_message(ch, log_time=t, data=b'{"x": 1}', publish_time=t)
        w.finish()
    return path


@pytest.mark.parametrize("extra", [[], ["--json"]])
def test_foreign_mcap_is_refused_in_one_line(
    tmp_path: Path, extra: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    log = write_foreign(tmp_path / "foreign.mcap")
    assert main(["replay", str(log), *extra]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "not a Pattern-RL log" in lines[0] and str(log) in lines[0]


def test_foreign_mcap_without_channels_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "empty.mcap"
    with log.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="some other tool")
        w.finish()
    assert main(["replay", str(log)]) == 2
    assert "not a Pattern-RL log" in capsys.readouterr().err


def test_foreign_mcap_compared_with_another_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b = write_foreign(tmp_path / "a.mcap"), write_foreign(tmp_path / "b.mcap")
    assert main(["replay", str(a), str(b)]) == 2
    assert "not a Pattern-RL log" in capsys.readouterr().err
