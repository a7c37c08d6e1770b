"""A robot's perceived team (the view message): round trip, bounds before allocation and
values, the robot's option, who may publish it and what it may cost."""

from __future__ import annotations

import argparse
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import runtime.wire.messages as m
from runtime.conditions import parse_conditions
from runtime.errors import InputError
from runtime.net.identity import access_control
from runtime.robot.cli import VIEW_EVERY, add_arguments, config_from_args
from runtime.wire import keys
from runtime.wire.messages import (
    MAX_VIEW_ROBOTS,
    MessageError,
    Tag,
    View,
    decode_view,
    encode_view,
)
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.budget import BUDGETS

SWARM = "s"
HEAD = struct.Struct("<BBIQI")
ROW = 24


def view(robot_id: int = 1, step: int = 7, ids: list[int] | None = None,
         xy: list[list[float]] | None = None) -> View:
    ids = [0, 1, 2] if ids is None else ids
    n = len(ids)
    pos = np.asarray(xy if xy is not None else [[float(i), 2.0 * i] for i in ids]).reshape(n, 2)
    return View(robot_id, step, ids, pos, np.arange(n))


finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(step=st.integers(0, 2**64 - 1),
       ids=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=40, unique=True),
       data=st.data())
def test_round_trip(step: int, ids: list[int], data: st.DataObject) -> None:
    ids = sorted(ids)
    n = len(ids)
    me = data.draw(st.sampled_from(ids))
    xy = data.draw(st.lists(st.tuples(finite, finite), min_size=n, max_size=n))
    age = data.draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n))
    msg = View(me, step, ids, np.array(xy).reshape(n, 2), age)
    raw = encode_view(msg)
    assert len(raw) == HEAD.size + ROW * n and raw[0] == Tag.VIEW
    back = decode_view(raw)
    assert back == msg and m.decode(raw) == msg and m.encode(msg) == raw
    assert back.ids.tolist() == ids and back.age_steps.tolist() == age
    assert back.xy.shape == (n, 2) and not back.xy.flags.writeable


def test_refused_before_allocation() -> None:
    with pytest.raises(MessageError, match=f"at most {MAX_VIEW_ROBOTS}"):  # a huge count
        decode_view(HEAD.pack(Tag.VIEW, m.VERSION, 1, 3, 2**32 - 1))
    with pytest.raises(MessageError, match="truncated"):  # claims more rows than there are
        decode_view(HEAD.pack(Tag.VIEW, m.VERSION, 1, 3, 3) + bytes(ROW))
    with pytest.raises(MessageError, match="truncated"):
        decode_view(HEAD.pack(Tag.VIEW, m.VERSION, 1, 3, 0)[:-1])
    good = encode_view(view())
    with pytest.raises(MessageError, match="trailing"):
        decode_view(good + b"\0")
    with pytest.raises(MessageError, match="expected view"):
        decode_view(b"\x03" + good[1:])
    with pytest.raises(MessageError, match="unsupported view version"):
        decode_view(good[:1] + b"\x09" + good[2:])
    with pytest.raises(MessageError, match="bytes-like"):
        decode_view("not bytes")  # type: ignore[arg-type]


@pytest.mark.parametrize(("offset", "value", "match"), [
    (4, float("nan"), "finite"),  # x of member 0
    (12, float("inf"), "finite"),  # y of member 0
    (ROW + 4, -float("inf"), "finite"),  # x of member 1
    (2 * ROW + 12, 2e6, "from the origin"),  # y of member 2: beyond MAX_VIEW_COORD_M
])
def test_refused_by_value(offset: int, value: float, match: str) -> None:
    raw = bytearray(encode_view(view()))
    raw[HEAD.size + offset: HEAD.size + offset + 8] = struct.pack("<d", value)
    with pytest.raises(MessageError, match=match):
        decode_view(bytes(raw))
    with pytest.raises(MessageError, match=match):
        m.decode(bytes(raw))


def test_refused_by_meaning() -> None:
    good = encode_view(view())
    twice = bytearray(good)
    twice[HEAD.size + ROW: HEAD.size + ROW + 4] = struct.pack("<I", 0)  # member 0 twice
    with pytest.raises(MessageError, match="ascending"):
        decode_view(bytes(twice))
    stranger = bytearray(good)
    stranger[2:6] = struct.pack("<I", 9)  # the sender is not in its team
    with pytest.raises(MessageError, match="lacks its own row"):
        decode_view(bytes(stranger))
    with pytest.raises(MessageError, match="lacks its own row"):  # an empty team
        decode_view(HEAD.pack(Tag.VIEW, m.VERSION, 1, 3, 0))


