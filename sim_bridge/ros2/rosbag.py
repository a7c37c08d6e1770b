"""``patternrl replay LOG --to-rosbag2 DIR``: a run's log as a rosbag2 folder of ROS 2 types.

Written with ``rosbags`` (pure Python; no ROS install), the ROS 2 Kilted type definitions,
MCAP storage (rosbag2's default), so ``ros2 bag play DIR``, RViz, Foxglove and ``rosbags``'
reader open it. Topics (:mod:`sim_bridge.ros2.scene`):

* ``/robot_<i>/pose`` ``geometry_msgs/msg/PoseStamped``: one per recorded pose of robot i
  (orientation: identity; the log holds positions);
* ``/robot_<i>/cmd_vel`` ``geometry_msgs/msg/Twist``: one per recorded command, the
  decision's velocity in the ``world`` frame (``linear.x``, ``linear.y``);
* ``/swarm/poses`` ``geometry_msgs/msg/PoseArray``: one per recorded step, robots in id order;
* ``/swarm/markers`` ``visualization_msgs/msg/MarkerArray``: one per recorded step, the robots
  and the targets (the pattern in force, centred on the team).

Time: every message of step s (its poses, PoseArray, MarkerArray and the commands decided
for it) is stamped, header and bag time alike, with the log time of that step's first pose:
in lockstep the simulated time the log carries (start + s x dt), so ``ros2 bag play`` moves
at the speed the swarm moved; in realtime the wall clock. A command of a step without a
recorded pose is stamped by the nearest recorded step's time, plus or minus steps x dt.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import Any, Final

import numpy as np

from runtime.errors import InputError
from sim_bridge.log.file import iter_messages
from sim_bridge.log.reader import LogData
from sim_bridge.ros2.scene import (
    FRAME,
    MARKERS_TOPIC,
    POSES_TOPIC,
    cmd_topic,
    markers_of,
    pose_topic,
)

__all__ = ["TYPES", "write_rosbag2"]

POSE_STAMPED: Final = "geometry_msgs/msg/PoseStamped"
TWIST: Final = "geometry_msgs/msg/Twist"
POSE_ARRAY: Final = "geometry_msgs/msg/PoseArray"
MARKER_ARRAY: Final = "visualization_msgs/msg/MarkerArray"
TYPES: Final = (POSE_STAMPED, TWIST, POSE_ARRAY, MARKER_ARRAY)
SPHERE_LIST: Final = 7  # visualization_msgs/msg/Marker's constants
ADD: Final = 0


class _Msgs:
    """Builders of the messages, on a rosbags type store."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_KILTED)
        t = self.store.types
        self.Time = t["builtin_interfaces/msg/Time"]
        self.Duration = t["builtin_interfaces/msg/Duration"]
        self.Header = t["std_msgs/msg/Header"]
        self.Point = t["geometry_msgs/msg/Point"]
        self.Quaternion = t["geometry_msgs/msg/Quaternion"]
        self.Pose = t["geometry_msgs/msg/Pose"]
        self.Vector3 = t["geometry_msgs/msg/Vector3"]
        self.PoseStamped = t[POSE_STAMPED]
        self.Twist = t[TWIST]
        self.PoseArray = t[POSE_ARRAY]
        self.Marker = t["visualization_msgs/msg/Marker"]
        self.MarkerArray = t[MARKER_ARRAY]
        self.ColorRGBA = t["std_msgs/msg/ColorRGBA"]
        self.CompressedImage = t["sensor_msgs/msg/CompressedImage"]
        self.MeshFile = t["visualization_msgs/msg/MeshFile"]

    def header(self, ns: int) -> Any:
        return self.Header(stamp=self.Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                           frame_id=FRAME)

    def pose(self, x: float, y: float) -> Any:
        return self.Pose(position=self.Point(x=float(x), y=float(y), z=0.0),
                         orientation=self.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))

    def twist(self, vx: float, vy: float) -> Any:
        return self.Twist(linear=self.Vector3(x=float(vx), y=float(vy), z=0.0),
                          angular=self.Vector3(x=0.0, y=0.0, z=0.0))

    def markers(self, ns: int, xy: np.ndarray, pattern: np.ndarray | None, radius: float) -> Any:
        out = []
        empty = np.zeros(0, dtype=np.uint8)
        for m in markers_of(xy, pattern, radius):
            r, g, b, a = m.rgba
            out.append(self.Marker(
                header=self.header(ns), ns=m.ns, id=m.id, type=SPHERE_LIST,
                action=ADD, pose=self.pose(0.0, 0.0),
                scale=self.Vector3(x=m.diameter_m, y=m.diameter_m, z=m.diameter_m),
                color=self.ColorRGBA(r=r, g=g, b=b, a=a),
                lifetime=self.Duration(sec=0, nanosec=0), frame_locked=False,
                points=[self.Point(x=float(px), y=float(py), z=0.0) for px, py in m.points],
                colors=[], texture_resource="",
                texture=self.CompressedImage(header=self.header(ns), format="", data=empty),
                uv_coordinates=[], text="", mesh_resource="",
                mesh_file=self.MeshFile(filename="", data=empty),
                mesh_use_embedded_materials=False,
            ))
        return self.MarkerArray(markers=out)


