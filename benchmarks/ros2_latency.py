"""Pose -> command latency through ROS 2, beside the Zenoh path, for a team of robot processes.

    .venv/bin/python benchmarks/ros2_latency.py [--robots 10] [--steps 100] [--json]

Both paths run the same ``patternrl robot`` processes (``--brain``, default ``rule:assign``) on
loopback, one team after the other, ``--steps`` steps at 10 Hz:

* **zenoh**: the world's path. The benchmark publishes every robot's pose of a step in one
  all-poses message (as ``patternrl sim`` does); latency = the robot's command arriving on its
  Zenoh ``cmd`` key - the poses going out.
* **ros2**: each robot runs with ``--ros2 robot_<i>``; the benchmark is a plain rclpy node that
  publishes ``/robot_<i>/odom`` (``nav_msgs/Odometry``) for every robot each step; each robot
  shares its pose with its peers over Zenoh, decides on its own odom and sends a
  ``geometry_msgs/Twist`` on ``/robot_<i>/cmd_vel``; latency = that Twist arriving - its
  odom going out (the first Twist after each odom).

The robots stand on a circle (their commands are not applied: the latency is the measure).
The first ``--warmup-steps`` steps are left out. Prints a table (median, p99, max in ms, and
the commands counted) or ``--json``. The ROS 2 run has its own ROS 2 domain (from the pid)
and localhost-only discovery.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the test support: stub world, robot processes

from support.stub_world import RobotProc, StubWorld  # noqa: E402

from runtime.world_config import DEFAULT_WORLD  # noqa: E402

W = DEFAULT_WORLD


def circle(n: int) -> np.ndarray:
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.stack([5.0 + 2.0 * np.cos(a), 5.0 + 2.0 * np.sin(a)], axis=1)


def summary(lat_ms: list[float], expected: int) -> dict[str, Any]:
    a = np.asarray(lat_ms, dtype=np.float64)
    if not len(a):
        return {"commands": 0, "expected": expected}
    return {"commands": len(a), "expected": expected,
            "median_ms": round(float(np.median(a)), 3),
            "p99_ms": round(float(np.percentile(a, 99)), 3),
            "max_ms": round(float(a.max()), 3)}


def start_team(world: StubWorld, n: int, brain: str, *extra: str) -> list[RobotProc]:
    robots = [RobotProc(world, i, brain, "--pattern", "circle", *(
        a.replace("{i}", str(i)) for a in extra)) for i in range(n)]
    world.wait_alive(set(range(n)), timeout=60.0)
    return robots


def stop_team(robots: list[RobotProc]) -> None:
    for r in robots:
        r.interrupt()
    for r in robots:
        try:
            r.finish(timeout=10.0)
        except AssertionError:
            r.kill()


def zenoh_path(n: int, steps: int, warmup: int, brain: str) -> dict[str, Any]:
    world = StubWorld(f"bench_zenoh_{os.getpid()}")
    world.batches = True
    robots = start_team(world, n, brain)
    pos = circle(n)
    lat: list[float] = []
    try:
        tick = time.monotonic()
        for step in range(warmup + steps):
            world.publish_poses(step, pos)
            world.wait_cmds(step, list(range(n)), timeout=5.0)
            if step >= warmup:
                with world.cond:
                    t0 = world.pose_times[step]
                    lat += [(world.cmd_times[(step, r)] - t0) * 1000.0 for r in range(n)]
            tick += W.dt_s
            time.sleep(max(0.0, tick - time.monotonic()))  # 10 Hz, as the world's steps
    finally:
        stop_team(robots)
        world.close()
    return summary(lat, n * steps)


class OdomFleet:
    """A plain rclpy node: odom out for every robot, Twists in, times kept."""

    def __init__(self, n: int) -> None:
        import rclpy
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.rclpy, self.Odometry = rclpy, Odometry
        self.ctx = Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("bench_odom_fleet", context=self.ctx)
        self.lock = threading.Lock()
        self.sent: list[float | None] = [None] * n  # the odom waiting for its Twist
        self.lat: list[float] = []
        self.counting = False
        self.pubs = [self.node.create_publisher(Odometry, f"/robot_{i}/odom", 10)
                     for i in range(n)]
        for i in range(n):
            self.node.create_subscription(Twist, f"/robot_{i}/cmd_vel",
                                          lambda m, i=i: self._on_twist(i), 10)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.run = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while self.run and self.ctx.ok():
            self.ex.spin_once(timeout_sec=0.05)

    def _on_twist(self, i: int) -> None:
        now = time.monotonic()
        with self.lock:
            t = self.sent[i]
            self.sent[i] = None
            if t is not None and self.counting:
                self.lat.append((now - t) * 1000.0)

    def publish(self, pos: np.ndarray) -> None:
        for i, (x, y) in enumerate(pos.tolist()):
            m = self.Odometry()
            m.header.frame_id = "world"
            m.pose.pose.position.x, m.pose.pose.position.y = x, y
            m.pose.pose.orientation.w = 1.0
            with self.lock:
                self.sent[i] = time.monotonic()
            self.pubs[i].publish(m)

    def close(self) -> None:
        self.run = False
        self.thread.join(timeout=2.0)
        self.ex.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)


def ros2_path(n: int, steps: int, warmup: int, brain: str) -> dict[str, Any]:
    os.environ.setdefault("ROS_DOMAIN_ID", str(101 + os.getpid() % 100))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    world = StubWorld(f"bench_ros2_{os.getpid()}")  # the team's Zenoh: peers' poses
    fleet = OdomFleet(n)
    robots = start_team(world, n, brain, "--ros2", "robot_{i}")
    pos = circle(n)
    try:
        tick = time.monotonic()
        for step in range(warmup + steps):
            if step == warmup:
                with fleet.lock:
                    fleet.counting = True
            fleet.publish(pos)
            tick += W.dt_s
            time.sleep(max(0.0, tick - time.monotonic()))  # 10 Hz, as a base's odometry
    finally:
        stop_team(robots)
        fleet.close()
        world.close()
    return summary(fleet.lat, n * steps)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--warmup-steps", type=int, default=20)
    p.add_argument("--brain", default="rule:assign")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    res = {"robots": a.robots, "steps": a.steps, "brain": a.brain,
           "load_1min": round(os.getloadavg()[0], 2),
           "zenoh": zenoh_path(a.robots, a.steps, a.warmup_steps, a.brain),
           "ros2": ros2_path(a.robots, a.steps, a.warmup_steps, a.brain)}
    if a.json:
        print(json.dumps(res))
        return 0
    print(f"pose -> command, {a.robots} robots, {a.steps} steps at 10 Hz, {a.brain} "
          f"(load {res['load_1min']})")
    print(f"{'path':<6} {'commands':>9} {'median ms':>10} {'p99 ms':>8} {'max ms':>8}")
    for path in ("zenoh", "ros2"):
        s = res[path]
        print(f"{path:<6} {s['commands']:>5}/{s['expected']:<4} {s.get('median_ms', '-'):>9} "
              f"{s.get('p99_ms', '-'):>8} {s.get('max_ms', '-'):>8}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
