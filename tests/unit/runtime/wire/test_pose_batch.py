"""All poses of a step in one message: round trip, bounds before allocation, the inbox's
use of it, its log form, and who may publish it."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import runtime.wire.messages as m
from runtime.log import Log
from runtime.net.identity import access_control
from runtime.robot.inbox import PoseInbox, Step
from runtime.wire import keys
from runtime.wire.messages import (
    MAX_POSES_ROBOTS,
    MessageError,
    PoseBatch,
    Tag,
    decode_poses,
    encode_poses,
)
from runtime.wire.pose_batch import decode_positions
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder

SWARM = "s"


def batch(step: int, ids: list[int], xy: list[list[float]] | None = None) -> PoseBatch:
    n = len(ids)
    pos = np.asarray(xy if xy is not None else [[float(i), 2.0 * i] for i in ids]).reshape(n, 2)
    return PoseBatch(step, step * 0.1, ids, pos, np.full((n, 2), 0.5))


finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(step=st.integers(0, 2**64 - 1),
       ids=st.lists(st.integers(0, 2**32 - 1), max_size=40, unique=True),
       data=st.data())
def test_round_trip(step: int, ids: list[int], data: st.DataObject) -> None:
    ids = sorted(ids)
    n = len(ids)
    xy = data.draw(st.lists(st.tuples(finite, finite), min_size=n, max_size=n))
    v = data.draw(st.lists(st.tuples(finite, finite), min_size=n, max_size=n))
    msg = PoseBatch(step, 1.5, ids, np.array(xy).reshape(n, 2), np.array(v).reshape(n, 2))
    raw = encode_poses(msg)
    assert len(raw) == 22 + 36 * n
    assert decode_poses(raw) == msg and m.decode(raw) == msg and m.encode(msg) == raw
    got_step, got_ids, got_xy = decode_positions(raw, 1e6)  # the robot's reader: the same
    assert (got_step, got_ids) == (step, ids) and np.array_equal(got_xy, msg.xy)
    assert got_xy.shape == (n, 2)


def test_robot_reader_refuses_what_the_decoder_refuses_and_far_positions() -> None:
    head = struct.Struct("<BBQdI")
    good = encode_poses(batch(1, [0, 1]))
    bad: list[bytes] = [head.pack(Tag.POSES, m.VERSION, 1, 0.1, 2**32 - 1),
                        head.pack(Tag.POSES, m.VERSION, 1, 0.1, 3) + bytes(36),
                        good + b"\0", b"\x01" + good[1:]]
    for offset, value in [(4, float("nan")), (12, float("-inf")), (20, float("nan")),
                          (36 + 28, float("inf"))]:  # x, y, vx of robot 0, vy of robot 1
        broken = bytearray(good)
        broken[22 + offset: 22 + offset + 8] = struct.pack("<d", value)
        bad.append(bytes(broken))
    twice = bytearray(good)
    twice[22 + 36: 22 + 40] = struct.pack("<I", 0)
    bad.append(bytes(twice))
    for raw in bad:
        with pytest.raises(MessageError) as full:
            decode_poses(raw)
        with pytest.raises(MessageError) as lean:
            decode_positions(raw, 1e6)
        assert str(lean.value) == str(full.value)
    far = encode_poses(batch(1, [0, 1], [[0.0, 0.0], [0.0, -2e6]]))
    decode_poses(far)  # a valid message ...
    with pytest.raises(MessageError, match="beyond"):  # ... that a robot does not take
        decode_positions(far, 1e6)
    assert decode_positions(encode_poses(batch(3, [])), 1e6)[:2] == (3, [])


def test_refused_before_allocation_and_by_value() -> None:
    head = struct.Struct("<BBQdI")
    with pytest.raises(MessageError, match="at most 4096"):  # a huge claimed count
        decode_poses(head.pack(Tag.POSES, m.VERSION, 1, 0.1, 2**32 - 1))
    with pytest.raises(MessageError, match="truncated"):  # claims more rows than there are
        decode_poses(head.pack(Tag.POSES, m.VERSION, 1, 0.1, 3) + bytes(36))
    good = encode_poses(batch(1, [0, 1]))
    with pytest.raises(MessageError, match="trailing"):
        decode_poses(good + b"\0")
    with pytest.raises(MessageError, match="expected poses"):
        decode_poses(b"\x01" + good[1:])
    nan = bytearray(good)
    nan[22 + 4: 22 + 12] = struct.pack("<d", float("nan"))
    with pytest.raises(MessageError, match="finite"):
        decode_poses(bytes(nan))
    twice = bytearray(good)
    twice[22 + 36: 22 + 40] = struct.pack("<I", 0)  # robot 0 twice
    with pytest.raises(MessageError, match="ascending"):
        decode_poses(bytes(twice))
    with pytest.raises(MessageError, match="ascending"):
        encode_poses(batch(1, [1, 0]))
    with pytest.raises(MessageError, match="at most"):
        encode_poses(batch(1, list(range(MAX_POSES_ROBOTS + 1))))
    with pytest.raises(MessageError, match="finite"):
        encode_poses(batch(1, [0], [[float("inf"), 0.0]]))


def make_inbox(realtime: bool) -> tuple[PoseInbox, list[str]]:
    dropped: list[str] = []
    inbox = PoseInbox(1, SWARM, realtime=realtime, rate_hz=10.0, lockstep_deadline_s=0.02,
                      stale_s=0.5, log=Log("test", False, "error"),
                      drop=lambda what, why: dropped.append(f"{what}: {why}"))
    return inbox, dropped


def ready(inbox: PoseInbox) -> Step | None:
    now = time.monotonic()
    return inbox.next_step(now, now, False, busy=lambda: True)


@pytest.mark.parametrize("realtime", [False, True])
def test_inbox_decides_each_new_step_at_once_and_only_the_newest(realtime: bool) -> None:
    inbox, dropped = make_inbox(realtime)
    inbox.take_batch(encode_poses(batch(3, [0, 1, 2])))
    s = ready(inbox)
    assert s is not None and s.step == 3 and s.ids == [0, 1, 2]
    np.testing.assert_array_equal(s.positions, [[0, 0], [1, 2], [2, 4]])
    assert ready(inbox) is None  # once
    inbox.take_batch(encode_poses(batch(4, [0, 1, 2])))  # fell behind: 4 and 5 came
    inbox.take_batch(encode_poses(batch(5, [0, 1])))
    s = ready(inbox)
    assert s is not None and s.step == 5 and s.ids == [0, 1]
    inbox.take_batch(encode_poses(batch(5, [0, 1])))  # a duplicate: nothing new
    assert ready(inbox) is None
    inbox.take_batch(encode_poses(batch(6, [0, 2])))  # without this robot: nothing to do
    assert ready(inbox) is None
    inbox.take_batch(encode_poses(batch(0, [0, 1])))  # our step went back: world restarted
    s = ready(inbox)
    assert s is not None and s.step == 0
    inbox.take_batch(b"\x06\x01junk")
    inbox.take_batch(encode_poses(batch(9, [1], [[2e6, 0.0]])))
    assert len(dropped) == 2 and ready(inbox) is None
    assert inbox.silence_s(time.monotonic()) is not None


def test_recorder_logs_a_batch_as_per_robot_poses(tmp_path: Path) -> None:
    path = tmp_path / "b.mcap"
    with Recorder(path) as rec:
        for step in range(3):
            rec.write_wire(keys.poses_key(SWARM), encode_poses(batch(step, [2, 5])))
        rec.write_wire(keys.poses_key(SWARM), b"\x06\x01bad")
    run = read_log(path)
    assert run.frames.steps.tolist() == [0, 1, 2] and run.frames.ids.tolist() == [2, 5]
    np.testing.assert_array_equal(run.frames.xy[1], [[2.0, 4.0], [5.0, 10.0]])
    assert run.topics[keys.pose_key(SWARM, 5)] == 3 and "/robot/5/pose" in run.topics
    assert keys.poses_key(SWARM) not in run.topics


def test_only_the_world_may_publish_all_poses() -> None:
    acl = access_control(SWARM, 3)
    puts = {r["id"]: r["key_exprs"] for r in acl["rules"] if r["messages"] == ["put"]}
    assert keys.poses_key(SWARM) in puts["world-put"]
    assert all(keys.poses_key(SWARM) not in v for k, v in puts.items() if k.startswith("robot"))
