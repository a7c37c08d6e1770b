"""``patternrl sim --ros2``: the simulated robots as a ROS 2 fleet of differential-drive bases.

:class:`Ros2FleetLink` takes the place of the world's Zenoh link
(:class:`sim_bridge.world.world_link.WorldLink`) for the robots' motion, as a simulator's
diff-drive plugin does for each robot ``robot_<i>``:

* it publishes ``/robot_<i>/odom`` (``nav_msgs/Odometry``, frame ``world``, the base's heading,
  its velocity in the body frame) every step, and the team as ``/swarm/poses``
  (``PoseArray``) and ``/swarm/markers`` (``MarkerArray``: robots and targets, for RViz);
* it subscribes ``/robot_<i>/cmd_vel`` (``geometry_msgs/Twist``) and moves the base by its
  newest one (the adapter :class:`DiffDriveBases`: turn by ``angular.z``, then drive by
  ``linear.x`` along the new heading, within v_max); a base with no Twist for
  ``cmd_timeout_s`` holds still (counted as a deadline miss).

The world runs in realtime (a base applies the newest Twist, as a ROS 2 base does); it
publishes no Zenoh poses: each robot (``robot --ros2 robot_<i>``) reads its odom and shares
its pose with its peers itself. The rest is the world's as ever: robots' liveliness, the
pattern key, judging formed, the log (the truth of the physics, and each applied Twist as the
robot's command of that step).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any, Final

import numpy as np
import zenoh

from runtime.ros2.environment import import_rclpy
from runtime.types import Array
from runtime.wire import keys
from runtime.wire.messages import Command, PoseBatch, encode_command, encode_poses
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from sim_bridge.log.recorder import Recorder
from sim_bridge.ros2.scene import (
    FRAME,
    MARKERS_TOPIC,
    POSES_TOPIC,
    cmd_topic,
    markers_of,
    odom_topic,
    robot_ns,
)
from sim_bridge.world.world_link import Collected, WorldLink

__all__ = ["CMD_TIMEOUT_S", "DiffDriveBases", "Ros2FleetLink"]

CMD_TIMEOUT_S: Final = 0.5
"""A base whose newest Twist is older than this holds still (a ROS 2 base's cmd timeout)."""
TWIST_BRAIN_ID: Final = "ros2:cmd_vel"
"""The brain id the log gives the Twist commands (the robots' own ids come in their statuses)."""


class DiffDriveBases:
    """The adapter from Twists to the physics' velocities: one heading per base."""

    def __init__(self, world: WorldConfig, seed: int, max_turn_rps: float = 2.84) -> None:
        self.world = world
        self.max_turn_rps = max_turn_rps
        self.rng = np.random.default_rng(seed)
        self.heading: dict[int, float] = {}
        self.twist: dict[int, tuple[float, float, float]] = {}  # rid -> (v, w, monotonic s)
        self.lock = threading.Lock()

    def add(self, rid: int) -> None:
        with self.lock:
            self.heading[rid] = float(self.rng.uniform(-math.pi, math.pi))
            self.twist.pop(rid, None)

    def remove(self, rid: int) -> None:
        with self.lock:
            self.heading.pop(rid, None)
            self.twist.pop(rid, None)

    def take(self, rid: int, linear_x: float, angular_z: float) -> bool:
        """A Twist for ``rid``; False (unused) when not finite or for no base."""
        if not (math.isfinite(linear_x) and math.isfinite(angular_z)):
            return False
        with self.lock:
            if rid not in self.heading:
                return False
            self.twist[rid] = (linear_x, angular_z, time.monotonic())
        return True

    def velocities(
        self, ids: list[int], dt_s: float, timeout_s: float
    ) -> tuple[Array, list[int], dict[int, tuple[float, float]]]:
        """Turn each base, then the velocities (n, 2) to drive it for one step, the robots
        with no fresh Twist (held still), and the Twist applied to each other one."""
        now = time.monotonic()
        v = np.zeros((len(ids), 2))
        missed: list[int] = []
        applied: dict[int, tuple[float, float]] = {}
        vmax = self.world.v_max_mps
        with self.lock:
            for k, rid in enumerate(ids):
                tw = self.twist.get(rid)
                if tw is None or now - tw[2] > timeout_s:
                    missed.append(rid)
                    continue
                fwd = min(max(tw[0], -vmax), vmax)
                rate = min(max(tw[1], -self.max_turn_rps), self.max_turn_rps)
                h = (self.heading[rid] + rate * dt_s + math.pi) % (2 * math.pi) - math.pi
                self.heading[rid] = h
                v[k] = (fwd * math.cos(h), fwd * math.sin(h))
                applied[rid] = (fwd, rate)
        return v, missed, applied


class Ros2FleetLink(WorldLink):
    """The world's link with the robots' motion over ROS 2 (see the module)."""

    def __init__(
        self,
        session: zenoh.Session,
        swarm: str,
        lockstep: bool,
        recorder: Recorder | None,
        event: Callable[..., None],
        world: WorldConfig = DEFAULT_WORLD,
        seed: int = 0,
        domain_id: int | None = None,
    ) -> None:
        super().__init__(session, swarm, lockstep, recorder, event)
        rclpy = import_rclpy()
        from geometry_msgs.msg import Pose, PoseArray, Twist
        from nav_msgs.msg import Odometry
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile
        from rclpy.signals import SignalHandlerOptions
        from visualization_msgs.msg import Marker, MarkerArray

        self.world = world
        self.bases = DiffDriveBases(world, seed)
        self._m = {"Odometry": Odometry, "Twist": Twist, "Pose": Pose, "PoseArray": PoseArray,
                   "Marker": Marker, "MarkerArray": MarkerArray}
        self._rclpy = rclpy
        self._ctx = Context()
        rclpy.init(context=self._ctx, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self._node = rclpy.create_node("patternrl_world", context=self._ctx)
        self._qos = QoSProfile(depth=10)
        self._qos_cmd = QoSProfile(depth=1)  # reliable, as a base's cmd_vel; the newest counts
        self._team_pub = self._node.create_publisher(PoseArray, POSES_TOPIC, self._qos)
        self._marker_pub = self._node.create_publisher(MarkerArray, MARKERS_TOPIC, self._qos)
        self._robots: dict[int, tuple[Any, Any]] = {}  # rid -> (odom publisher, subscription)
        self._ros_lock = threading.Lock()
        self._executor = SingleThreadedExecutor(context=self._ctx)
        self._executor.add_node(self._node)
        self._run = True
        self._thread = threading.Thread(target=self._spin, name="ros2-fleet", daemon=True)
        self._thread.start()
        self.pattern_points: Array | None = None
        """The pattern in force (for the targets' markers)."""
        self.bad_twists = 0

    def _spin(self) -> None:
        while self._run and self._ctx.ok():
            try:
                self._executor.spin_once(timeout_sec=0.05)
            except Exception as e:  # never a traceback on the executor's thread
                if self._run and self._ctx.ok():
                    self._event("malformed", key="ros2", reason=f"{type(e).__name__}: {e}"[:200])

    # ------------------------------------------------------------ robots

    def add_robot(self, rid: int, x: float, y: float) -> None:
        """A base placed at (x, y): its odom publisher and cmd_vel subscription."""
        self._prev_pos[rid] = (x, y)
        with self.cond:
            self._spoke_at[rid] = self._exchanges
        self.bases.add(rid)
        with self._ros_lock:
            pub = self._node.create_publisher(self._m["Odometry"], odom_topic(rid), self._qos)
            sub = self._node.create_subscription(
                self._m["Twist"], cmd_topic(rid), lambda m, r=rid: self._on_twist(r, m),
                self._qos_cmd)
            self._robots[rid] = (pub, sub)

    def remove_robot(self, rid: int) -> None:
        self._prev_pos.pop(rid, None)
        self.bases.remove(rid)
        with self._ros_lock:
            got = self._robots.pop(rid, None)
            if got is not None:
                self._node.destroy_publisher(got[0])
                self._node.destroy_subscription(got[1])

    def _undeclare_poses(self) -> None:
        for rid in list(self._robots):
            self.remove_robot(rid)

    def _on_twist(self, rid: int, msg: Any) -> None:
        if not self.bases.take(rid, msg.linear.x, msg.angular.z):
            self.bad_twists += 1
            self._malformed(cmd_topic(rid), "a Twist that is not finite")

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """The robots' Zenoh poses and commands are theirs (their own clock's steps): the
        log holds the world's truth and the Twists applied; the rest as ever."""
        k = keys.parse_key(str(sample.key_expr))
        if k is not None and k.robot_id is not None and k.kind in (keys.POSE, keys.CMD):
            self.roster.heard(k.robot_id)
            return
        super()._on_sample(sample)

    # ------------------------------------------------------------ each step

    def put_pattern(self, payload: bytes | None = None) -> None:
        super().put_pattern(payload)
        if payload is not None:
            from runtime.wire.messages import decode_pattern

            self.pattern_points = np.array(decode_pattern(payload).points)

    def publish_poses(self, step: int, dt_s: float, ids: list[int], pos: Array) -> None:
        """Each base's odom, the team's PoseArray and markers; the poses on the log."""
        pos = np.asarray(pos, dtype=np.float64).reshape(-1, 2)
        prev = np.array([self._prev_pos.get(rid, (x, y))
                         for rid, (x, y) in zip(ids, pos.tolist(), strict=True)]).reshape(-1, 2)
        vel = (pos - prev) / dt_s
        with self.cond:
            self._last_step = max(self._last_step, step)
        if self.rec is not None:
            self.rec.write_wire(keys.poses_key(self.swarm),
                                encode_poses(PoseBatch(step, step * dt_s, ids, pos, vel)))
        stamp = self._node.get_clock().now().to_msg()
        m = self._m
        team = m["PoseArray"]()
        team.header.frame_id, team.header.stamp = FRAME, stamp
        with self._ros_lock:
            for k, rid in enumerate(ids):
                got = self._robots.get(rid)
                h = self.bases.heading.get(rid, 0.0)
                x, y = pos[k].tolist()
                odom = m["Odometry"]()
                odom.header.frame_id, odom.header.stamp = FRAME, stamp
                odom.child_frame_id = f"{robot_ns(rid)}/base_link"
                _set_pose(odom.pose.pose, x, y, h)
                vx, vy = vel[k].tolist()
                c, s = math.cos(h), math.sin(h)
                odom.twist.twist.linear.x = c * vx + s * vy
                odom.twist.twist.linear.y = -s * vx + c * vy
                if got is not None:
                    got[0].publish(odom)
                p = m["Pose"]()
                _set_pose(p, x, y, h)
                team.poses.append(p)
            self._team_pub.publish(team)
            self._marker_pub.publish(self._markers(stamp, pos))

    def _markers(self, stamp: Any, pos: Array) -> Any:
        m = self._m
        arr = m["MarkerArray"]()
        for spec in markers_of(pos, self.pattern_points, self.world.radius_m):
            mk = m["Marker"]()
            mk.header.frame_id, mk.header.stamp = FRAME, stamp
            mk.ns, mk.id, mk.type, mk.action = spec.ns, spec.id, 7, 0  # SPHERE_LIST, ADD
            mk.pose.orientation.w = 1.0
            mk.scale.x = mk.scale.y = mk.scale.z = spec.diameter_m
            mk.color.r, mk.color.g, mk.color.b, mk.color.a = spec.rgba
            pts = []
            for px, py in spec.points.tolist():
                p = m["Pose"]().position
                p.x, p.y = px, py
                pts.append(p)
            mk.points = pts
            arr.markers.append(mk)
        return arr

    def exchange(
        self, step: int, dt_s: float, ids: list[int], pos: Array, deadline_s: float,
        stop: threading.Event, wait_all: bool = False,
        meanwhile: Callable[[], None] | None = None,
    ) -> Collected:
        """Odom out, then at the step's tick the newest Twist of each base: its velocity (age
        0; a base without a Twist in time holds still, age -1). A Twist answers no step, so
        there is nothing to wait for all of: ``wait_all`` waits one step (``dt_s``) at most;
        ``meanwhile`` runs once the odometry is out."""
        with self.cond:
            self._exchanges += 1
        t0 = time.monotonic()
        if wait_all:
            deadline_s = min(deadline_s, dt_s)
        self.publish_poses(step, dt_s, ids, pos)
        if meanwhile is not None:
            meanwhile()
        stop.wait(max(0.0, t0 + deadline_s - time.monotonic()))
        v, missed, applied = self.bases.velocities(ids, dt_s, CMD_TIMEOUT_S)
        if self.rec is not None:
            for k, rid in enumerate(ids):
                if rid in applied:
                    cmd = Command(rid, step, float(v[k, 0]), float(v[k, 1]), TWIST_BRAIN_ID,
                                  False, 0.0, 0.0, float(v[k, 0]), float(v[k, 1]))
                    self.rec.write_wire(keys.cmd_key(self.swarm, rid), encode_command(cmd))
        age = np.array([0 if rid in applied else -1 for rid in ids], dtype=np.int64)
        return Collected(v, missed, age)

    def close(self) -> None:
        super().close()
        if self._run:
            self._run = False
            self._thread.join(timeout=2.0)
            try:
                self._executor.shutdown(timeout_sec=1.0)
                self._node.destroy_node()
            finally:
                self._rclpy.try_shutdown(context=self._ctx)


def _set_pose(p: Any, x: float, y: float, yaw: float) -> None:
    p.position.x, p.position.y = float(x), float(y)
    p.orientation.z, p.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
