"""``patternrl launch --ros2``: the world as a ROS 2 fleet, each robot driving its base over
ROS 2, watched by a plain rclpy node as any ROS 2 tool would (its own domain, localhost)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

from support import ROOT
from support.ros2_fleet import ros2_isolated

from sim_bridge.log.reader import read_log


class Watcher:
    """A plain rclpy node counting what it hears on robot 0's topics and the team's."""

    def __init__(self) -> None:
        import rclpy
        from geometry_msgs.msg import PoseArray, Twist
        from nav_msgs.msg import Odometry
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data
        from rclpy.signals import SignalHandlerOptions
        from visualization_msgs.msg import MarkerArray

        self.rclpy, self.ctx = rclpy, Context()
        rclpy.init(context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("test_watcher", context=self.ctx)
        self.seen: dict[str, list[Any]] = {}
        for topic, typ in (("/robot_0/odom", Odometry), ("/robot_0/cmd_vel", Twist),
                           ("/swarm/poses", PoseArray), ("/swarm/markers", MarkerArray)):
            self.node.create_subscription(typ, topic, lambda m, t=topic: self._on(t, m),
                                          qos_profile_sensor_data)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.run = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on(self, topic: str, msg: Any) -> None:
        self.seen.setdefault(topic, []).append(msg)

    def _spin(self) -> None:
        while self.run and self.ctx.ok():
            self.ex.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.run = False
        self.thread.join(timeout=2.0)
        self.ex.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)


def test_launch_ros2_forms_without_collisions_and_speaks_ros2(tmp_path: Path) -> None:
    ros2_isolated()
    watcher = Watcher()
    log = tmp_path / "run.mcap"
    try:
        r = subprocess.run(
            [sys.executable, "-m", "patternrl.cli", "launch", "--ros2", "--robots", "4",
             "--patterns", "line", "--seed", "3", "--no-plot", "--record", str(log), "--json"],
            cwd=ROOT, capture_output=True, text=True, timeout=150)
    finally:
        watcher.close()
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads(r.stdout.strip().splitlines()[-1])
    (phase,) = res["phases"]
    assert phase["formed"] and phase["collisions"] == 0
    odom, cmds = watcher.seen.get("/robot_0/odom", []), watcher.seen.get("/robot_0/cmd_vel", [])
    assert len(odom) >= phase["steps"] // 2 and odom[-1].header.frame_id == "world"
    assert any(abs(t.linear.x) > 0.05 for t in cmds)  # robot 0 drove its base
    assert all(t.linear.y == 0.0 for t in cmds)  # a diff-drive base
    assert len(watcher.seen["/swarm/poses"][-1].poses) == 4
    assert [m.ns for m in watcher.seen["/swarm/markers"][-1].markers] == ["robots", "targets"]
    # the log holds the world's truth and the Twists it applied, as any run's
    data = read_log(log)
    assert list(data.frames.ids) == [0, 1, 2, 3] and len(data.commands.step) > 0
    assert not data.skipped, data.skipped
