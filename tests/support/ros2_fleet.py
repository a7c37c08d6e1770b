"""ROS 2 as a user's own nodes would be: plain rclpy, no Pattern-RL code on the ROS side.

:func:`ros2_isolated` gives this test run its own ROS 2 domain (from the pid) and
localhost-only discovery, for the test process and every child, so runs never hear each
other. :class:`DiffDriveFleet` is one node that plays a fleet of differential-drive bases
as a simulator's diff-drive plugin does: each subscribes ``<ns>/cmd_vel`` (Twist), integrates
it at ``rate_hz`` and publishes ``<ns>/odom`` (Odometry), and records every Twist it got.
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from runtime.ros2.environment import import_rclpy
from support.net import wait_notified


def ros2_isolated() -> int:
    """Set this run's ROS 2 domain and localhost-only discovery (inherited by children);
    returns the domain id. The ros2 extra is part of what the test command installs: without
    it the test fails with the one line that says so."""
    import_rclpy()
    dom = 1 + os.getpid() % 100  # 1..100: each run its own domain, within DDS's port range
    os.environ["ROS_DOMAIN_ID"] = str(dom)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    return dom


@dataclass
class Base:
    """One simulated differential-drive base."""

    ns: str
    x: float
    y: float
    yaw: float
    v: float = 0.0
    w: float = 0.0
    twists: list[tuple[float, float, float, float]] = field(default_factory=list)
    """Every Twist received: (monotonic s, linear.x, linear.y, angular.z)."""
    publishing: bool = True
    nan_next: bool = False
    pub: Any = None


class DiffDriveFleet:
    """A rclpy node simulating diff-drive bases from their ``cmd_vel``; closes with ``close``."""

    def __init__(
        self,
        bases: dict[str, tuple[float, float, float]],
        rate_hz: float = 50.0,
        no_odom: frozenset[str] = frozenset(),
    ) -> None:
        """``no_odom``: bases with no ``odom`` publisher at all (a missing topic)."""
        import rclpy
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        self._Odometry = Odometry
        self.ctx = Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("test_diff_drive_fleet", context=self.ctx)
        self.lock = threading.Condition()
        self.bases: dict[str, Base] = {}
        self.dt = 1.0 / rate_hz
        for ns, (x, y, yaw) in bases.items():
            b = Base(ns, x, y, yaw)
            b.publishing = ns not in no_odom
            if b.publishing:
                b.pub = self.node.create_publisher(Odometry, f"/{ns}/odom", 10)
            self.node.create_subscription(
                Twist, f"/{ns}/cmd_vel", lambda m, b=b: self._on_twist(b, m), 10
            )
            self.bases[ns] = b
        self.node.create_timer(self.dt, self._tick)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._run = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while self._run and self.ctx.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def _on_twist(self, b: Base, m: Any) -> None:
        with self.lock:
            b.v, b.w = m.linear.x, m.angular.z
            b.twists.append((time.monotonic(), m.linear.x, m.linear.y, m.angular.z))
            self.lock.notify_all()

    def _tick(self) -> None:
        with self.lock:
            for b in self.bases.values():
                b.yaw += b.w * self.dt
                b.x += b.v * math.cos(b.yaw) * self.dt
                b.y += b.v * math.sin(b.yaw) * self.dt
                if b.publishing:
                    b.pub.publish(self.odom(b, nan=b.nan_next))
                    b.nan_next = False
            self.lock.notify_all()

    def odom(self, b: Base, nan: bool = False) -> Any:
        m = self._Odometry()
        m.header.frame_id = "odom"
        m.child_frame_id = f"{b.ns}/base_link"
        m.header.stamp = self.node.get_clock().now().to_msg()
        m.pose.pose.position.x = math.nan if nan else b.x
        m.pose.pose.position.y = b.y
        m.pose.pose.orientation.z = math.sin(b.yaw / 2)
        m.pose.pose.orientation.w = math.cos(b.yaw / 2)
        m.twist.twist.linear.x = b.v
        m.twist.twist.angular.z = b.w
        return m

    def wait(self, pred: Any, timeout: float, what: str) -> Any:
        return wait_notified(self.lock, pred, timeout, what)

    def close(self) -> None:
        self._run = False
        self.thread.join(timeout=2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.ctx)