def write_rosbag2(data: LogData, out: str | Path) -> dict[str, int]:
    """Write ``data`` as a rosbag2 folder ``out`` (which must not exist); returns topic ->
    messages written. :class:`InputError` when ``out`` exists or ``rosbags`` is missing."""
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer
    except ImportError:
        raise InputError(
            "--to-rosbag2 needs rosbags: install the ros2 extra: pip install -e '.[ros2]'"
        ) from None
    out = Path(out)
    if out.exists():
        raise InputError(f"--to-rosbag2 {out}: exists already; give a new folder")
    m = _Msgs()
    world = data.world
    dt_ns = round(world.dt_s * 1e9)
    fr, cmds = data.frames, data.commands
    step_ns = _step_times(data)
    marks = [p.msg_index for p in data.patterns]
    counts: dict[str, int] = {}
    out.parent.mkdir(parents=True, exist_ok=True)
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns: dict[tuple[str, str], Any] = {}

        def put(topic: str, typ: str, ns: int, msg: Any) -> None:
            c = conns.get((topic, typ))
            if c is None:
                c = conns[(topic, typ)] = w.add_connection(topic, typ, typestore=m.store)
            w.write(c, ns, m.store.serialize_cdr(msg, typ))
            counts[topic] = counts.get(topic, 0) + 1

        order = np.argsort(cmds.step, kind="stable")
        c_steps = cmds.step[order]
        steps = np.union1d(fr.steps, c_steps).tolist()
        ci = 0
        for s in steps:
            k = fr.row(int(s))
            ns = int(step_ns[k]) if k >= 0 else _nearest(fr.steps, step_ns, int(s), dt_ns)
            if k >= 0:
                here = fr.present[k]
                ids, xy = fr.ids[here].tolist(), fr.xy[k, here]
                for rid, (x, y) in zip(ids, xy.tolist(), strict=True):
                    put(pose_topic(rid), POSE_STAMPED, ns,
                        m.PoseStamped(header=m.header(ns), pose=m.pose(x, y)))
                put(POSES_TOPIC, POSE_ARRAY, ns,
                    m.PoseArray(header=m.header(ns), poses=[m.pose(x, y) for x, y in xy.tolist()]))
                j = bisect.bisect_right(marks, int(fr.first_msg[k])) - 1
                pattern = data.patterns[j].msg.points if j >= 0 else None
                put(MARKERS_TOPIC, MARKER_ARRAY, ns, m.markers(ns, xy, pattern, world.radius_m))
            while ci < len(order) and c_steps[ci] == s:
                i = int(order[ci])
                put(cmd_topic(int(cmds.robot_id[i])), TWIST, ns, m.twist(*cmds.v[i].tolist()))
                ci += 1
    return counts


def _step_times(data: LogData) -> np.ndarray:
    """The log time (ns) of each recorded step's first pose (a second, light pass)."""
    want = data.frames.first_msg
    out = np.zeros(len(want), dtype=np.int64)
    if not len(want):
        return out
    order = np.argsort(want, kind="stable")
    targets = want[order].tolist()
    j = 0
    for i, raw in enumerate(iter_messages(data.path)):
        while j < len(targets) and targets[j] == i:
            out[order[j]] = raw[1]
            j += 1
        if j == len(targets):
            break
    return out


def _nearest(steps: np.ndarray, times: np.ndarray, s: int, dt_ns: int) -> int:
    """The time of step ``s`` from the nearest recorded step's (or ``s x dt`` without any)."""
    if not len(steps):
        return s * dt_ns
    k = int(np.clip(np.searchsorted(steps, s), 0, len(steps) - 1))
    if k > 0 and abs(int(steps[k - 1]) - s) < abs(int(steps[k]) - s):
        k -= 1
    return int(times[k]) + (s - int(steps[k])) * dt_ns
