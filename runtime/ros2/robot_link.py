"""One robot's link to ROS 2: its pose in, its command out as ``geometry_msgs/Twist``.

:class:`Ros2Link` runs one rclpy node (its own context, no signal handlers: the robot keeps
its own) on a background thread:

* it subscribes the robot's pose: ``<ns>/odom`` (``nav_msgs/Odometry``) or a
  ``geometry_msgs/PoseStamped`` topic (motion capture), best effort (the sensor QoS, which
  matches reliable and best-effort publishers alike), depth 1: only the newest pose counts;
* each good pose, in the swarm's frame (``--ros2-origin``), goes to ``on_pose(x, y, vx, vy)``
  (the robot publishes it on its Zenoh pose key, so peers and the coordinator see it, and
  takes it itself);
* :meth:`Ros2Link.command` turns the decision's velocity into a ``Twist`` on ``<ns>/cmd_vel``
  (reliable, depth 1) for the base (:mod:`runtime.ros2.twist`);
* safety: with no pose for ``pose_timeout_s`` (a missing or silent topic) or a bad one
  (NaN, inf, absurd), the link publishes a zero ``Twist`` at once, turns every command
  into a zero ``Twist`` until a good pose comes (and repeats it every ``HOLD_REPEAT_S``, for a
  base that joins late), logs one line and reports why through ``error`` (the robot's
  status). Closing publishes a zero ``Twist`` too.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any, Final, Protocol

from runtime.log import Log
from runtime.ros2.environment import import_rclpy
from runtime.ros2.options import Ros2Options
from runtime.ros2.twist import ZERO, Planar, body_twist, planar_from_odom, yaw_of

__all__ = ["MAX_COORD_M", "Ros2Link"]

MAX_COORD_M: Final = 1e6  # as the robot's inbox: a pose farther away is malformed
SPIN_S: Final = 0.05
DAY_S: Final = 86_400.0
HOLD_REPEAT_S: Final = 0.5
"""While it holds still, the link says so again (a zero ``Twist``) this often."""


class Ros2Link:
    """A rclpy node for one robot: pose in, ``Twist`` out, a zero ``Twist`` without a pose."""

    def __init__(
        self,
        opts: Ros2Options,
        robot_id: int,
        dt_s: float,
        on_pose: Callable[[float, float, float, float], None],
        *,
        log: Log,
        error: Callable[[str], None] = lambda _why: None,
        drop: Callable[[str, str], None] = lambda _what, _why: None,
    ) -> None:
        """Opens the node and starts its thread; raises :class:`Ros2Unavailable` without
        ROS 2."""
        rclpy = import_rclpy()
        from geometry_msgs.msg import PoseStamped, Twist
        from nav_msgs.msg import Odometry
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from rclpy.signals import SignalHandlerOptions

        self.opts = opts
        self.dt_s = dt_s
        self._on_pose = on_pose
        self._log = log
        self._error = error
        self._drop = drop
        self._Twist = Twist
        self._lock = threading.Lock()
        self._pose: tuple[float, float, float, float] | None = None  # x, y, yaw, monotonic s
        self._last_stamp: tuple[float, float, float] | None = None  # PoseStamped: t, x, y
        self._stopped = ""  # why the robot holds still ("" when it does not)
        self._t_start = time.monotonic()
        self._t_zero = 0.0  # when the last zero Twist went out
        self.poses = 0
        """Good poses taken (for tests and status)."""
        self.twists = 0
        """Twists published (zero ones included)."""
        self.source = opts.pose_source
        self.kind = "geometry_msgs/PoseStamped" if opts.pose_topic else "nav_msgs/Odometry"

        self._ctx = Context()
        rclpy.init(
            context=self._ctx,
            domain_id=opts.domain_id,
            signal_handler_options=SignalHandlerOptions.NO,
        )
        try:
            self._node = rclpy.create_node(f"patternrl_robot_{robot_id}", context=self._ctx)
            sensor = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
            sensor.durability = qos_profile_sensor_data.durability
            if opts.pose_topic is None:
                self._node.create_subscription(Odometry, self.source, self._on_odom, sensor)
            else:
                self._node.create_subscription(
                    PoseStamped, self.source, self._on_pose_stamped, sensor
                )
            self._cmd_pub = self._node.create_publisher(
                Twist, opts.cmd_topic, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
            )
            period = min(0.05, opts.pose_timeout_s / 4.0)
            self._node.create_timer(period, self._check)
            self._executor = SingleThreadedExecutor(context=self._ctx)
            self._executor.add_node(self._node)
        except Exception:
            rclpy.try_shutdown(context=self._ctx)
            raise
        self._rclpy = rclpy
        self._closers: list[Callable[[], object]] = []
        self._run = True
        self._thread = threading.Thread(target=self._spin, name="ros2", daemon=True)
        self._thread.start()
        log("info", "ros2", f"pose from {self.source} ({self.kind}), command on "
            f"{opts.cmd_topic} (geometry_msgs/Twist, {opts.base} base)")

    # ------------------------------------------------------------ ROS 2 side

    def _spin(self) -> None:
        while self._run and self._ctx.ok():
            try:
                self._executor.spin_once(timeout_sec=SPIN_S)
            except Exception as e:  # a shutdown race or a callback's bug: never a traceback
                if self._run and self._ctx.ok():
                    self._log("warning", "ros2", f"{type(e).__name__}: {e}")

    def _on_odom(self, msg: Any) -> None:
        p = msg.pose.pose.position
        q = msg.pose.pose.orientation
        yaw = yaw_of(q.x, q.y, q.z, q.w)
        v = msg.twist.twist.linear
        vx, vy = planar_from_odom(v.x, v.y, yaw)
        self._take(p.x, p.y, yaw, vx, vy)

    def _on_pose_stamped(self, msg: Any) -> None:
        p = msg.pose.position
        q = msg.pose.orientation
        now = time.monotonic()
        vx = vy = 0.0
        last = self._last_stamp
        if last is not None and now - last[0] > 1e-3 and math.isfinite(p.x + p.y):
            vx, vy = (p.x - last[1]) / (now - last[0]), (p.y - last[2]) / (now - last[0])
        if math.isfinite(p.x + p.y):
            self._last_stamp = (now, p.x, p.y)
        self._take(p.x, p.y, yaw_of(q.x, q.y, q.z, q.w), vx, vy)

    def _take(self, x: float, y: float, yaw: float, vx: float, vy: float) -> None:
        vals = (x, y, yaw, vx, vy)
        if not all(math.isfinite(v) for v in vals):
            self._bad(f"non-finite pose on {self.source} (x={x}, y={y}, yaw={yaw})")
            return
        if max(abs(x), abs(y)) > MAX_COORD_M:
            self._bad(f"pose on {self.source} beyond {MAX_COORD_M:g} m ({x:g}, {y:g})")
            return
        ox, oy, oyaw = self.opts.origin
        if ox or oy or oyaw:
            c, s = math.cos(oyaw), math.sin(oyaw)
            x, y = ox + c * x - s * y, oy + s * x + c * y
            vx, vy = c * vx - s * vy, s * vx + c * vy
            yaw += oyaw
        with self._lock:
            self._pose = (x, y, yaw, time.monotonic())
            self.poses += 1
            was = self._stopped
            self._stopped = ""
        if was:
            self._log("info", "ros2", f"pose back on {self.source}: driving again")
        try:
            self._on_pose(x, y, vx, vy)
        except Exception as e:  # never a traceback on the executor's thread
            self._error(f"ros2 pose: {type(e).__name__}: {e}")

    def _bad(self, why: str) -> None:
        self._drop("ros2 pose", why)
        with self._lock:
            self._pose = None  # nothing to steer by until a good pose comes
        self._hold(f"{why}: holding still (zero Twist on {self.opts.cmd_topic})")

    def _check(self) -> None:
        """The pose timeout, on the executor's thread."""
        now = time.monotonic()
        with self._lock:
            pose, stopped = self._pose, self._stopped
        if stopped:
            if now - self._t_zero >= HOLD_REPEAT_S:  # for a base that joins late, or missed it
                self._publish(ZERO)
            return
        age = now - (pose[3] if pose is not None else self._t_start)
        if age <= self.opts.pose_timeout_s:
            return
        what = "no pose yet" if pose is None else "no fresh pose"
        why = f"{what} on {self.source} ({self.kind}) for {age:.1f} s"
        try:
            if self._node.count_publishers(self.source) == 0:
                why += ", nobody publishes it"
        except Exception:  # the graph is a hint only
            pass
        self._hold(f"{why}: holding still (zero Twist on {self.opts.cmd_topic})")

    def _hold(self, why: str) -> None:
        with self._lock:
            first = self._stopped != why
            self._stopped = why
        if first:
            self._log("warning", "ros2", why)
            self._error(f"ros2: {why}")
        self._publish(ZERO)

    # ------------------------------------------------------------ robot side

    def pose(self) -> tuple[float, float, float] | None:
        """The newest good pose (x, y, yaw in the swarm's frame) if fresh, else None."""
        with self._lock:
            p = self._pose
        if p is None or time.monotonic() - p[3] > self.opts.pose_timeout_s:
            return None
        return p[0], p[1], p[2]

    @property
    def holding(self) -> str:
        """Why the robot holds still on ROS 2 ("" when it drives)."""
        with self._lock:
            return self._stopped

    def command(self, vx: float, vy: float) -> Planar:
        """Send the decision's velocity (m/s, swarm frame) as a ``Twist``; a zero one without a
        fresh pose. Returns what was sent."""
        p = self.pose()
        tw = ZERO
        if p is not None:
            o = self.opts
            tw = body_twist(vx, vy, p[2], o.base, max_turn_rps=o.max_turn_rps, dt_s=self.dt_s)
        self._publish(tw)
        return tw

    def _publish(self, tw: Planar) -> None:
        if tw == ZERO:
            self._t_zero = time.monotonic()
        msg = self._Twist()
        msg.linear.x, msg.linear.y, msg.angular.z = tw
        try:
            self._cmd_pub.publish(msg)
            self.twists += 1
        except Exception as e:  # the context is going down
            if self._run:
                self._log("warning", "ros2", f"cmd_vel: {type(e).__name__}: {e}")

    def close(self) -> None:
        """A zero ``Twist`` (the base stops), then the node and its context go."""
        if not self._run:
            return
        self._publish(ZERO)
        self._run = False
        self._thread.join(timeout=2.0)
        try:
            self._executor.shutdown(timeout_sec=1.0)
            self._node.destroy_node()
        finally:
            self._rclpy.try_shutdown(context=self._ctx)
            for f in reversed(self._closers):
                f()

    def on_close(self, f: Callable[[], object]) -> None:
        """Run ``f`` when the link closes, after the node."""
        self._closers.append(f)

    def __enter__(self) -> Ros2Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _RobotLike(Protocol):
    """What :func:`open_robot_link` uses of a :class:`runtime.robot.robot.Robot`."""

    id: int
    session: Any
    cfg: Any
    world: Any
    inbox: Any
    log: Log
    stats: Any

    def _drop(self, what: str, why: str) -> None: ...


