"""Zenoh keys: every builder's key parses back to what built it; anything else is refused."""

from __future__ import annotations

import pytest

from runtime.wire import keys
from runtime.wire.keys import Key

SWARMS = ["s", "swarm_A-1", "demo"]


@pytest.mark.parametrize("swarm", SWARMS)
@pytest.mark.parametrize("robot_id", [0, 1, 7, 12345])
def test_round_trip_of_robot_keys(swarm: str, robot_id: int) -> None:
    for build, kind in (
        (keys.pose_key, keys.POSE),
        (keys.cmd_key, keys.CMD),
        (keys.status_key, keys.STATUS),
        (keys.view_key, keys.VIEW),
        (keys.slots_key, keys.SLOTS),
    ):
        key = build(swarm, robot_id)
        assert keys.parse_key(key) == Key(swarm, kind, robot_id)
        assert keys.parse_robot_id(key) == robot_id
    alive = keys.alive_key(swarm, robot_id)
    assert keys.parse_key(alive) == Key(swarm, keys.ALIVE, robot_id, str(robot_id))
    assert keys.parse_robot_id(alive) == robot_id


@pytest.mark.parametrize("swarm", SWARMS)
def test_round_trip_of_swarm_keys(swarm: str) -> None:
    assert keys.parse_key(keys.pattern_key(swarm)) == Key(swarm, keys.PATTERN, None)
    assert keys.parse_key(keys.brain_key(swarm)) == Key(swarm, keys.BRAIN, None)
    world = keys.alive_key(swarm, keys.WORLD_ID)
    assert keys.parse_key(world) == Key(swarm, keys.ALIVE, None, keys.WORLD_ID)
    for key in (keys.pattern_key(swarm), keys.brain_key(swarm), world):
        assert keys.parse_robot_id(key) is None


def test_every_kind_is_parsed() -> None:
    built = [
        keys.pose_key("s", 1),
        keys.cmd_key("s", 1),
        keys.status_key("s", 1),
        keys.pattern_key("s"),
        keys.brain_key("s"),
        keys.alive_key("s", 1),
        keys.poses_key("s"),
        keys.operator_pattern_key("s"),
        keys.view_key("s", 1),
        keys.slots_key("s", 1),
    ]
    parsed = [keys.parse_key(k) for k in built]
    assert [k.kind for k in parsed if k is not None] == list(keys.KINDS)


@pytest.mark.parametrize(
    "key",
    [
        keys.pose_key("a", 3),
        keys.cmd_key("a", 0),
        keys.status_key("a", 12),
        keys.pattern_key("a"),
        keys.brain_key("a"),
        keys.alive_key("a", 5),
        keys.alive_key("a", keys.WORLD_ID),
        keys.operator_pattern_key("a"),
        keys.view_key("a", 4),
        keys.slots_key("a", 6),
    ],
)
def test_with_swarm_moves_every_key_to_the_other_swarm(key: str) -> None:
    moved = keys.with_swarm(key, "b_2")
    assert moved is not None
    a, b = keys.parse_key(key), keys.parse_key(moved)
    assert a is not None and b is not None
    assert b.swarm == "b_2" and b._replace(swarm="a") == a
    assert keys.with_swarm(moved, "a") == key


@pytest.mark.parametrize(
    "key",
    [
        # wildcards: what a subscriber declares, never a sample's key
        keys.all_poses("s"),
        keys.all_cmds("s"),
        keys.all_status("s"),
        keys.all_views("s"),
        keys.all_slots("s"),
        keys.all_alive("s"),
        keys.swarm_root("s"),
        "patternrl/*/pattern",
        "patternrl/s/robot/**/pose",
        # zero-padded, signed or non-decimal ids
        "patternrl/s/robot/03/pose",
        "patternrl/s/robot/00/cmd",
        "patternrl/s/robot/-1/pose",
        "patternrl/s/robot/+1/pose",
        "patternrl/s/robot/1.0/status",
        "patternrl/s/robot/x/pose",
        "patternrl/s/robot//pose",
        # other prefixes, layouts and channels
        "other/s/robot/1/pose",
        "Patternrl/s/robot/1/pose",
        "/patternrl/s/robot/1/pose",
        "patternrl/s/robot/1/pose/",
        "patternrl/s/robot/1/velocity",
        "patternrl/s/robot/1",
        "patternrl/s/patterns",
        "patternrl/s/alive",
        "patternrl/s/alive/1/2",
        "patternrl/s",
        "",
        # bad swarm names
        "patternrl//robot/1/pose",
        "patternrl/a.b/robot/1/pose",
        "patternrl/a b/pattern",
        "patternrl/a$/brain",
        "patternrl/é/brain",
    ],
)
def test_refuses_keys_it_does_not_build(key: str) -> None:
    assert keys.parse_key(key) is None
    assert keys.parse_robot_id(key) is None
    assert keys.with_swarm(key, "other") is None


def test_zero_padded_alive_id_is_no_robot() -> None:
    k = keys.parse_key("patternrl/s/alive/007")
    assert k == Key("s", keys.ALIVE, None, "007")
    assert keys.parse_robot_id("patternrl/s/alive/007") is None


def test_parse_key_refuses_non_strings() -> None:
    assert keys.parse_key(None) is None  # type: ignore[arg-type]
    assert keys.parse_key(b"patternrl/s/brain") is None  # type: ignore[arg-type]


@pytest.mark.parametrize("swarm", ["", "a/b", "a*", "a b", "a.b", "é", "**"])
def test_builders_refuse_bad_swarm_names(swarm: str) -> None:
    for build in (keys.pattern_key, keys.brain_key, keys.all_poses, keys.swarm_root):
        with pytest.raises(ValueError, match="swarm"):
            build(swarm)
    with pytest.raises(ValueError, match="swarm"):
        keys.pose_key(swarm, 1)
    with pytest.raises(ValueError, match="swarm"):
        keys.with_swarm(keys.pose_key("s", 1), swarm)


@pytest.mark.parametrize("robot_id", [-1, True, 1.0, "1"])
def test_builders_refuse_bad_robot_ids(robot_id: object) -> None:
    with pytest.raises(ValueError, match="robot id"):
        keys.pose_key("s", robot_id)  # type: ignore[arg-type]


def test_alive_key_refuses_bad_string_ids() -> None:
    for bad in ("", "a/b", "*"):
        with pytest.raises(ValueError, match="liveliness id"):
            keys.alive_key("s", bad)


def test_poses_key_round_trips() -> None:
    k = keys.poses_key("s1")
    assert k == "patternrl/s1/poses"
    assert keys.parse_key(k) == Key("s1", keys.POSES, None)
    assert keys.with_swarm(k, "s2") == "patternrl/s2/poses"
