"""A robot's status figures: counts, latency percentiles, jitter, swap answers."""

from __future__ import annotations

from runtime.brain.brain import RULE_ASSIGN
from runtime.robot.status import RobotStats, percentile
from runtime.robot.swap_worker import SwapReply


def test_percentile_is_nearest_rank() -> None:
    vals = [float(v) for v in range(1, 101)]
    assert percentile(vals, 0.5) == 50.0
    assert percentile(vals, 0.99) == 99.0
    assert percentile(vals, 1.0) == 100.0
    assert percentile([], 0.5) == 0.0
    assert percentile([7.0], 0.99) == 7.0


def test_counts_and_timings_of_one_period() -> None:
    stats = RobotStats()
    for step, lat in enumerate([10.0, 20.0, 30.0, 40.0]):
        stats.decided(step, lat, safety_changed=step % 2 == 0)
    stats.drop()
    stats.error("first\nproblem")
    stats.error("not counted", count=False)
    st = stats.status(3, RULE_ASSIGN)
    assert (st.robot_id, st.step, st.brain_id) == (3, 3, RULE_ASSIGN)
    assert st.decision_latency_us_p50 == 20.0 and st.decision_latency_us_p99 == 40.0
    assert st.loop_jitter_ms >= 0.0
    assert (st.messages_dropped, st.errors, st.safety_interventions) == (1, 1, 2)
    assert st.last_error == "not counted" and stats.steps == 4
    assert st.swap_request_id == "" and not st.swap_accepted
    stats.new_period()
    st = stats.status(3, RULE_ASSIGN)
    assert st.decision_latency_us_p50 == 0.0 and st.loop_jitter_ms == 0.0
    assert st.errors == 1 and stats.steps == 4  # counts run since start


def test_a_status_answering_a_swap() -> None:
    stats = RobotStats()
    st = stats.status(0, "a" * 64, SwapReply("req\n1", False, "bad brain", "a" * 64, "a" * 80))
    assert st.swap_request_id == "req 1" and not st.swap_accepted
    assert st.swap_reason == "bad brain"
    assert st.old_brain_id == "a" * 64 and st.brain_id == "a" * 64
