"""Which target a team forms: fitting a pattern message, and the robot's pattern policy."""

from __future__ import annotations

import numpy as np
import pytest
from support import ROOT

from runtime.brain.brain import RuleBrain, load_brain
from runtime.decision.patterns import PatternError, make_pattern
from runtime.decision.team_pattern import MAX_VERSION_STEP, TeamPattern, fit_pattern
from runtime.wire.messages import PatternMsg

EXPORTS = ROOT / "exports"


def msg(version: int, name: str, points: np.ndarray) -> PatternMsg:
    return PatternMsg(version, name, points, 0.025)


def test_fit_pattern_keeps_rebuilds_or_resamples() -> None:
    pts = make_pattern("circle", 6)
    np.testing.assert_array_equal(fit_pattern("circle", pts, 6), pts)
    np.testing.assert_allclose(fit_pattern("circle", pts, 8), make_pattern("circle", 8))
    line = np.array([[0.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(fit_pattern("custom", line, 4)[:, 0], [0.0, 1.0, 2.0, 3.0])
    with pytest.raises(PatternError, match="closer than 2R"):
        fit_pattern("custom", np.array([[0.0, 0.0], [0.1, 0.0]]), 5)


def test_default_then_newest_message_cached_per_team_size() -> None:
    policy = TeamPattern(None)
    assert policy.for_team(4) == (None, "no pattern yet")
    policy = TeamPattern("line")
    pts, why = policy.for_team(4)
    assert why == "" and pts is not None
    np.testing.assert_allclose(pts, make_pattern("line", 4))
    policy.offer(msg(2, "circle", make_pattern("circle", 4)))
    a, _ = policy.for_team(5)
    b, _ = policy.for_team(5)
    assert a is b  # cached for the same message and team size
    assert a is not None
    np.testing.assert_allclose(a, make_pattern("circle", 5))
    with pytest.raises(PatternError, match="older"):  # refused, counted by the robot
        policy.offer(msg(1, "cross", make_pattern("cross", 4)))
    c, _ = policy.for_team(5)
    assert c is a
    with pytest.raises(PatternError, match="fewer than 2 points"):
        policy.offer(msg(3, "dot", np.zeros((1, 2))))
    with pytest.raises(PatternError, match="closer than 2R"):
        policy.offer(msg(3, "dense", np.zeros((4, 2))))


def test_an_unfittable_message_gives_no_target_and_why() -> None:
    policy = TeamPattern("line")
    policy.offer(msg(1, "custom", make_pattern("line", 3)))
    pts, why = policy.for_team(40)  # 40 points on a 3-point line come closer than 2R
    assert pts is None and "closer than 2R" in why


def test_a_paper_brain_forms_its_own_pattern_only() -> None:
    brain = load_brain(str(EXPORTS / "heart-10-paper.onnx"))
    policy = TeamPattern("line")
    policy.offer(msg(1, "circle", make_pattern("circle", 10)))
    policy.use_brain(brain)
    pts, _ = policy.for_team(10)
    assert pts is not None
    np.testing.assert_allclose(pts, make_pattern("heart", 10))
    pts, why = policy.for_team(9)
    assert pts is None and why == "brain's pattern has 10 points, team 9"
    policy.use_brain(RuleBrain())  # any other brain follows the message again
    pts, _ = policy.for_team(10)
    assert pts is not None
    np.testing.assert_allclose(pts, make_pattern("circle", 10))


def test_a_version_cannot_jump_to_the_end_of_its_range() -> None:
    policy = TeamPattern(None)
    with pytest.raises(PatternError, match="beyond"):
        policy.offer(msg(2**64 - 1, "cross", make_pattern("cross", 4)))
    policy.offer(msg(3, "circle", make_pattern("circle", 4)))
    for bad, why in ((2**64 - 1, "beyond"), (3 + MAX_VERSION_STEP + 1, "jumps"), (2, "older")):
        with pytest.raises(PatternError, match=why):
            policy.offer(msg(bad, "cross", make_pattern("cross", 4)))
    policy.offer(msg(3, "cross", make_pattern("cross", 4)))  # a republish changes nothing
    pts, _ = policy.for_team(4)
    np.testing.assert_allclose(pts, make_pattern("circle", 4))
    policy.offer(msg(3 + MAX_VERSION_STEP, "line", make_pattern("line", 4)))
    np.testing.assert_allclose(policy.for_team(4)[0], make_pattern("line", 4))
    policy.world_restarted()  # versions count from 1 again
    policy.offer(msg(1, "cross", make_pattern("cross", 4)))
    np.testing.assert_allclose(policy.for_team(4)[0], make_pattern("cross", 4))
    with pytest.raises(PatternError, match="older"):
        policy.offer(msg(0, "circle", make_pattern("circle", 4)))


def test_a_message_the_team_cannot_form_is_refused_and_the_old_one_kept() -> None:
    policy = TeamPattern(None)
    policy.offer(msg(1, "circle", make_pattern("circle", 6)))
    assert policy.for_team(6)[0] is not None
    two = np.array([[0.0, 0.0], [0.25, 0.0]])  # fine for 2 robots, too short for 6
    with pytest.raises(PatternError, match="closer than 2R"):
        policy.offer(msg(2, "two", two))
    with pytest.raises(PatternError, match="closer than 2R"):
        policy.offer(msg(2, "two", np.array([[0.0, 0.0], [0.1, 0.0]])))
    np.testing.assert_allclose(policy.for_team(6)[0], make_pattern("circle", 6))


def test_no_operator_pattern_locks_out_the_worlds_next_phase() -> None:
    """An operator pattern at the edge of the allowance, then any number of others in any
    order: every next world pattern is still taken."""
    policy = TeamPattern(None)
    circle, cross, line = (make_pattern(p, 4) for p in ("circle", "cross", "line"))
    v = 7
    policy.offer(msg(v, "circle", circle))  # the world's phase
    policy.offer(msg(v + MAX_VERSION_STEP, "cross", cross), operator=True)  # taken
    np.testing.assert_allclose(policy.for_team(4)[0], cross)
    with pytest.raises(PatternError, match="past the world's"):  # no further than S past W
        policy.offer(msg(v + MAX_VERSION_STEP + 1, "line", line), operator=True)
    policy.offer(msg(v + 1, "line", line))  # the world's next phase, below the operator's
    np.testing.assert_allclose(policy.for_team(4)[0], line)
    with pytest.raises(PatternError, match="not newer"):  # a late operator pattern: older
        policy.offer(msg(v + 1, "cross", cross), operator=True)
    # an operator walking the versions up as far as it may, many times: the world's
    # next (at most S past its last) is still taken each time
    rng = np.random.default_rng(0)
    world_v = v + 1
    for _ in range(50):
        for op_v in rng.integers(world_v - 5, world_v + MAX_VERSION_STEP + 5, 8).tolist():
            try:
                policy.offer(msg(int(op_v), "cross", cross), operator=True)
            except PatternError:
                pass
        world_v += int(rng.integers(1, MAX_VERSION_STEP + 1))
        policy.offer(msg(world_v, "circle", circle))
        np.testing.assert_allclose(policy.for_team(4)[0], circle)


def test_operator_patterns_do_not_move_the_worlds_version() -> None:
    policy = TeamPattern(None)
    policy.offer(msg(1, "circle", make_pattern("circle", 4)), operator=True)  # before the world
    policy.offer(msg(1, "cross", make_pattern("cross", 4)))  # the world's 1 is not a republish
    np.testing.assert_allclose(policy.for_team(4)[0], make_pattern("cross", 4))


def test_a_pattern_inside_the_safety_guard_is_taken_with_a_warning() -> None:
    said: list[tuple[str, str, str]] = []
    policy = TeamPattern("circle", log=lambda level, what, text: said.append((level, what, text)))
    policy.guard_m = 0.45  # the harsh preset's guard, wider than the built-ins' 0.40 m
    pts, why = policy.for_team(6)
    assert pts is not None and why == ""
    warned = [t for level, _, t in said if level == "warning"]
    assert len(warned) == 1 and "closest pair is 0.40 m apart, inside the 0.45 m" in warned[0]
    policy.for_team(6)  # the cached target: said once
    assert len([s for s in said if s[0] == "warning"]) == 1
    said.clear()
    policy.guard_m = 0.37  # the realistic preset's: the pattern lies outside it
    policy.offer(msg(2, "line", make_pattern("line", 6)))
    assert policy.for_team(6)[0] is not None
    assert [s for s in said if s[0] == "warning"] == []
