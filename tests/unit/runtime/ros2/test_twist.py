"""The decision's velocity as a base's Twist (no ROS 2 needed)."""

from __future__ import annotations

import math

import pytest

from runtime.decision.kinematics import diff_drive
from runtime.ros2.options import Ros2Options
from runtime.ros2.twist import Planar, body_twist, planar_from_odom, yaw_of


def test_holonomic_is_the_command_in_the_body_frame() -> None:
    tw = body_twist(1.0, 0.0, math.pi / 2, "holonomic", max_turn_rps=1.0, dt_s=0.1)
    assert tw.linear_x == pytest.approx(0.0, abs=1e-12) and tw.linear_y == pytest.approx(-1.0)
    assert tw.angular_z == 0.0
    assert planar_from_odom(tw.linear_x, tw.linear_y, math.pi / 2) == pytest.approx((1.0, 0.0))


def test_diff_is_the_kinematics_law() -> None:
    tw = body_twist(0.0, 0.5, 0.0, "diff", max_turn_rps=1.8, dt_s=0.1)
    fwd, rate = diff_drive(0.0, 0.5, 0.0, 1.8, 0.1)
    assert tw == Planar(float(fwd), 0.0, float(rate))
    assert tw.angular_z == pytest.approx(1.8)  # a right angle away: turn at the limit
    assert abs(tw.linear_x) < 0.5 * math.sin(0.18) + 1e-9  # and drive by the projection


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_gives_a_zero_twist(bad: float) -> None:
    for base in ("diff", "holonomic"):
        assert body_twist(bad, 0.0, 0.0, base, max_turn_rps=1.0, dt_s=0.1) == (0.0, 0.0, 0.0)
        assert body_twist(0.3, 0.0, bad, base, max_turn_rps=1.0, dt_s=0.1) == (0.0, 0.0, 0.0)


def test_yaw_of_a_quaternion() -> None:
    for yaw in (-3.0, -1.0, 0.0, 0.5, 3.0):
        assert yaw_of(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)) == pytest.approx(yaw)


def test_topics_from_the_namespace() -> None:
    o = Ros2Options("robot_3")
    assert (o.pose_source, o.cmd_topic) == ("/robot_3/odom", "/robot_3/cmd_vel")
    assert Ros2Options("/tb3_0/", pose_topic="/mocap/tb3_0/pose").pose_source == (
        "/mocap/tb3_0/pose")
    assert Ros2Options("tb", pose_topic="mocap_pose").pose_source == "/tb/mocap_pose"
