"""A robot process's side of the slot agreement: what it keeps of what its team tells, what
it hears at a step (the told step, the pattern held, the very team for the leader's
assignment, the simulated loss), and what it drops."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from runtime.conditions import PERFECT, parse_conditions
from runtime.decision.agreement import AGREE_MODES, hears
from runtime.net.session import tells_each_other
from runtime.robot.cli import add_arguments, config_from_args
from runtime.robot.slot_talk import KEEP_STEPS, SlotTalk
from runtime.wire import keys
from runtime.wire.messages import NO_SLOT, Slots, encode_slots
from runtime.world_config import DEFAULT_WORLD

SWARM = "s"
TEAM = (0, 2, 5)


class Drops:
    def __init__(self) -> None:
        self.why: list[str] = []

    def __call__(self, what: str, why: str) -> None:
        self.why.append(f"{what}: {why}")


def talk(conditions: str = "perfect", me: int = 2) -> tuple[SlotTalk, Drops]:
    drops = Drops()
    return SlotTalk(me, parse_conditions(conditions), (0, me), drops), drops


def tell(t: SlotTalk, rid: int, step: int, slot: int, version: int = 1,
         full: tuple[int, ...] | None = None) -> None:
    msg = (Slots(rid, step, version, slot) if full is None
           else Slots(rid, step, version, slot, np.array(TEAM), np.array(full)))
    t.take(keys.slots_key(SWARM, rid), encode_slots(msg))


def test_a_step_hears_what_was_told_a_step_before_for_the_pattern_held() -> None:
    t, drops = talk()
    tell(t, 0, 9, 2, full=(2, 0, 1))  # the leader (robot 0, row 0)
    tell(t, 5, 9, 0)  # robot 5 claims slot 0: robot 2's own under the leader's
    tell(t, 5, 10, 1)  # told at 10: heard at 11, not at 10
    heard = t.heard(10, TEAM, 1, version=1)
    assert heard.claims.tolist() == [2, -1, 0] and heard.claim_steps.tolist() == [9, -1, 9]
    assert heard.leader is not None and heard.leader.tolist() == [2, 0, 1]
    assert t.heard_messages == 2 and not drops.why
    again = t.heard(11, TEAM, 1, version=1)  # nothing from the leader at 10: its last kept
    assert again.claims.tolist() == [2, -1, 1] and again.claim_steps.tolist() == [9, -1, 10]
    assert again.leader is not None and again.leader.tolist() == [2, 0, 1]
    other = talk()[0]
    tell(other, 0, 9, 2, version=2, full=(2, 0, 1))  # for another pattern: not heard
    tell(other, 5, 9, NO_SLOT)  # a robot holding still claims nothing
    h = other.heard(10, TEAM, 1, version=1)
    assert h.leader is None and (h.claims == -1).all()


def test_the_leaders_frame_is_heard_with_its_assignment() -> None:
    t, _ = talk()
    t.take(keys.slots_key(SWARM, 0), encode_slots(
        Slots(0, 4, 1, 2, np.array(TEAM), np.array([2, 0, 1]), (3.0, 4.0))))
    h = t.heard(5, TEAM, 1, version=1)
    assert h.frame is not None and h.frame.tolist() == [3.0, 4.0]
    tell(t, 0, 5, 2, full=(2, 0, 1))  # a frameless message: the last frame heard kept
    h = t.heard(6, TEAM, 1, version=1)
    assert h.frame is not None and h.frame.tolist() == [3.0, 4.0]
    other, _ = talk()
    other.take(keys.slots_key(SWARM, 0), encode_slots(
        Slots(0, 4, 1, 2, np.array(TEAM), np.array([2, 0, 1]), (3.0, 4.0))))
    assert other.heard(5, (0, 2, 5, 7), 1, version=1).frame is None  # another team


def test_the_leaders_assignment_counts_for_its_very_team_only() -> None:
    t, _ = talk()
    tell(t, 0, 4, 2, full=(2, 0, 1))
    h = t.heard(5, (0, 2, 5, 7), 1, version=1)  # robot 7 joined: another team
    assert h.leader is None and h.claims.tolist()[0] == 2
    t2, _ = talk()
    tell(t2, 5, 4, 1, full=None)
    h2 = t2.heard(5, TEAM, 1, version=1)  # robot 5 is not the leader
    assert h2.leader is None and h2.claims.tolist() == [-1, -1, 1]


def test_the_conditions_delay_and_lose_what_is_heard_the_same_way_each_run() -> None:
    late, _ = talk("perfect,latency_steps=3")
    tell(late, 5, 7, 1)
    assert late.heard(9, TEAM, 1, 1).claims.tolist() == [-1, -1, -1]
    assert late.heard(10, TEAM, 1, 1).claims.tolist() == [-1, -1, 1]

    def lossy() -> list[int]:
        t, _ = talk("perfect,loss=0.5")
        got = []
        for s in range(40):
            tell(t, 5, s, s % 3)
            got.append(int(t.heard(s + 1, TEAM, 1, 1).claim_steps[2]))
        return got

    a, b = lossy(), lossy()
    assert a == b  # seeded
    fresh = sum(g == s for s, g in enumerate(a))
    assert 8 <= fresh <= 32  # about half heard fresh, the rest the last kept


def test_bad_payloads_are_dropped_and_counted_and_what_is_kept_is_bounded() -> None:
    t, drops = talk()
    t.take(keys.slots_key(SWARM, 5), b"\x08\x01junk")
    t.take(keys.slots_key(SWARM, 5), encode_slots(Slots(0, 1, 1, 0)))  # robot 0 on 5's key
    t.take(keys.cmd_key(SWARM, 5), encode_slots(Slots(5, 1, 1, 0)))  # not a slots key
    t.take(keys.slots_key(SWARM, 2), b"anything")  # its own key: ignored, not a drop
    assert len(drops.why) == 3
    assert "truncated" in drops.why[0] or "slots" in drops.why[0]
    assert "robot_id 0 on key" in drops.why[1] and "not a slots key" in drops.why[2]
    for s in range(100):
        tell(t, 5, s, 0)
    kept = t._got[5]
    assert len(kept) <= KEEP_STEPS + 1 and max(kept) == 99


def test_what_a_robot_tells() -> None:
    t, _ = talk(me=0)
    lead = t.told(3, 1, TEAM, 0, np.array([2, 0, 1]))
    assert lead.slot == 2 and lead.ids.tolist() == list(TEAM)
    assert lead.assignment.tolist() == [2, 0, 1] and lead.frame is None
    framed = t.told(3, 1, TEAM, 0, np.array([2, 0, 1]), np.array([4.0, 5.5]))
    assert framed.frame == (4.0, 5.5)
    assert t.told(3, 1, TEAM, 0, np.array([2, 0, 1]), np.array([np.nan, 1.0])).frame is None
    assert talk(me=5)[0].told(3, 1, TEAM, 2, np.array([2, 0, 1]),
                              np.array([4.0, 5.5])).frame is None  # a follower's: no frame
    follower = talk(me=5)[0].told(3, 1, TEAM, 2, np.array([2, 0, 1]))
    assert follower.slot == 1 and follower.ids.size == 0
    assert talk(me=5)[0].told(3, 1, TEAM, 2, None).slot == NO_SLOT
    assert talk(me=5)[0].told(3, 1, TEAM, 2, np.array([0, 1])).slot == NO_SLOT


def test_the_agree_option() -> None:
    p = argparse.ArgumentParser()
    add_arguments(p)
    assert "--agree" in p.format_help()
    args = p.parse_args(["--swarm", SWARM, "--id", "1", "--brain", "rule:assign", "--agree",
                         "--conditions", "realistic"])
    cfg, _ = config_from_args(args, DEFAULT_WORLD)
    assert cfg.agree == "slots" and cfg.conditions != PERFECT
    cfg, _ = config_from_args(p.parse_args(["--swarm", SWARM, "--id", "1", "--brain",
                                            "rule:assign"]), DEFAULT_WORLD)
    assert cfg.agree == "auto"  # the default: the frame, or slots where views are local
    for mode in AGREE_MODES:
        got = p.parse_args(["--swarm", SWARM, "--id", "1", "--brain", "rule:assign",
                            "--agree", mode])
        assert config_from_args(got, DEFAULT_WORLD)[0].agree == mode
    with pytest.raises(SystemExit):  # argparse: a mode it does not know
        p.parse_args(["--swarm", SWARM, "--id", "1", "--brain", "rule:assign", "--agree", "x"])


@pytest.mark.parametrize(("argv", "conditions", "tells"), [
    ([], "realistic", True),  # the leader's frame, under noise
    ([], "perfect", False),
    ([], "perfect,latency_steps=2", False),  # exact views: one frame without telling
    (["--agree"], "perfect,latency_steps=2", True),  # slots under any imperfect sensing
    (["--agree", "off"], "realistic", False),
    ([], "realistic,k_nearest=6", True),  # local noisy views: slots too
    ([], "perfect,k_nearest=6", False),  # local exact views: one plan, nothing to tell
])
def test_who_tells_and_enforces_every_robots_rules(argv: list[str], conditions: str,
                                                    tells: bool) -> None:
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--swarm", SWARM, "--id", "1", "--brain", "rule:assign",
                         "--conditions", conditions, *argv])
    assert tells_each_other(args) is tells
    cfg, _ = config_from_args(args, DEFAULT_WORLD)
    assert hears(cfg.agree, cfg.conditions) is tells


def test_telling_the_frame_alone_the_leader_tells_and_its_frame_is_all_that_is_heard() -> None:
    drops = Drops()
    follower = SlotTalk(2, parse_conditions("realistic,loss=0"), (0, 2), drops, slots=False)
    assert follower.told(3, 1, TEAM, 1, np.array([2, 0, 1]), np.array([1.0, 2.0])) is None
    lead = SlotTalk(0, parse_conditions("realistic,loss=0"), (0, 0), drops, slots=False)
    assert lead.told(3, 1, TEAM, 0, np.array([2, 0, 1]), None) is None  # no frame yet
    msg = lead.told(3, 1, TEAM, 0, np.array([2, 0, 1]), np.array([1.0, 2.0]))
    assert msg is not None and msg.frame == (1.0, 2.0) and msg.assignment.tolist() == [2, 0, 1]
    follower.take(keys.slots_key(SWARM, 0), encode_slots(msg))
    tell(follower, 5, 3, 1)  # robot 5 claims robot 2's own slot: not heard in this mode
    h = follower.heard(4, TEAM, 1, version=1)
    assert h.frame is not None and h.frame.tolist() == [1.0, 2.0]
    assert h.leader is None and (h.claims == -1).all() and not drops.why


def test_a_new_pattern_forgets_what_was_heard_of_the_last() -> None:
    t, _ = talk()
    t.take(keys.slots_key(SWARM, 0), encode_slots(
        Slots(0, 4, 1, 2, np.array(TEAM), np.array([2, 0, 1]), (3.0, 4.0))))
    tell(t, 5, 4, 1)
    h = t.heard(5, TEAM, 1, version=1)
    assert h.frame is not None and h.leader is not None and h.claims.tolist() == [2, -1, 1]
    nothing = t.heard(6, TEAM, 1, version=2)  # the next pattern: its frame and slots are new
    assert nothing.frame is None and nothing.leader is None and (nothing.claims == -1).all()
