"""The plan's frame under slot agreement: the leader's mean frame, what the others hear of it
and when they take it, and a noisy team that goes by one frame reaching its pattern sooner."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.brain.brain import load_brain
from runtime.conditions import parse_conditions
from runtime.decision.agreement import (
    FRAME_MIN_STEPS,
    LEAD_SLACK_STEPS,
    Heard,
    Hearing,
    SlotAgreement,
)
from runtime.decision.local import LocalDecisions
from runtime.decision.patterns import make_pattern
from runtime.world_config import DEFAULT_WORLD
from trainer.evaluate import evaluate_brain


def with_frame(frame: tuple[float, float] | None) -> Heard:
    return Heard(np.full(3, -1), np.full(3, -1), None,
                 None if frame is None else np.array(frame))


def test_the_leader_tells_the_mean_of_its_frames_and_forgets_it_on_reset() -> None:
    a = SlotAgreement()
    long = float(FRAME_MIN_STEPS)
    assert a.told_frame is None and not a.lead_due()
    assert_frame(a.lead_frame(np.array([1.0, 2.0]), long), [1.0, 2.0])
    assert_frame(a.lead_frame(np.array([3.0, 0.0]), 1.0), [2.0, 1.0])  # the first step's plan
    got = a.lead_frame(np.array([2.0, 4.0]), 1.0)
    assert_frame(got, [2.0, 2.0])
    assert got is not None and a.told_frame is not None
    got[0] = 9.0  # a copy: what it tells is its own
    assert a.told_frame.tolist() == [2.0, 2.0]
    for _ in range(2 * FRAME_MIN_STEPS + LEAD_SLACK_STEPS - 3):
        a.lead_frame(np.array([2.0, 2.0]), 1.0)
    assert not a.lead_due()  # twice the first plan and the slack: not yet
    a.lead_frame(np.array([2.0, 2.0]), 1.0)
    assert a.lead_due()
    a.reset()  # a new pattern or team: a new mean
    assert a.told_frame is None
    assert_frame(a.lead_frame(np.array([5.0, 5.0]), long), [5.0, 5.0])


def test_a_leader_whose_plan_starts_short_tells_no_frame() -> None:
    a = SlotAgreement()
    assert not a.frame_declined  # nothing decided before the first step
    assert a.lead_frame(np.array([1.0, 2.0]), FRAME_MIN_STEPS - 1.0) is None
    assert a.frame_declined
    assert a.lead_frame(np.array([1.0, 2.0]), 40.0) is None  # the first step's plan counts
    assert a.told_frame is None and not a.lead_due()
    a.reset()
    assert not a.frame_declined


def assert_frame(got: np.ndarray | None, want: list[float]) -> None:
    assert got is not None and got.tolist() == want


def test_a_robot_takes_the_leaders_frame_heard_within_reach_only() -> None:
    a = SlotAgreement()
    own = np.array([10.0, 10.0])
    assert a.follow_frame(None, own, 3.0) is None and not a.heard_frame
    assert a.follow_frame(with_frame(None), own, 3.0) is None and not a.heard_frame
    got = a.follow_frame(with_frame((11.0, 12.0)), own, 3.0)
    assert got is not None and got.tolist() == [11.0, 12.0] and a.heard_frame
    # a frame no plan of the team could have (a leader gone wrong): its own
    assert a.follow_frame(with_frame((14.0, 10.0)), own, 3.0) is None and not a.heard_frame
    assert a.follow_frame(with_frame((np.nan, 10.0)), own, 3.0) is None


def test_the_leaders_frame_is_heard_late_kept_when_lost_and_forgotten_on_restart() -> None:
    h = Hearing(parse_conditions("perfect,latency_steps=2"), 2, 3, seed=4)
    slots = np.array([[0, 1, 2], [2, 1, 0]])
    frames = np.array([[1.0, 2.0], [np.nan, np.nan]])  # team 1's leader has none
    h.hear(0)
    h.tell(0, slots, slots, frames)
    h.hear(1)
    assert h.heard(1).frame is None  # two steps late
    h.tell(1, slots, slots)  # nothing told of frames: the last heard stays
    h.hear(2)
    for b in range(3):
        got = h.heard(b).frame
        assert got is not None and got.tolist() == [1.0, 2.0]
    assert all(h.heard(b).frame is None for b in range(3, 6))
    h.hear(3)
    assert h.heard(2).frame is not None and h.heard(2).frame.tolist() == [1.0, 2.0]
    h.restart(np.array([0]))
    assert h.heard(2).frame is None
    alone = Hearing(parse_conditions("perfect"), 1, 3, seed=4)  # the frame alone: no slots
    none = np.full((1, 3), -1)
    alone.tell(0, none, none, np.array([[5.0, 6.0]]))
    alone.hear(1)
    got = alone.heard(2)
    assert got.frame is not None and got.frame.tolist() == [5.0, 6.0]
    assert got.leader is None and (got.claims == -1).all()


def plan_frames(agree: bool, steps: int = 6) -> list[np.ndarray]:
    """Each step, every robot's plan frame (the centroid of the targets it planned for its
    team), (E, n, 2), for 3 teams of 10 from random starts to the heart, 5 cm of noise, no
    loss, 1 step late."""
    E, n = 3, 10
    w = DEFAULT_WORLD
    rng = np.random.default_rng(2)
    pos = rng.uniform(1.0, w.arena_m - 1.0, (E, n, 2))
    pattern = np.repeat(make_pattern("heart", n)[None], E, axis=0)
    local = LocalDecisions(load_brain("rule:frame-balanced"), E, n,
                           parse_conditions("perfect,noise_m=0.05,latency_steps=1"),
                           estimator=True, seed=3, agree=agree)
    out = []
    for _ in range(steps):
        v, _, _ = local.decide(pos, pattern)
        frames = np.full((E, n, 2), np.nan)
        for b, c in enumerate(local.controllers):
            t = c._landing_targets  # the targets of its plan for the team
            if t is not None:
                frames[b // n, b % n] = t.mean(axis=0)
        out.append(frames)
        pos = pos + v * w.dt_s
    return out


def test_a_team_that_agrees_goes_by_its_leaders_frame_of_the_step_before() -> None:
    agreed, own = plan_frames(True), plan_frames(False)
    assert all(np.isfinite(f).all() for f in agreed + own)
    for s in range(1, len(agreed)):
        lead_before = agreed[s - 1][:, 0]
        for i in range(1, 10):  # every other robot: the leader's frame, exactly
            assert np.array_equal(agreed[s][:, i], lead_before)
    spread = np.hypot(*(own[-1] - own[-1].mean(axis=1, keepdims=True)).transpose(2, 0, 1))
    assert spread.max() > 1e-3  # each on its own view: a frame of its own


def test_a_noisy_team_that_agrees_on_its_frame_forms_sooner() -> None:
    brain = load_brain("rule:frame-balanced")
    c = parse_conditions("realistic")

    def run(agree: str) -> float:
        r = evaluate_brain(brain, "random", 25, 8, seed=41, conditions=c, estimator=True,
                           progress=False, agree=agree)
        assert r.success_rate == 1.0 and r.collisions == 0 and r.agree == agree
        return r.steps_ratio

    assert run("frame") < run("off") - 0.02


def test_a_team_that_never_hears_its_leader_still_forms_around_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The leader plans in its own frame, told; robots that never hear it plan in the team's
    centroid frame. Once its team would have formed had it followed (twice the plan's steps
    and 10 more), the leader lands where the team's core stands, so the team still forms,
    later, where a leader left in a frame of its own would never form with it."""
    made = LocalDecisions.__init__

    def deaf(self: LocalDecisions, *a: object, **k: object) -> None:
        made(self, *a, **k)  # type: ignore[arg-type]
        assert self.hearing is not None and not self.tells_slots
        self.hearing.loss = 1.0  # every message lost; the sensing as it was

    monkeypatch.setattr(LocalDecisions, "__init__", deaf)
    r = evaluate_brain(load_brain("rule:frame-balanced"), "heart", 10, 20, seed=77,
                       conditions=parse_conditions("realistic"), estimator=True,
                       progress=False, agree="frame")
    assert r.agree == "frame" and r.formed_rate == 1.0 and r.collisions == 0
    assert r.success_rate >= 0.8 and r.steps_ratio < 3.0  # left in its own: 20 %, 4.5x
