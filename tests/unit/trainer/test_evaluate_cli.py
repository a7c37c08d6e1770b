"""``patternrl eval`` in process: a team too small for a pattern is refused in one line."""

from __future__ import annotations

import pytest

from patternrl.cli import main


@pytest.mark.parametrize("robots", ["0", "1", "-3"])
def test_eval_refuses_fewer_than_two_robots(
    robots: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["eval", "--brain", "rule:assign", "--pattern", "circle", "--robots", robots,
            "--episodes", "1", "--no-progress"]
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip().splitlines() == [
        f"patternrl eval: --robots must be >= 2 (a pattern needs 2 robots), got {robots}"
    ]


def test_eval_takes_a_team_of_two(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["eval", "--brain", "rule:assign", "--pattern", "line", "--robots", "2",
            "--episodes", "1", "--no-progress", "--json"]
    assert main(argv) == 0
    assert '"n_robots": 2' in capsys.readouterr().out
