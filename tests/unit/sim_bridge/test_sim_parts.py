"""The world's parts on their own: phase measures, the roster, brain labels and the Zenoh link."""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from runtime.decision.formation import (
    assign_slots,
    formation_error,
    formation_error_batch,
    slot_distances,
)
from runtime.decision.patterns import make_pattern
from runtime.net.session import open_session
from runtime.wire import keys
from runtime.wire.messages import Command, decode_poses, encode_command
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.launch.launch import free_port
from sim_bridge.world.brain_choice import BrainChoice, rule_choice
from sim_bridge.world.brain_swaps import phase_brain_label
from sim_bridge.world.membership import Roster
from sim_bridge.world.phase_tally import PhaseTally, formation_measure
from sim_bridge.world.sim_world import SimConfig, phase_step_limit
from sim_bridge.world.world_link import WorldLink

W = DEFAULT_WORLD


def test_formation_measure_is_the_shared_definition() -> None:
    rng = np.random.default_rng(0)
    C = make_pattern("heart", 7, W)
    P = C[::-1] + rng.normal(scale=0.2, size=C.shape) + np.array([3.0, -1.0])
    err, far = formation_measure(P, C)
    assert err == pytest.approx(formation_error(P, C), abs=1e-12)
    assert err == pytest.approx(formation_error_batch(P[None], C)[0], abs=1e-12)
    assert far == pytest.approx(slot_distances(P, C, assign_slots(P, C)).max(), abs=1e-12)
    err0, far0 = formation_measure(C + np.array([5.0, 5.0]), C)  # a translated pattern is formed
    assert err0 == pytest.approx(0.0, abs=1e-12) and far0 == pytest.approx(0.0, abs=1e-12)


def test_phase_tally_counts_a_collision_once_per_encounter() -> None:
    C = make_pattern("line", 2, W)
    gap = W.min_separation_m
    ids = [4, 9]
    xs = (3.0, 0.5, 0.4, 3.0, 3.0, 0.5)  # in units of the minimum separation
    at = [np.array([[0.0, 0.0], [x * gap, 0.0]]) for x in xs]
    tally = PhaseTally()
    tally.start(at[0], C)
    new = [tally.step(ids, a, b, C, [], [9], W).new_collisions
           for a, b in itertools.pairwise(at)]
    # overlapping over three steps in a row is one encounter; apart, then close again: a second
    assert new == [[(4, 9)], [], [], [], [(4, 9)]]
    assert tally.collisions == 2 and tally.deadline_misses == 5
    assert tally.min_separation_m == pytest.approx(0.4 * gap)
    assert tally.travel_m == pytest.approx(7.7 * gap)
    assert not tally.formed(W)


def test_a_pattern_gets_twice_its_lower_bound_and_at_least_the_worlds_step_limit() -> None:
    assert SimConfig().max_steps is None  # the default: from each pattern's lower bound
    assert phase_step_limit(0) == phase_step_limit(150) == DEFAULT_WORLD.step_limit
    assert phase_step_limit(201) == 402 and phase_step_limit(694) == 1388


def test_phase_brain_label() -> None:
    choice = BrainChoice("b.onnx", "a" * 64, "general", "b.onnx (aaaaaaaa)")
    assert phase_brain_label(choice, ["a" * 64]) == "b.onnx (aaaaaaaa)"
    assert phase_brain_label(choice, ["a" * 64, "b" * 64]).endswith("(not in every robot)")
    assert phase_brain_label(None, ["rule:assign", "c" * 64]) == "rule:assign, cccccccc"
    assert phase_brain_label(None, []) == "unknown"
    assert rule_choice().kind == "rule"


def test_roster_follows_tokens_and_hands_over_changes_once() -> None:
    cond = threading.Condition(threading.Lock())
    roster = Roster(cond)
    stop = threading.Event()
    roster.saw(2, joined=True)
    roster.saw(0, joined=True)
    roster.saw(2, joined=False)
    assert roster.alive_ids() == [0] and roster.gone == {2}
    assert list(roster.changes()) == [(True, 2), (True, 0), (False, 2)]
    assert list(roster.changes()) == []
    roster.saw(2, joined=True)
    assert roster.gone == set() and roster.wait_for(2, 0.0, stop) == 2
    stop.set()  # a stop ends the wait at once
    assert roster.wait_for(5, 60.0, stop) == 2


@pytest.mark.timeout(60)
def test_world_link_exchanges_a_step_with_a_robot() -> None:
    swarm, port = "unit-link", free_port()
    world = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    robot = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"], listen=[])
    events: list[tuple[str, dict[str, Any]]] = []
    link = WorldLink(world, swarm, lockstep=True, recorder=None,
                     event=lambda kind, **f: events.append((kind, f)))
    stop = threading.Event()

    def answer(sample: Any) -> None:  # the robot: each step's poses answered with a command
        pose = decode_poses(sample.payload.to_bytes())
        robot.put(keys.cmd_key(swarm, 1), encode_command(
            Command(1, pose.step, 0.25, -0.5, "rule:assign", False, 0.0, 12.0)))

    try:
        with link:
            link.open()  # a second open declares nothing more
            sub = robot.declare_subscriber(keys.poses_key(swarm), answer)
            token = robot.liveliness().declare_token(keys.alive_key(swarm, 1))
            assert link.roster.wait_for(1, 20.0, stop) == 1
            link.add_robot(1, 0.5, 0.5)
            pos = np.array([[1.0, 2.0]])
            v, missed, age = link.exchange(0, W.dt_s, [1], pos, 20.0, stop)
            assert missed == [] and v.tolist() == [[0.25, -0.5]] and age.tolist() == [0]
            assert link.brains() == {1: "rule:assign"} and link.decision_us == [12.0]
            robot.put(keys.cmd_key(swarm, 1), b"\x00garbage")  # dropped and counted
            deadline = time.monotonic() + 30.0  # delivery is asynchronous: wait, bounded
            while link.malformed < 1 and time.monotonic() < deadline:
                time.sleep(0.01)
            link.put_pattern(b"pattern")
            token.undeclare()
            sub.undeclare()
            v, missed, age = link.exchange(1, W.dt_s, [1], pos, 20.0, stop)  # gone: no wait
            assert missed == [1] and v.tolist() == [[0.0, 0.0]] and age.tolist() == [-1]
        link.close()  # closing twice is harmless
        assert link.malformed == 1 and events[0][0] == "malformed"
    finally:
        robot.close()  # type: ignore[no-untyped-call]
        world.close()  # type: ignore[no-untyped-call]