def open_robot_link(
    opts: Ros2Options, robot: _RobotLike, team_size: Callable[[], int]
) -> Ros2Link:
    """The link of a robot process: each ROS 2 pose becomes this robot's :class:`Pose` on its
    Zenoh pose key (peers and the coordinator see it; the robot takes it at once), stamped with
    the step of the UTC day's wall clock (time of day / dt: robots with synchronised clocks
    share steps, and a day's steps stay within what a log reader takes as a run's)."""
    from runtime.wire import keys
    from runtime.wire.messages import Pose, encode_pose

    key = keys.pose_key(robot.cfg.swarm, robot.id)
    import zenoh

    # to the peers only: the robot takes its own pose directly (once, not twice)
    pub = robot.session.declare_publisher(
        key, express=True, allowed_destination=zenoh.Locality.REMOTE
    )
    dt = float(robot.world.dt_s)
    rid = robot.id

    def on_pose(x: float, y: float, vx: float, vy: float) -> None:
        t = time.time()
        step = int((t % DAY_S) / dt)
        payload = encode_pose(Pose(rid, step, t, x, y, vx, vy, max(1, team_size())))
        robot.inbox.take(key, payload)
        pub.put(payload)

    try:
        link = Ros2Link(
            opts,
            rid,
            dt,
            on_pose,
            log=robot.log,
            error=lambda why: robot.stats.error(why, count=False),
            drop=robot._drop,
        )
    except BaseException:
        pub.undeclare()
        raise
    link.on_close(pub.undeclare)
    return link
