"""From the decision's holonomic velocity to a base's ``geometry_msgs/Twist``, and back.

No ROS 2 here (plain numbers), so it is tested and used without rclpy:

* ``diff`` (differential drive: a TurtleBot, most wheeled bases): ``linear.x`` and
  ``angular.z`` from :func:`runtime.decision.kinematics.diff_drive` -- turn toward the command
  at most ``max_turn_rps``, drive by its projection on the new heading;
* ``holonomic`` (omni or mecanum wheels, a drone in a plane): ``linear.x``/``linear.y``, the
  command in the robot's body frame (rotated by minus its yaw), ``angular.z`` 0.

A non-finite command gives a zero twist.
"""

from __future__ import annotations

import math
from typing import Final, NamedTuple

from runtime.decision.kinematics import diff_drive

__all__ = ["BASES", "Planar", "body_twist", "planar_from_odom", "yaw_of"]

BASES: Final = ("diff", "holonomic")


class Planar(NamedTuple):
    """A twist in the plane: ``linear.x``, ``linear.y`` (m/s, body frame), ``angular.z``."""

    linear_x: float
    linear_y: float
    angular_z: float


ZERO: Final = Planar(0.0, 0.0, 0.0)


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    """The yaw (rad, about z) of a quaternion."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def body_twist(
    vx: float,
    vy: float,
    yaw: float,
    base: str,
    *,
    max_turn_rps: float,
    dt_s: float,
) -> Planar:
    """The twist a ``base`` at heading ``yaw`` (rad, swarm frame) runs for the command
    (``vx``, ``vy``) m/s in the swarm frame, decided for a period of ``dt_s``."""
    if not all(math.isfinite(v) for v in (vx, vy, yaw)):
        return ZERO
    if base == "holonomic":
        c, s = math.cos(yaw), math.sin(yaw)
        return Planar(c * vx + s * vy, -s * vx + c * vy, 0.0)
    if base != "diff":
        raise ValueError(f"unknown base {base!r}: one of {', '.join(BASES)}")
    forward, rate = diff_drive(vx, vy, yaw, max_turn_rps, dt_s)
    return Planar(float(forward), 0.0, float(rate))


def planar_from_odom(
    linear_x: float, linear_y: float, yaw: float
) -> tuple[float, float]:
    """An odometry twist (body frame, ``child_frame_id``) as a velocity in the pose's frame."""
    c, s = math.cos(yaw), math.sin(yaw)
    return c * linear_x - s * linear_y, s * linear_x + c * linear_y