@pytest.mark.timeout(120)
def test_a_realtime_step_that_brings_news_waits_for_every_command_and_does_its_work_meanwhile(
) -> None:
    """The run's first step, a pattern's first and the first after a join wait for every
    robot's command (a realtime step otherwise waits its whole period); the world's own work
    of that step (the phase's lower bounds) runs once the poses are out, while the robots
    decide, and the commands that come meanwhile count."""
    swarm, port = "unit-news", free_port()
    world = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    robot = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"], listen=[])
    link = WorldLink(world, swarm, lockstep=False, recorder=None, event=lambda kind, **f: None)
    stop = threading.Event()
    answered = threading.Event()

    def answer(sample: Any) -> None:
        pose = decode_poses(sample.payload.to_bytes())
        robot.put(keys.cmd_key(swarm, 1), encode_command(
            Command(1, pose.step, 0.1, 0.2, "rule:assign", False, 0.0, 12.0)))
        answered.set()

    def meanwhile() -> None:  # the world's work outlasts the robot's answer
        assert answered.wait(60.0)

    try:
        with link:
            link.open()
            sub = robot.declare_subscriber(keys.poses_key(swarm), answer)
            token = robot.liveliness().declare_token(keys.alive_key(swarm, 1))
            assert link.roster.wait_for(1, 20.0, stop) == 1
            link.add_robot(1, 0.5, 0.5)
            pos = np.array([[1.0, 2.0]])
            # a deadline far beyond the test's timeout: only the answer can end the wait
            v, missed, age = link.exchange(0, W.dt_s, [1], pos, 3600.0, stop, wait_all=True,
                                           meanwhile=meanwhile)
            assert answered.is_set()
            assert missed == [] and v.tolist() == [[0.1, 0.2]] and age.tolist() == [0]
            token.undeclare()
            sub.undeclare()
    finally:
        robot.close()  # type: ignore[no-untyped-call]
        world.close()  # type: ignore[no-untyped-call]


def test_the_worlds_next_pattern_is_numbered_above_an_operators() -> None:
    """An operator's pattern at the edge of what robots take: the world's next phase is
    numbered above it (so it wins at every robot), never more than MAX_VERSION_STEP past
    the world's last (so every robot takes it); versions further out are not followed."""
    from runtime.decision.team_pattern import MAX_VERSION_STEP
    from runtime.wire.messages import PatternMsg, encode_pattern

    swarm, port = "unit-numbering", free_port()
    world = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    operator = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"], listen=[])
    link = WorldLink(world, swarm, lockstep=True, recorder=None, event=lambda kind, **f: None)
    key = keys.operator_pattern_key(swarm)
    circle = make_pattern("circle", 4)

    def heard(v: int) -> None:
        """Put ``v`` and then a malformed marker: once the world counted the marker, ``v``
        has arrived (one publisher's samples arrive in order)."""
        want = link.malformed + 1
        pub.put(encode_pattern(PatternMsg(v, "circle", circle, W.formed_tol_m)))
        pub.put(b"\x00marker")
        deadline = time.monotonic() + 20.0
        while link.malformed < want:
            assert time.monotonic() < deadline, "the operator's puts never reached the world"
            time.sleep(0.01)

    pub = operator.declare_publisher(key)
    try:
        with link:
            deadline = time.monotonic() + 20.0  # the world's subscription reached the operator
            while not pub.matching_status.matching:
                assert time.monotonic() < deadline, "the world never subscribed"
                time.sleep(0.01)
            assert link.next_pattern_version() == 1
            heard(1 + MAX_VERSION_STEP - 1)  # the farthest an operator's is followed
            assert link.next_pattern_version() == 1 + MAX_VERSION_STEP
            heard(5_000_000)  # robots refuse it: the world does not follow it either
            heard(3)  # older than the world's: nothing
            assert link.next_pattern_version() == 2 + MAX_VERSION_STEP
    finally:
        pub.undeclare()  # type: ignore[no-untyped-call]
        operator.close()  # type: ignore[no-untyped-call]
        world.close()  # type: ignore[no-untyped-call]


def test_launch_notes_the_patterns_inside_the_guard_once(tmp_path: Path) -> None:
    """``launch --conditions harsh``: one line naming every pattern the guard (0.45 m) keeps
    its neighbours out of; a pattern spaced wider, and the realistic preset's guard (0.35 m),
    draw none."""
    from runtime.conditions import parse_conditions
    from sim_bridge.launch.launch import guard_notes

    wide = tmp_path / "wide.csv"
    pts = make_pattern("cross", 8)
    pts = pts * (0.6 / 0.4)
    wide.write_text("".join(f"{x},{y}\n" for x, y in pts))
    harsh = guard_notes(["circle", str(wide), "line", "circle"], 8, parse_conditions("harsh"))
    assert len(harsh) == 1 and harsh[0].startswith("note: circle, line: the pattern's closest")
    assert guard_notes(["circle", "line"], 8, parse_conditions("realistic")) == []
