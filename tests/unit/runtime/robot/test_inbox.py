"""The robot's pose inbox: lockstep and realtime readiness, stale peers, malformed poses."""

from __future__ import annotations

import time

import numpy as np

from runtime.log import Log
from runtime.robot.inbox import PoseInbox, Step
from runtime.wire import keys
from runtime.wire.messages import Pose, encode_pose

SWARM = "s"


def make_inbox(realtime: bool = False, stale_s: float = 0.5) -> tuple[PoseInbox, list[str]]:
    dropped: list[str] = []
    inbox = PoseInbox(
        0,
        SWARM,
        realtime=realtime,
        rate_hz=10.0,
        lockstep_deadline_s=0.02,
        stale_s=stale_s,
        log=Log("test", False, "error"),
        drop=lambda what, why: dropped.append(f"{what}: {why}"),
    )
    return inbox, dropped


def put(inbox: PoseInbox, rid: int, step: int, x: float, n_live: int = 3) -> None:
    pose = Pose(rid, step, 0.0, x, 2.0 * x, 0.0, 0.0, n_live)
    inbox.take(keys.pose_key(SWARM, rid), encode_pose(pose))


def ready(inbox: PoseInbox, after_s: float = 0.0, holding: bool = False) -> Step | None:
    """The step ready ``after_s`` from now; never sleeps (busy)."""
    now = time.monotonic() + after_s
    return inbox.next_step(now, now, holding, busy=lambda: True)


def test_lockstep_step_is_ready_once_complete_and_only_once() -> None:
    inbox, dropped = make_inbox()
    put(inbox, 0, 1, 0.0)
    put(inbox, 2, 1, 2.0)
    assert ready(inbox) is None  # robot 1 missing, deadline not passed
    put(inbox, 1, 1, 1.0)
    step = ready(inbox)
    assert step is not None and step.step == 1 and step.ids == [0, 1, 2]
    np.testing.assert_array_equal(step.positions, [[0.0, 0.0], [1.0, 2.0], [2.0, 4.0]])
    assert ready(inbox) is None  # decided already
    assert dropped == []


def test_lockstep_deadline_decides_with_fresh_peers_or_skips_without_own_pose() -> None:
    inbox, _ = make_inbox(stale_s=2.0)
    for rid in range(3):
        put(inbox, rid, 1, float(rid))
    assert ready(inbox) is not None
    put(inbox, 0, 2, 0.5)
    put(inbox, 1, 2, 1.5)
    assert ready(inbox) is None  # robot 2 missing before the deadline
    late = ready(inbox, after_s=0.1)  # past the deadline: robot 2's step-1 pose is fresh
    assert late is not None and late.step == 2 and late.ids == [0, 1, 2]
    np.testing.assert_array_equal(late.positions[:, 0], [0.5, 1.5, 2.0])
    put(inbox, 1, 3, 1.5)
    assert ready(inbox, after_s=10.0) is None  # our own pose is stale: step 3 is skipped
    put(inbox, 0, 3, 0.0)
    assert ready(inbox, after_s=10.0) is None  # ... and stays skipped


def test_world_restart_counts_steps_again() -> None:
    inbox, _ = make_inbox()
    for rid in range(3):
        put(inbox, rid, 50, float(rid))
    assert ready(inbox) is not None
    for rid in range(3):
        put(inbox, rid, 0, float(rid))
    step = ready(inbox)
    assert step is not None and step.step == 0


def test_malformed_poses_are_dropped() -> None:
    inbox, dropped = make_inbox()
    good = encode_pose(Pose(0, 1, 0.0, 1.0, 1.0, 0.0, 0.0, 1))
    inbox.take(keys.pose_key(SWARM, 1), good)  # another robot's key
    inbox.take(keys.status_key(SWARM, 0), good)  # not a pose key
    inbox.take(keys.pose_key(SWARM, 0), good[:-1])
    inbox.take(keys.pose_key(SWARM, 0), encode_pose(Pose(0, 1, 0.0, 1.0, 1.0, 0.0, 0.0, 0)))
    inbox.take(keys.pose_key(SWARM, 0), encode_pose(Pose(0, 1, 0.0, 1e300, 1.0, 0.0, 0.0, 1)))
    assert len(dropped) == 5 and all(d.startswith("pose: ") for d in dropped)
    assert inbox.silence_s(time.monotonic()) is None  # nothing was stored


def test_holding_makes_no_step_ready() -> None:
    inbox, _ = make_inbox()
    put(inbox, 0, 1, 0.0, n_live=1)
    assert ready(inbox, holding=True) is None
    silent = inbox.silence_s(time.monotonic() + 2.0)
    assert silent is not None and silent >= 2.0
    assert ready(inbox) is not None  # the step is still there once the robot acts again


def test_realtime_ticks_with_the_latest_fresh_poses() -> None:
    inbox, _ = make_inbox(realtime=True, stale_s=2.0)
    assert ready(inbox) is None  # no own pose yet (the tick passes)
    put(inbox, 0, 7, 0.0)
    put(inbox, 1, 6, 1.0)  # realtime takes whatever step each pose is of
    step = ready(inbox, after_s=0.2)
    assert step is not None and step.step == 7 and step.ids == [0, 1]
    assert ready(inbox, after_s=0.2) is None  # the next tick is a period later
    step = ready(inbox, after_s=0.35)
    assert step is not None and step.step == 7  # the same poses, decided again
    assert ready(inbox, after_s=5.0) is None  # every pose stale, our own included
