"""A ``--cfg`` zenoh refuses is one line naming the key, never zenoh's Rust source path."""

from __future__ import annotations

import pytest

from patternrl.cli import main


@pytest.mark.parametrize("argv", [
    ["launch"],
    ["sim", "--insecure"],
    ["robot", "--id", "0", "--insecure", "--swarm", "s1", "--brain", "rule:assign"],
])
def test_unknown_cfg_key_is_named_in_one_line(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*argv, "--cfg", "foo/bar:1"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == [
        f"patternrl {argv[0]}: error: bad --cfg 'foo/bar:1': unknown zenoh config key 'foo/bar'"
    ]


@pytest.mark.parametrize("item, words", [
    ("mode:12", "key 'mode': bad value: invalid type: integer `12`"),
    ('transport/unicast/max_links:"x"', "key 'transport/unicast/max_links': bad value"),
    ("connect/endpoints:[1", "key 'connect/endpoints': bad value: expected boolean"),
])
def test_bad_cfg_value_names_the_key(
    item: str, words: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sim", "--insecure", "--cfg", item]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and words in err
    assert ".rs:" not in err and "cargo" not in err
