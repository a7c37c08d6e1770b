"""A robot's own certificate floods its own status key with valid 64 KiB statuses: the world's
log and ``patternrl record``'s grow by the key's budget only, and the drops are counted."""

from __future__ import annotations

import random
import string
import time
from contextlib import AbstractContextManager
from pathlib import Path

import pytest
import zenoh
from support import free_port

from runtime.net.session import open_session
from runtime.wire import keys
from runtime.wire.messages import MAX_STATUS_BYTES, Status, encode_status
from sim_bridge.log.budget import BUDGETS, KeyBudget
from sim_bridge.log.reader import read_log
from sim_bridge.log.record import SwarmRecorder
from sim_bridge.log.recorder import Recorder
from sim_bridge.world.world_link import WorldLink

SENT = 400
"""Valid 64 KiB statuses put as fast as the link takes them: 25 MiB."""


def _big_status() -> bytes:
    """A valid status as large as the wire allows, of text that does not compress."""
    st = Status(1, 5, "rule:assign", 10.0, 20.0, 0.1, 0, 0, 0, "", 1.0)
    pad = MAX_STATUS_BYTES - len(encode_status(st)) - 8
    text = "".join(random.Random(0).choices(string.ascii_letters, k=pad))
    payload = encode_status(Status(1, 5, "rule:assign", 10.0, 20.0, 0.1, 0, 0, 0, text, 1.0))
    assert MAX_STATUS_BYTES - 64 < len(payload) <= MAX_STATUS_BYTES
    return payload


@pytest.mark.parametrize("consumer", ["world", "record"])
def test_a_flooded_key_costs_the_log_its_budget_only(tmp_path: Path, consumer: str) -> None:
    swarm, port = f"flood{consumer}", free_port()
    sink = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    robot = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"], listen=[])
    log = tmp_path / "run.mcap"
    rec = Recorder(log)
    taker: AbstractContextManager[object]
    if consumer == "world":
        link = WorldLink(sink, swarm, lockstep=True, recorder=rec,
                         event=lambda kind, **f: rec.event(kind, 0, 0.0, **f))
        taker, budget = link, link.budget
    else:
        sr = SwarmRecorder(sink, swarm, rec)
        taker, budget = sr, sr.budget
    assert isinstance(budget, KeyBudget)
    payload = _big_status()
    key = keys.status_key(swarm, 1)
    try:
        with rec, taker:
            pub = robot.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            deadline = time.monotonic() + 20.0
            while not pub.matching_status.matching:
                assert time.monotonic() < deadline, "the flood never found its listener"
                time.sleep(0.01)
            t0 = time.monotonic()
            for _ in range(SENT):
                pub.put(payload)
            deadline = time.monotonic() + 30.0
            while budget.allowed + budget.dropped < SENT:  # reliable, blocking: all arrive
                assert time.monotonic() < deadline, (budget.allowed, budget.dropped)
                time.sleep(0.01)
            elapsed = time.monotonic() - t0
            pub.undeclare()  # type: ignore[no-untyped-call]
    finally:
        robot.close()  # type: ignore[no-untyped-call]
        sink.close()  # type: ignore[no-untyped-call]
    b = BUDGETS[keys.STATUS]
    allowed_at_most = b.messages * (1.0 + elapsed)  # one second's burst, then the rate
    assert budget.allowed <= allowed_at_most + 1
    assert budget.dropped >= SENT - allowed_at_most - 1 and budget.dropped_by_key == {
        key: budget.dropped}
    size = log.stat().st_size
    assert size < b.bytes * (1.0 + elapsed) + (1 << 20), (size, elapsed)  # not 25 MiB
    events = read_log(log).events_of("over_budget")
    assert [e["key"] for e in events] == [key]  # said once
