"""What a step looks like in ROS 2, in plain numbers: the one source of the topics' names, the
frame, the robots' and targets' markers, for the live fleet (rclpy) and rosbag2 (rosbags) alike.

=========================  ==================================  ==============================
topic                      type                                what
=========================  ==================================  ==============================
``/robot_<i>/odom``        ``nav_msgs/msg/Odometry``           live: robot i (``sim --ros2``)
``/robot_<i>/cmd_vel``     ``geometry_msgs/msg/Twist``         robot i's command
``/robot_<i>/pose``        ``geometry_msgs/msg/PoseStamped``   rosbag2: robot i's pose
``/swarm/poses``           ``geometry_msgs/msg/PoseArray``     every robot of a step (id order)
``/swarm/markers``         ``visualization_msgs/msg/MarkerArray``  robots and targets, for RViz
=========================  ==================================  ==============================

Everything is in the frame ``world`` (the swarm's plane, z = 0). The targets are the pattern
in force centred on the team's centroid (a formation counts up to translation).
"""

from __future__ import annotations

from typing import Final, NamedTuple

import numpy as np

from runtime.types import Array

__all__ = [
    "FRAME",
    "MARKERS_TOPIC",
    "POSES_TOPIC",
    "MarkerSpec",
    "cmd_topic",
    "markers_of",
    "odom_topic",
    "pose_topic",
    "robot_ns",
]

FRAME: Final = "world"
POSES_TOPIC: Final = "/swarm/poses"
MARKERS_TOPIC: Final = "/swarm/markers"
ROBOT_RGBA: Final = (0.2, 0.5, 0.9, 1.0)
TARGET_RGBA: Final = (0.9, 0.3, 0.2, 0.6)


def robot_ns(rid: int) -> str:
    """Robot ``rid``'s ROS 2 namespace (``robot_<rid>``, as a simulator's fleet names them)."""
    return f"robot_{int(rid)}"


def odom_topic(rid: int) -> str:
    return f"/{robot_ns(rid)}/odom"


def cmd_topic(rid: int) -> str:
    return f"/{robot_ns(rid)}/cmd_vel"


def pose_topic(rid: int) -> str:
    return f"/{robot_ns(rid)}/pose"


class MarkerSpec(NamedTuple):
    """One ``SPHERE_LIST`` marker: namespace, id, sphere diameter (m), colour, points (k, 2)."""

    ns: str
    id: int
    diameter_m: float
    rgba: tuple[float, float, float, float]
    points: Array


def markers_of(xy: Array, pattern: Array | None, radius_m: float) -> list[MarkerSpec]:
    """The robots at ``xy`` (k, 2) and, with a ``pattern`` (m, 2), its points centred on
    the robots' centroid."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = [MarkerSpec("robots", 0, 2.0 * radius_m, ROBOT_RGBA, xy)]
    if pattern is not None and len(xy):
        pts = np.asarray(pattern, dtype=np.float64).reshape(-1, 2)
        targets = pts - pts.mean(axis=0) + xy.mean(axis=0)
        out.append(MarkerSpec("targets", 1, radius_m, TARGET_RGBA, targets))
    return out
