"""A late robot's prediction of its own motion until its next command applies."""

from __future__ import annotations

import pytest

from runtime.robot.in_flight import MAX_COMMAND_AGE_STEPS, InFlight

DT = 0.1


def test_on_time_nothing_moves() -> None:
    f = InFlight()
    arrived = {s: s * DT for s in range(10)}
    for s in range(5):
        f.sent(s, 1.0, 0.0, s * DT + 0.02, newest_heard=s)  # out before the next poses
    assert f.lag == 0
    assert f.displacement(5, arrived.get, DT) == (0.0, 0.0)


def test_one_step_late_the_command_sent_before_is_counted_once() -> None:
    f = InFlight()
    arrived = {s: s * DT for s in range(10)}
    for s in range(5):  # each command goes out after the next step's poses came: age 1
        f.sent(s, 0.5, -0.25, (s + 1) * DT + 0.01, newest_heard=s + 1)
    assert f.lag == 1
    # deciding on the poses of 5: the world applies the command of 4 at step 5 meanwhile
    assert f.displacement(5, arrived.get, DT) == pytest.approx((0.05, -0.025))


def test_two_steps_late_each_step_gets_the_newest_command_sent_before_it_ended() -> None:
    f = InFlight()
    arrived = {s: s * DT for s in range(8)}  # the poses of 0..7 came at 0.0 .. 0.7 s
    for s, v in zip(range(6), (0.1, 0.2, 0.3, 0.4, 0.5, 0.6), strict=True):
        f.sent(s, v, 0.0, (s + 2) * DT + 0.01, newest_heard=s + 2)
    assert f.lag == 2
    # deciding on 6: step 6 gets the command of 4 (sent at 0.61, before 7's poses at 0.7),
    # step 7 (still to come) the newest sent, that of 5
    assert f.displacement(6, arrived.get, DT) == pytest.approx(((0.5 + 0.6) * DT, 0.0))


def test_a_command_too_old_for_the_world_moves_nothing() -> None:
    f = InFlight()
    for s in range(3):
        f.sent(s, 1.0, 0.0, s * DT, newest_heard=s + 2)
    assert f.lag == 2
    far = 2 + MAX_COMMAND_AGE_STEPS + 1  # the newest (step 2) is too old by then
    assert f.displacement(far, lambda s: None, DT) == (0.0, 0.0)


def test_a_restart_forgets() -> None:
    f = InFlight()
    f.sent(7, 1.0, 0.0, 0.0, newest_heard=9)
    f.sent(0, 1.0, 0.0, 0.1, newest_heard=0)  # the world's steps went back
    assert f.lag == 0 and f.displacement(0, lambda s: None, DT) == (0.0, 0.0)
