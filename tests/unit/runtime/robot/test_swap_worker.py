"""A robot's swap worker: validation off the loop, install between steps, one answer each."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator

import pytest

from runtime.brain.brain import RULE_ASSIGN, Brain, BrainManifest, RuleBrain, read_brain_file
from runtime.decision.observation import ObservationSpec
from runtime.log import Log
from runtime.robot.swap_worker import SwapReply, SwapWorker
from runtime.wire.messages import BrainMsg, encode_brain
from runtime.world_config import DEFAULT_WORLD


class Harness:
    """A swap worker with the robot's side played here: a running brain and counters."""

    def __init__(self, robot_id: int = 1, team: int = 0) -> None:
        self.wake = threading.Condition(threading.Lock())
        self.dropped: list[str] = []
        self.errors: list[str] = []
        self.running: Brain = RuleBrain()
        self.installed: list[Brain] = []
        self.worker = SwapWorker(
            robot_id,
            DEFAULT_WORLD,
            Log("test", False, "error"),
            self.wake,
            team_size=lambda: team,
            drop=lambda what, why: self.dropped.append(what),
            error=self.errors.append,
        )

    def install(self, brain: Brain) -> None:
        self.running = brain
        self.installed.append(brain)

    def replies(self, n: int) -> list[SwapReply]:
        """Apply between two 'steps' until ``n`` replies came (a guard against a hang only)."""
        out: list[SwapReply] = []
        while len(out) < n:
            with self.wake:
                assert self.wake.wait_for(self.worker.busy, timeout=60.0), "no swap in 60 s"
            out += self.worker.apply(lambda: self.running.brain_id, self.install)
        return out


@pytest.fixture
def h() -> Iterator[Harness]:
    h = Harness()
    h.worker.start()
    try:
        yield h
    finally:
        h.worker.close()


def send(
    h: Harness, request: str, manifest: str, data: bytes = b"", to: tuple[int, ...] = ()
) -> None:
    h.worker.offer(encode_brain(BrainMsg(request, manifest, data, to)))


RULE = read_brain_file(RULE_ASSIGN).wire_manifest()


def test_rule_brain_swap_and_a_resend_answered_twice_swapped_once(h: Harness) -> None:
    send(h, "r1", RULE)
    [a] = h.replies(1)
    assert a == SwapReply("r1", True, "already running", RULE_ASSIGN, RULE_ASSIGN)
    send(h, "r1", RULE)  # re-sent: same answer, no second install
    [b] = h.replies(1)
    assert b == a and len(h.installed) == 1


def test_refusals_keep_the_running_brain(h: Harness) -> None:
    send(h, "other", RULE, to=(7,))  # addressed to another robot: no answer
    send(h, "bad", json.dumps({"format": "nope"}))
    no_id = BrainManifest(observation=ObservationSpec("general")).to_json(with_id=False)
    send(h, "noid", no_id, b"onnx bytes")
    replies = h.replies(2)
    assert [r.request for r in replies] == ["bad", "noid"]
    assert all(not r.accepted and r.old_brain == r.new_brain == RULE_ASSIGN for r in replies)
    assert "format" in replies[0].reason and "no brain_id" in replies[1].reason
    assert h.installed == [] and h.errors == []


def test_malformed_message_is_dropped(h: Harness) -> None:
    h.worker.offer(b"\x00garbage")
    send(h, "after", RULE)
    [a] = h.replies(1)
    assert a.request == "after" and h.dropped == ["brain"]
