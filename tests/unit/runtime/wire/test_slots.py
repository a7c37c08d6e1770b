"""The slots message (slot agreement): round trip, bounds before allocation, values and
meaning, who may publish it, what it may cost, and its channel in a real MCAP log."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

import runtime.wire.messages as m
from runtime.net.identity import access_control
from runtime.wire import keys
from runtime.wire.messages import (
    MAX_SLOTS_ROBOTS,
    NO_SLOT,
    MessageError,
    Slots,
    Tag,
    decode_slots,
    encode_slots,
)
from sim_bridge.log import schemas as pb
from sim_bridge.log.budget import BUDGETS
from sim_bridge.log.layout import PB_SCHEMAS
from sim_bridge.log.recorder import Recorder

SWARM = "s"
HEAD = struct.Struct("<BBIQQII")


def leader(rid: int = 3, ids: tuple[int, ...] = (3, 5, 9), a: tuple[int, ...] = (2, 0, 1),
           step: int = 7) -> Slots:
    me = ids.index(rid) if rid in ids else 0
    return Slots(rid, step, 4, a[me], np.array(ids), np.array(a))


@settings(max_examples=50, deadline=None)
@given(step=st.integers(0, 2**64 - 1), version=st.integers(0, 2**64 - 1),
       ids=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=40, unique=True),
       data=st.data())
def test_round_trip(step: int, version: int, ids: list[int], data: st.DataObject) -> None:
    ids = sorted(ids)
    n = len(ids)
    perm = data.draw(st.permutations(list(range(n))))
    me = data.draw(st.integers(0, n - 1))
    full = Slots(ids[me], step, version, perm[me], np.array(ids), np.array(perm))
    claim = Slots(ids[me], step, version, data.draw(st.sampled_from([perm[me], NO_SLOT])))
    for msg, size in ((full, HEAD.size + 6 * n), (claim, HEAD.size)):
        raw = encode_slots(msg)
        assert len(raw) == size and raw[0] == Tag.SLOTS
        back = decode_slots(raw)
        assert back == msg and m.decode(raw) == msg and m.encode(msg) == raw
        assert not back.ids.flags.writeable and not back.assignment.flags.writeable
    assert decode_slots(encode_slots(full)).assignment.tolist() == perm
    fx, fy = data.draw(st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False)] * 2))
    framed = Slots(ids[me], step, version, perm[me], np.array(ids), np.array(perm), (fx, fy))
    raw = encode_slots(framed)
    assert len(raw) == HEAD.size + 6 * n + 16
    back = decode_slots(raw)
    assert back == framed and back.frame == (fx, fy) and back != full


def test_a_frame_is_bounded_and_comes_only_with_the_leaders_assignment() -> None:
    good = encode_slots(leader())
    framed = encode_slots(Slots(3, 7, 4, 2, np.array([3, 5, 9]), np.array([2, 0, 1]),
                                (1.5, -2.0)))
    assert framed[:len(good)] == good and decode_slots(framed).frame == (1.5, -2.0)
    for x in (float("nan"), float("inf"), 2e6):
        with pytest.raises(MessageError, match=r"slots\.frame must be finite"):
            decode_slots(good + struct.pack("<dd", x, 0.0))
        with pytest.raises(MessageError, match=r"slots\.frame must be finite"):
            encode_slots(Slots(3, 7, 4, 2, np.array([3, 5, 9]), np.array([2, 0, 1]),
                               (0.0, x)))
    claim = encode_slots(Slots(1, 3, 0, 0))
    with pytest.raises(MessageError, match="only with the leader's assignment"):
        decode_slots(claim + struct.pack("<dd", 0.0, 0.0))
    with pytest.raises(MessageError, match="only with the leader's assignment"):
        encode_slots(Slots(1, 3, 0, 0, frame=(0.0, 0.0)))
    with pytest.raises(MessageError, match="trailing"):  # half a frame
        decode_slots(good + struct.pack("<d", 1.0))
    with pytest.raises(MessageError, match=r"slots.frame: \(x, y\) expected"):
        Slots(3, 7, 4, 2, frame=(1.0,))  # type: ignore[arg-type]
    parsed = pb.parse(pb.ROBOT_SLOTS, pb.slots_pb(decode_slots(framed)))
    assert list(parsed.frame) == [1.5, -2.0]
    assert pb.slots_of(parsed) == decode_slots(framed)
    assert pb.slots_of(pb.parse(pb.ROBOT_SLOTS, pb.slots_pb(leader()))).frame is None
    del parsed.frame[1]
    with pytest.raises(MessageError, match="none or"):
        pb.slots_of(parsed)


def test_refused_before_allocation() -> None:
    with pytest.raises(MessageError, match=f"at most {MAX_SLOTS_ROBOTS}"):  # a huge count
        decode_slots(HEAD.pack(Tag.SLOTS, m.VERSION, 1, 3, 0, 0, 2**32 - 1))
    with pytest.raises(MessageError, match="truncated"):  # claims more than there is
        decode_slots(HEAD.pack(Tag.SLOTS, m.VERSION, 1, 3, 0, 0, 3) + bytes(6))
    with pytest.raises(MessageError, match="truncated"):
        decode_slots(HEAD.pack(Tag.SLOTS, m.VERSION, 1, 3, 0, 0, 0)[:-1])
    good = encode_slots(leader())
    with pytest.raises(MessageError, match="trailing"):
        decode_slots(good + b"\0")
    with pytest.raises(MessageError, match="expected slots"):
        decode_slots(b"\x03" + good[1:])
    with pytest.raises(MessageError, match="bytes-like"):
        decode_slots("not bytes")  # type: ignore[arg-type]


def test_refused_by_value_and_meaning() -> None:
    good = bytearray(encode_slots(leader()))
    ids_at, a_at = HEAD.size, HEAD.size + 12

    def bad(at: int, fmt: str, value: int, match: str) -> None:
        raw = bytearray(good)
        raw[at: at + struct.calcsize(fmt)] = struct.pack(fmt, value)
        with pytest.raises(MessageError, match=match):
            decode_slots(bytes(raw))
        with pytest.raises(MessageError, match=match):
            m.decode(bytes(raw))

    bad(ids_at + 4, "<I", 3, "ascending")  # robot 3 twice
    bad(a_at, "<H", 0, "its own slot")  # slot 0 twice (robot 3's entry: 2 -> 0)
    bad(a_at + 2, "<H", 7, "its own slot")  # a slot beyond the team
    bad(2, "<I", 4, "not among the ids")  # the sender is not in its team
    bad(22, "<I", 1, "not its own")  # its slot is not its own entry (2)
    claim = bytearray(encode_slots(Slots(1, 3, 0, 0)))
    claim[22:26] = struct.pack("<I", MAX_SLOTS_ROBOTS)  # a claim beyond any team
    with pytest.raises(MessageError, match="beyond any team"):
        decode_slots(bytes(claim))


def test_encoder_refuses_what_the_decoder_would() -> None:
    with pytest.raises(MessageError, match="ascending"):
        encode_slots(leader(ids=(9, 5, 3)))
    with pytest.raises(MessageError, match="not among"):
        encode_slots(leader(rid=4))
    with pytest.raises(MessageError, match="its own slot"):
        encode_slots(leader(a=(0, 0, 1)))
    with pytest.raises(MessageError, match="slots: 3 ids but 2"):
        encode_slots(Slots(3, 1, 0, 0, np.array([3, 5, 9]), np.array([0, 1])))
    with pytest.raises(MessageError, match="step"):
        encode_slots(Slots(3, -1, 0, 0))
    with pytest.raises(MessageError, match="assignment must be in"):
        Slots(3, 1, 0, 0, np.array([3]), np.array([-1]))


def test_a_robot_may_publish_its_own_slots_only_and_its_budget_fits_a_step() -> None:
    acl = access_control(SWARM, 3)
    puts = {r["id"]: r["key_exprs"] for r in acl["rules"] if r["messages"] == ["put"]}
    for i in range(3):
        mine = puts[f"robot-{i}-put"]
        assert keys.slots_key(SWARM, i) in mine
        assert all(keys.slots_key(SWARM, j) not in mine for j in range(3) if j != i)
    assert keys.parse_key(keys.slots_key(SWARM, 2)) == keys.Key(SWARM, keys.SLOTS, 2)
    b = BUDGETS[keys.SLOTS]
    assert b.messages >= 213  # one a step at lockstep's fastest measured rate
    n100 = leader(rid=0, ids=tuple(range(100)), a=tuple(range(100)))
    assert b.bytes >= 213 * len(encode_slots(n100))  # the leader's, at 100 robots


def test_the_recorder_writes_the_slots_channel_and_play_back_gives_the_payload(
        tmp_path: Path) -> None:
    msg = leader()
    raw = encode_slots(msg)
    path = tmp_path / "slots.mcap"
    with Recorder(path) as rec:
        rec.write_wire(keys.slots_key(SWARM, 3), raw, 10**8)
    with open(path, "rb") as f:
        got = [(s.name, c.topic, d.data) for s, c, d in make_reader(f).iter_messages()]
    mine = [g for g in got if g[1] == keys.slots_key(SWARM, 3)]
    assert len(mine) == 1 and mine[0][0] == PB_SCHEMAS[keys.SLOTS] == pb.ROBOT_SLOTS
    parsed = pb.parse(pb.ROBOT_SLOTS, mine[0][2])
    assert list(parsed.assignment) == [2, 0, 1] and parsed.slot == 2
    assert pb.to_wire(pb.ROBOT_SLOTS, mine[0][2]) == raw
