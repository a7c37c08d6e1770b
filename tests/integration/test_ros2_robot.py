"""``patternrl robot --ros2``: a robot process drives a ROS 2 base, as a user would run it.

The ROS 2 side is plain rclpy (:class:`support.ros2_fleet.DiffDriveFleet`: a node that turns
each base's ``cmd_vel`` into its ``odom``); the swarm side is real Zenoh on loopback
(:class:`support.stub_world.StubWorld`'s session, and a peer whose pose the test publishes on
its Zenoh pose key, as another ROS 2 robot of the swarm would). Each run has its own ROS 2
domain and localhost-only discovery.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from support.ros2_fleet import DiffDriveFleet, ros2_isolated
from support.stub_world import RobotProc, StubWorld

from runtime.decision.formation import formation_error
from runtime.decision.patterns import make_pattern
from runtime.wire import keys
from runtime.wire.messages import Pose, decode_pose, encode_pose
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD
FAST_STATUS = ("--status-period-s", "0.2")


class StaticPeer:
    """Another robot of the swarm standing still: its pose on its Zenoh pose key at 20 Hz."""

    def __init__(self, world: StubWorld, rid: int, x: float, y: float) -> None:
        self.pub = world.session.declare_publisher(keys.pose_key(world.swarm, rid))
        self.rid, self.x, self.y = rid, x, y
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.05):
            t = time.time()
            pose = Pose(self.rid, int((t % 86400) / W.dt_s), t, self.x, self.y, 0.0, 0.0, 2)
            self.pub.put(encode_pose(pose))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=2.0)
        self.pub.undeclare()


def test_robot_drives_a_diff_drive_base_to_its_slot_and_stops_on_bad_poses(
    world: StubWorld, robots: list[RobotProc]
) -> None:
    ros2_isolated()
    seen: list[Pose] = []
    sub = world.session.declare_subscriber(
        keys.pose_key(world.swarm, 0), lambda s: seen.append(decode_pose(s.payload.to_bytes()))
    )
    peer = StaticPeer(world, 1, 0.8, 0.5)
    fleet = DiffDriveFleet({"robot_0": (0.0, 0.0, 0.0)})
    base = fleet.bases["robot_0"]
    try:
        robots.append(RobotProc(world, 0, "rule:assign", "--ros2", "robot_0", "--pattern",
                                "line", *FAST_STATUS))
        pattern = make_pattern("line", 2)

        def formed() -> bool:
            P = np.array([[base.x, base.y], [peer.x, peer.y]])
            return formation_error(P, pattern) < 2 * W.formed_tol_m

        fleet.wait(formed, 30.0, "robot_0's base at its slot")
        assert len(base.twists) > 10 and any(abs(t[3]) > 0.1 for t in base.twists)  # it turned
        assert all(abs(t[2]) == 0.0 for t in base.twists)  # a diff base: no linear.y
        # its pose went to the swarm on its own Zenoh pose key, as ROS 2 reported it
        assert seen and math.isclose(seen[-1].x, base.x, abs_tol=0.1)
        world.wait(lambda: len(world.cmds) > 0, 5.0, "the robot's Zenoh commands")

        # a NaN pose: a zero Twist at once, one line, the status says why; good poses resume
        n = len(base.twists)
        with fleet.lock:
            base.nan_next = True
            base.x += 0.3  # off its slot: the robot would drive again
        fleet.wait(lambda: any(t[1:] == (0.0, 0.0, 0.0) for t in base.twists[n:]), 5.0,
                   "a zero Twist after a NaN pose")
        world.wait_status(0, lambda s: "non-finite pose" in s.last_error, 5.0, "NaN status")
        fleet.wait(lambda: abs(base.twists[-1][1]) > 0.01, 10.0, "driving again")

        # the odometry falls silent: a zero Twist once the timeout passes, and it stays
        with fleet.lock:
            base.publishing = False
            t_silent = time.monotonic()
        fleet.wait(lambda: base.twists[-1][1:] == (0.0, 0.0, 0.0)
                   and base.twists[-1][0] > t_silent + 0.3, 5.0, "a zero Twist on silence")
        world.wait_status(0, lambda s: "no fresh pose on /robot_0/odom" in s.last_error, 5.0,
                          "silence status")
        assert robots[0].proc.poll() is None  # nothing crashed
        robots[0].interrupt()
        code, _, err = robots[0].finish(10.0)
        assert code == 0, err
        assert sum("non-finite pose on /robot_0/odom" in line for line in err.splitlines()) == 1
        assert sum("no fresh pose on /robot_0/odom" in line for line in err.splitlines()) == 1
        assert base.twists[-1][1:] == (0.0, 0.0, 0.0)  # the last word is: stop
    finally:
        fleet.close()
        peer.close()
        sub.undeclare()


def test_robot_without_a_pose_topic_holds_still_and_says_so(
    world: StubWorld, robots: list[RobotProc]
) -> None:
    ros2_isolated()
    fleet = DiffDriveFleet({"robot_7": (0.0, 0.0, 0.0)}, no_odom=frozenset({"robot_7"}))
    base = fleet.bases["robot_7"]
    try:
        robots.append(RobotProc(world, 7, "rule:assign", "--ros2", "robot_7",
                                "--ros2-base", "holonomic", *FAST_STATUS))
        fleet.wait(lambda: base.twists, 20.0, "a Twist on /robot_7/cmd_vel")
        assert base.twists[0][1:] == (0.0, 0.0, 0.0)
        world.wait_status(7, lambda s: "nobody publishes it" in s.last_error, 5.0, "status")
        assert robots[0].proc.poll() is None
        robots[0].interrupt()
        code, _, err = robots[0].finish(10.0)
        assert code == 0, err
        lines = [ln for ln in err.splitlines() if "no pose yet on /robot_7/odom" in ln]
        assert len(lines) == 1 and "nobody publishes it" in lines[0], err
    finally:
        fleet.close()


@pytest.mark.parametrize(
    ("opts", "says"),
    [
        (["--ros2", "robot 3"], "not a ROS 2 namespace"),
        (["--ros2", "robot_3", "--ros2-pose-timeout-s", "0"], "--ros2-pose-timeout-s"),
        (["--ros2-pose-topic", "/mocap/pose"], "needs --ros2"),
        (["--ros2", "robot_3", "--ros2-origin", "1,2"], "--ros2-origin"),
    ],
)
def test_bad_ros2_options_are_one_line(opts: list[str], says: str) -> None:
    import argparse

    from runtime.errors import InputError
    from runtime.robot.cli import add_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--swarm", "s", "--id", "0", "--brain", "rule:assign", *opts])
    with pytest.raises(InputError, match=says.replace("-", r"\-")):
        config_from_args(args, W)
