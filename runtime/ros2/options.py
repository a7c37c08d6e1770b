"""``patternrl robot --ros2 ...``: the options of a robot on ROS 2 and their checks (no rclpy)."""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass
from typing import Final

from runtime.errors import InputError
from runtime.ros2.twist import BASES

__all__ = ["Ros2Options", "add_ros2_arguments", "ros2_options_from_args"]

_NAME_RE: Final = re.compile(r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")
DEFAULT_MAX_TURN_RPS: Final = 1.8
"""A TurtleBot 3 Waffle's top turn rate (a Burger's is 2.84 rad/s)."""


@dataclass(frozen=True)
class Ros2Options:
    """Where a robot on ROS 2 reads its pose and sends its command."""

    namespace: str
    """The robot's ROS 2 namespace, e.g. ``robot_3`` (``/robot_3/odom``, ``/robot_3/cmd_vel``)."""
    pose_topic: str | None = None
    """A ``geometry_msgs/PoseStamped`` topic (motion capture) instead of ``<ns>/odom``."""
    base: str = "diff"
    pose_timeout_s: float = 0.5
    max_turn_rps: float = DEFAULT_MAX_TURN_RPS
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Where the pose topic's frame sits in the swarm's frame: x, y (m), yaw (rad)."""
    domain_id: int | None = None

    @property
    def odom_topic(self) -> str:
        return _join(self.namespace, "odom")

    @property
    def cmd_topic(self) -> str:
        return _join(self.namespace, "cmd_vel")

    @property
    def pose_source(self) -> str:
        """The topic the pose comes from."""
        if self.pose_topic is None:
            return self.odom_topic
        return self.pose_topic if self.pose_topic.startswith("/") else _join(
            self.namespace, self.pose_topic
        )


def _join(ns: str, name: str) -> str:
    ns = ns.strip("/")
    return f"/{ns}/{name}" if ns else f"/{name}"


def add_ros2_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--ros2*`` options (in their own group)."""
    g = parser.add_argument_group(
        "ROS 2 (a real or simulated ROS 2 robot; needs the ros2 extra)"
    )
    g.add_argument(
        "--ros2",
        metavar="NAMESPACE",
        default=None,
        help="drive the ROS 2 robot NAMESPACE: pose from NAMESPACE/odom (nav_msgs/Odometry), "
        "command on NAMESPACE/cmd_vel (geometry_msgs/Twist); the pose also goes to the swarm "
        "on this robot's Zenoh pose key. Implies --mode realtime unless given",
    )
    g.add_argument(
        "--ros2-pose-topic",
        metavar="TOPIC",
        default=None,
        help="read the pose from this geometry_msgs/PoseStamped topic instead (motion "
        "capture; relative names are under NAMESPACE)",
    )
    g.add_argument(
        "--ros2-base",
        choices=BASES,
        default="diff",
        help="diff: linear.x and angular.z (turn toward the command, drive by its "
        "projection); holonomic: linear.x/y in the body frame (default diff)",
    )
    g.add_argument(
        "--ros2-pose-timeout-s",
        type=float,
        default=0.5,
        help="no fresh pose this long: a zero Twist until one comes (default 0.5)",
    )
    g.add_argument(
        "--ros2-max-turn-rps",
        type=float,
        default=DEFAULT_MAX_TURN_RPS,
        help=f"a diff base's turn-rate limit, rad/s (default {DEFAULT_MAX_TURN_RPS})",
    )
    g.add_argument(
        "--ros2-origin",
        metavar="X,Y,YAW",
        default="0,0,0",
        help="where the pose topic's frame (the odom origin) sits in the swarm's frame "
        "(m, m, rad; default 0,0,0)",
    )
    g.add_argument(
        "--ros2-domain-id",
        type=int,
        default=None,
        help="ROS 2 domain (default: ROS_DOMAIN_ID, else 0)",
    )


def ros2_options_from_args(args: argparse.Namespace) -> Ros2Options | None:
    """The ROS 2 options, None without ``--ros2``; :class:`InputError` (one line) when bad."""
    ns = getattr(args, "ros2", None)
    if ns is None:
        if getattr(args, "ros2_pose_topic", None) is not None:
            raise InputError("--ros2-pose-topic needs --ros2 NAMESPACE")
        return None
    if ns.strip("/") and _NAME_RE.fullmatch(ns) is None:
        raise InputError(f"--ros2 {ns!r}: not a ROS 2 namespace ([A-Za-z_][A-Za-z0-9_/]*)")
    topic = args.ros2_pose_topic
    if topic is not None and _NAME_RE.fullmatch(topic) is None:
        raise InputError(f"--ros2-pose-topic {topic!r}: not a ROS 2 topic name")
    for name, v in (
        ("--ros2-pose-timeout-s", args.ros2_pose_timeout_s),
        ("--ros2-max-turn-rps", args.ros2_max_turn_rps),
    ):
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v}")
    try:
        parts = tuple(float(p) for p in str(args.ros2_origin).split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3 or not all(math.isfinite(p) for p in parts):
        raise InputError(f"--ros2-origin must be X,Y,YAW (three numbers), got {args.ros2_origin!r}")
    dom = args.ros2_domain_id
    if dom is not None and not 0 <= dom <= 232:
        raise InputError(f"--ros2-domain-id must be in 0..232, got {dom}")
    return Ros2Options(
        namespace=ns,
        pose_topic=topic,
        base=args.ros2_base,
        pose_timeout_s=args.ros2_pose_timeout_s,
        max_turn_rps=args.ros2_max_turn_rps,
        origin=(parts[0], parts[1], parts[2]),
        domain_id=dom,
    )