def test_encoder_refuses_what_the_decoder_would() -> None:
    with pytest.raises(MessageError, match="ascending"):
        encode_view(view(ids=[2, 1, 0]))
    with pytest.raises(MessageError, match="lacks its own row"):
        encode_view(view(robot_id=5))
    with pytest.raises(MessageError, match="finite"):
        encode_view(view(xy=[[0.0, 0.0], [float("nan"), 1.0], [2.0, 2.0]]))
    with pytest.raises(MessageError, match="from the origin"):
        encode_view(view(xy=[[0.0, 0.0], [1e7, 1.0], [2.0, 2.0]]))
    with pytest.raises(MessageError, match="at most"):
        encode_view(view(ids=list(range(MAX_VIEW_ROBOTS + 1))))
    with pytest.raises(MessageError, match="step"):
        encode_view(view(step=-1))
    with pytest.raises(MessageError, match="xy must be"):
        View(1, 2, [0, 1], np.zeros((3, 2)), [0, 0])
    with pytest.raises(MessageError, match="age_steps must be in"):
        View(1, 2, [0, 1], np.zeros((2, 2)), [0, -1])


def test_a_robot_may_publish_its_own_view_only_and_the_world_hears_it() -> None:
    acl = access_control(SWARM, 3)
    puts = {r["id"]: r["key_exprs"] for r in acl["rules"] if r["messages"] == ["put"]}
    for i in range(3):
        mine = puts[f"robot-{i}-put"]
        assert keys.view_key(SWARM, i) in mine and keys.status_key(SWARM, i) in mine
        assert all(keys.view_key(SWARM, j) not in mine for j in range(3) if j != i)
    listen = next(r for r in acl["rules"] if r["id"] == "listen")
    assert listen["key_exprs"] == [f"patternrl/{SWARM}/**"]  # world and recorder subscribe
    assert keys.parse_key(keys.view_key(SWARM, 2)) == keys.Key(SWARM, keys.VIEW, 2)
    assert keys.with_swarm(keys.view_key(SWARM, 2), "t") == keys.view_key("t", 2)


def test_the_view_key_has_a_budget_sized_to_its_rate() -> None:
    b = BUDGETS[keys.VIEW]
    per_s_at_fastest = 213 / VIEW_EVERY  # lockstep's fastest measured steps per second
    assert b.messages >= per_s_at_fastest and b.messages >= 10  # one a step at 10 Hz fits
    assert b.bytes >= 4 * len(encode_view(view(ids=list(range(MAX_VIEW_ROBOTS)))))
    assert b.messages < BUDGETS[keys.CMD].messages


def _robot_args(*extra: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(["--swarm", SWARM, "--id", "1", "--brain", "rule:assign", *extra])


def test_view_every_option() -> None:
    cfg, _ = config_from_args(_robot_args(), DEFAULT_WORLD)
    assert cfg.view_every == VIEW_EVERY == 10
    cfg, _ = config_from_args(_robot_args("--view-every", "0", "--conditions", "realistic"),
                              DEFAULT_WORLD)
    assert cfg.view_every == 0 and cfg.conditions == parse_conditions("realistic")
    with pytest.raises(InputError, match="--view-every must be >= 0"):
        config_from_args(_robot_args("--view-every", "-1"), DEFAULT_WORLD)
    p = argparse.ArgumentParser()
    add_arguments(p)
    assert "--view-every" in p.format_help()


def test_lockstep_deadline_must_be_below_the_watchdog() -> None:
    """A deadline past the watchdog never comes: a robot missing a pose of the step holds
    still first, and holding, no deadline wakes it, while a lockstep world waits for it."""
    cfg, _ = config_from_args(_robot_args("--lockstep-deadline-s", "0.5"), DEFAULT_WORLD)
    assert cfg.lockstep_deadline_s == 0.5
    for extra in (("--lockstep-deadline-s", "1"),
                  ("--lockstep-deadline-s", "0.5", "--watchdog-s", "0.4")):
        with pytest.raises(InputError, match="--lockstep-deadline-s must be below --watchdog-s"):
            config_from_args(_robot_args(*extra), DEFAULT_WORLD)
