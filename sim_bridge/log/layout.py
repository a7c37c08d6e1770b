"""The layout of a run's MCAP log: topics, encodings, schemas. Writer and reader both use it.

Every channel has a standard message encoding and a real schema, so any MCAP tool
decodes every message without this project (``mcap_protobuf.decoder`` for the
protobuf channels, ``json`` for the others). ``K`` = ``patternrl/<swarm>``:

==========================  ===============================  ==========================
topic                       schema                           what
==========================  ===============================  ==========================
``K/robot/<id>/pose``       ``patternrl.RobotPose``          world -> robot
``K/robot/<id>/cmd``        ``patternrl.RobotCommand``       robot -> world
``K/robot/<id>/status``     ``patternrl.RobotStatus``        robot health
``K/robot/<id>/view``       ``patternrl.RobotView``          the team it perceived
``K/robot/<id>/slots``      ``patternrl.RobotSlots``         the slot it goes by
``K/pattern``               ``patternrl.Pattern``            target pattern (the world's)
``K/operator/pattern``      ``patternrl.Pattern``            an operator's target
``K/brain``                 ``patternrl.BrainSwap``          brain swaps
``/robot/<id>/pose``        ``foxglove.PoseInFrame``         frame ``world``
``/tf``                     ``foxglove.FrameTransforms``     ``world`` -> ``robot_<id>``
``/log/other``              ``patternrl.RawSample``          see below
``/world/events``           ``patternrl.Event``              JSON, see below
``/world/metrics``          ``patternrl.StepMetrics``        JSON, one per step
``/world/scene``            ``foxglove.SceneUpdate``         JSON, one per step
==========================  ===============================  ==========================

Protobuf channels have message and schema encoding ``protobuf``; JSON ones
message encoding ``json`` and schema encoding ``jsonschema``.

The protobuf schemas are :mod:`sim_bridge.log.schemas`'s (a ``FileDescriptorSet``
per schema record). The ``K/...`` channels hold every field of the Zenoh message
on that key (:mod:`runtime.wire.messages`), one channel per key; play-back turns them
back into the wire payloads. The world's poses of a step in one message (``K/poses``,
:class:`runtime.wire.messages.PoseBatch`) are written as the per-robot ``K/robot/<id>/pose``
messages they hold (same step, ``n_live`` = the batch's size), so every reader, replay
and panel sees one layout whichever way the poses travelled; play-back republishes them
on the per-robot keys, which robots accept as well. ``/tf`` holds one message per
recorded step with a transform per robot; ``/robot/<id>/pose`` the same position as a
``PoseInFrame`` (Foxglove's Plot panel: ``/robot/3/pose.pose.position.x``). ``/log/other`` holds
what is not one of the project's messages: a sample on a foreign key (whole), a
payload that did not decode (``reason``, its first bytes) and a payload refused
for its size (``reason``, no bytes; see :data:`MAX_PAYLOAD_BYTES`).

``K/robot/<id>/slots`` is there only for robots that agreed on their slots (``robot
--agree`` under imperfect sensing, :mod:`runtime.decision.agreement`): the slot each went by
at each step it decided, and its leader's whole assignment.

``K/robot/<id>/view`` is there only for robots that ran under imperfect sensing
(``robot --conditions``, every ``--view-every`` steps): where the robot believed each
member of its team to be when it decided a step, beside the world's poses of that same
step, so ``patternrl replay`` measures the estimation error. Older logs lack it and read
as before.

Time: ``publish_time`` is always the wall clock (ns since the Unix epoch). In
lockstep the world's log has ``log_time`` = simulated time, start + step x dt (the
wall clock at the run's start, plus the step of the message: a pose's, a command's,
a status's own step, the world's current step for the rest), so a log plays in
Foxglove at the speed the swarm moved; otherwise (realtime, ``patternrl record``)
``log_time`` is the wall clock too.

Old logs (written before this layout) hold the Zenoh payloads byte for byte in
channels of message encoding ``patternrl-wire``; the reader tells the two apart
per channel (:func:`channel_kind`) and reads both.

``/world/events`` (one JSON object each, ``kind`` plus ``step`` and ``time_s``):
``run_start`` (configuration), ``pattern`` (a pattern published: version, name,
points, reason ``phase`` or ``resize``), ``phase_start``, ``phase_end`` (the
phase's results: formed, steps, lower bounds, travel, collisions, min separation,
deadline misses, brain; ``hold_steps``, ``held_steps`` and ``held`` for the steps watched
after the first passage, absent from older logs), ``brain_swap`` (per robot: accepted,
reason), ``join``, ``leave``, ``collision`` (robot pairs that overlapped during the step),
``contact`` (pairs the physics saw start touching, walls included),
``deadline_miss`` (robots that had not answered step ``for_step`` in time),
``stale_command`` (of those, the robots that moved on an older command, and each
command's ``ages``: steps between its poses and ``for_step``), ``stale_guard`` (robots
whose applied command the world's guard slowed down at ``for_step``), ``malformed``
(a payload that did not decode), ``payload_refused`` (key and bytes of a payload over
the size limit, not written), ``run_end`` (outcome), ``log_dropped`` (messages the
recorder's writer could not keep up with and dropped, counted, at the end).

``/world/scene``: one ``foxglove.SceneUpdate`` per step, frame ``world``: an
entity per robot (entity id = the robot id, a cylinder of diameter 2R at its
position), an entity ``targets`` (a small sphere at each target slot, placed on
the team's centroid) and ``arena`` (the walls as a line loop). A robot that left
is deleted by id. Robots under imperfect sensing add ``perceived/<id>``: small
translucent spheres of the robot's colour where it believed its peers to be, drawn
when a new view of it came and kept until the next. The log opens in Foxglove's 3D
panel without custom panels.

Durability: chunks are small and the writer is flushed regularly
(:class:`sim_bridge.log.recorder.Recorder`), so a writer killed with SIGKILL leaves a
file that :mod:`sim_bridge.log.file` reads up to its last complete chunk. A
finished log also has the summary section and reads with any reader.
"""

from __future__ import annotations

from typing import Any, Final

from runtime.wire import keys
from runtime.wire import messages as wire
from sim_bridge.log import schemas as pb

WIRE_ENCODING: Final = "patternrl-wire"
"""Message (and schema) encoding of the wire channels of old logs."""
PROTOBUF_ENCODING: Final = pb.PROTOBUF
JSON_ENCODING: Final = "json"
JSON_SCHEMA_ENCODING: Final = "jsonschema"

EVENTS_TOPIC: Final = "/world/events"
METRICS_TOPIC: Final = "/world/metrics"
SCENE_TOPIC: Final = "/world/scene"
SCENE_FRAME: Final = "world"
TF_TOPIC: Final = "/tf"
OTHER_TOPIC: Final = "/log/other"


def robot_pose_topic(robot_id: int) -> str:
    """The ``foxglove.PoseInFrame`` topic of one robot."""
    return f"/robot/{int(robot_id)}/pose"


def robot_frame(robot_id: int) -> str:
    """The frame of one robot in ``/tf`` (child of :data:`SCENE_FRAME`)."""
    return f"robot_{int(robot_id)}"


MAX_PAYLOAD_BYTES: Final = 1 << 20
"""The largest payload the recorder writes (1 MiB), brains aside: a larger one is
not written, an event ``payload_refused`` (key, bytes) says so."""
MAX_BRAIN_PAYLOAD_BYTES: Final = (wire.MAX_ONNX_BYTES + wire.MAX_MANIFEST_BYTES
                                  + wire.MAX_TARGET_ROBOTS * 4 + (1 << 16))
"""The largest brain payload written: the largest brain the wire accepts."""

PB_SCHEMAS: Final = {
    keys.POSE: pb.ROBOT_POSE,
    keys.CMD: pb.ROBOT_COMMAND,
    keys.STATUS: pb.ROBOT_STATUS,
    keys.PATTERN: pb.PATTERN,
    keys.OPERATOR_PATTERN: pb.PATTERN,
    keys.BRAIN: pb.BRAIN_SWAP,
    keys.VIEW: pb.ROBOT_VIEW,
    keys.SLOTS: pb.ROBOT_SLOTS,
}
"""Key kind -> protobuf schema of the channel of keys of that kind."""

WIRE_SCHEMAS: Final = {
    keys.POSE: "patternrl.Pose",
    keys.CMD: "patternrl.Command",
    keys.STATUS: "patternrl.Status",
    keys.PATTERN: "patternrl.Pattern",
    keys.OPERATOR_PATTERN: "patternrl.Pattern",
    keys.BRAIN: "patternrl.Brain",
    keys.VIEW: "patternrl.View",
    keys.SLOTS: "patternrl.Slots",
}
"""Key kind -> schema name of the wire message on keys of that kind (old logs)."""

WIRE_SCHEMA_DATA: Final = (wire.__doc__ or "").encode()
"""The data of every wire schema record: the wire module's layout description."""


def wire_schema(key: str) -> str | None:
    """Schema name of the wire channel of ``key``; None for a key that is not ours (raw bytes)."""
    k = keys.parse_key(key)
    return None if k is None else WIRE_SCHEMAS.get(k.kind)


def channel_kind(topic: str, message_encoding: str, schema_name: str) -> tuple[str, int, bool]:
    """What a channel carries: (key kind or "", robot id on its key or -1, old wire format).

    A channel of one of the project's keys counts when it is in the old wire format
    or in protobuf with the schema of its kind (another writer's channel on such a
    key, in another schema, is ""); JSON topics and foreign keys are "".
    """
    if message_encoding == WIRE_ENCODING:
        kind, rid = wire_kind(topic, message_encoding)
        return kind, rid, True
    if message_encoding != PROTOBUF_ENCODING:
        return "", -1, False
    k = keys.parse_key(topic)
    if k is None or PB_SCHEMAS.get(k.kind) != schema_name:
        return "", -1, False
    return k.kind, -1 if k.robot_id is None else k.robot_id, False


def wire_kind(topic: str, message_encoding: str) -> tuple[str, int]:
    """What a channel carries: (key kind or "", robot id on its key or -1).

    The kind is one of :data:`runtime.wire.keys.KINDS` for a wire channel on one of the
    project's keys, "" for anything else (JSON topics, foreign keys).
    """
    if message_encoding != WIRE_ENCODING:
        return "", -1
    k = keys.parse_key(topic)
    if k is None:
        return "", -1
    return k.kind, -1 if k.robot_id is None else k.robot_id


EVENT_SCHEMA: Final[dict[str, Any]] = {
    "title": "patternrl.Event",
    "description": "Something the world did or saw; fields beyond these depend on kind.",
    "type": "object",
    "properties": {
        "kind": {"type": "string", "description": "run_start, pattern, phase_start, phase_end, "
                 "brain_swap, join, leave, collision, contact, deadline_miss, stale_command, "
                 "stale_guard, malformed, log_dropped, "
                 "payload_refused, run_end"},
        "step": {"type": "integer", "description": "world step when it happened"},
        "time_s": {"type": "number", "description": "simulated time, step * dt (s)"},
    },
    "required": ["kind", "step", "time_s"],
}

METRICS_SCHEMA: Final[dict[str, Any]] = {
    "title": "patternrl.StepMetrics",
    "description": "Per-step figures of the formation, after the step's physics.",
    "type": "object",
    "properties": {
        "step": {"type": "integer"},
        "time_s": {"type": "number"},
        "phase": {"type": "integer", "description": "index of the pattern in the sequence"},
        "pattern": {"type": "string"},
        "pattern_version": {"type": "integer"},
        "phase_step": {"type": "integer", "description": "steps since the phase began"},
        "n_live": {"type": "integer"},
        "formation_error_m": {"type": "number"},
        "max_slot_distance_m": {"type": "number"},
        "min_separation_m": {"type": "number"},
        "collisions": {"type": "integer", "description": "robot pairs overlapping this step"},
        "contacts": {"type": "integer", "description": "contacts the physics saw begin"},
        "deadline_misses": {"type": "integer",
                            "description": "robots without a command for the step in time"},
        "stale_commands": {"type": "integer",
                           "description": "of those, robots that moved on an older command"},
        "command_age_max": {"type": "integer",
                            "description": "oldest command applied (steps since its poses)"},
        "held_still": {"type": "integer",
                       "description": "robots that held still (no command within the bound)"},
        "guard_scaled": {"type": "integer",
                         "description": "commands the world's guard slowed down or stopped"},
        "rate_hz": {"type": "number",
                    "description": "realtime: the world's rate at the step (slower while "
                                   "robots cannot keep up)"},
        "wall_ms": {"type": "number", "description": "wall time of the step (ms)"},
    },
    "required": ["step", "time_s", "n_live", "formation_error_m", "min_separation_m"],
}


def _obj(title: str, props: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": props, "required": list(props)}


def _scene_schema() -> dict[str, Any]:
    """JSON schema of ``foxglove.SceneUpdate``, the parts this log writes.

    Names and fields follow Foxglove's published schema; the primitive arrays this
    log leaves empty are declared as arrays of objects.
    """
    num = {"type": "number"}
    time_ = _obj("time", {"sec": {"type": "integer", "minimum": 0},
                          "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}})
    dur = _obj("duration", {"sec": {"type": "integer"},
                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}})
    vec3 = _obj("foxglove.Vector3", {"x": num, "y": num, "z": num})
    quat = _obj("foxglove.Quaternion", {"x": num, "y": num, "z": num, "w": num})
    pose = _obj("foxglove.Pose", {"position": vec3, "orientation": quat})
    color = _obj("foxglove.Color", {"r": num, "g": num, "b": num, "a": num})
    point3 = _obj("foxglove.Point3", {"x": num, "y": num, "z": num})
    any_arr = {"type": "array", "items": {"type": "object"}}
    sphere = _obj("foxglove.SpherePrimitive", {"pose": pose, "size": vec3, "color": color})
    cylinder = _obj("foxglove.CylinderPrimitive", {
        "pose": pose, "size": vec3, "bottom_scale": num, "top_scale": num, "color": color})
    line = _obj("foxglove.LinePrimitive", {
        "type": {"title": "foxglove.LineType", "oneOf": [
            {"title": "LINE_STRIP", "const": 0}, {"title": "LINE_LOOP", "const": 1},
            {"title": "LINE_LIST", "const": 2}]},
        "pose": pose, "thickness": num, "scale_invariant": {"type": "boolean"},
        "points": {"type": "array", "items": point3}, "color": color,
        "colors": {"type": "array", "items": color},
        "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}}})
    text = _obj("foxglove.TextPrimitive", {
        "pose": pose, "billboard": {"type": "boolean"}, "font_size": num,
        "scale_invariant": {"type": "boolean"}, "color": color, "text": {"type": "string"}})
    kv = _obj("foxglove.KeyValuePair", {"key": {"type": "string"}, "value": {"type": "string"}})
    entity = _obj("foxglove.SceneEntity", {
        "timestamp": time_, "frame_id": {"type": "string"}, "id": {"type": "string"},
        "lifetime": dur, "frame_locked": {"type": "boolean"},
        "metadata": {"type": "array", "items": kv},
        "arrows": any_arr, "cubes": any_arr,
        "spheres": {"type": "array", "items": sphere},
        "cylinders": {"type": "array", "items": cylinder},
        "lines": {"type": "array", "items": line},
        "triangles": any_arr,
        "texts": {"type": "array", "items": text},
        "models": any_arr,
    })
    deletion = _obj("foxglove.SceneEntityDeletion", {
        "timestamp": time_,
        "type": {"title": "foxglove.SceneEntityDeletionType", "oneOf": [
            {"title": "MATCHING_ID", "const": 0}, {"title": "ALL", "const": 1}]},
        "id": {"type": "string"}})
    out = _obj("foxglove.SceneUpdate", {
        "deletions": {"type": "array", "items": deletion},
        "entities": {"type": "array", "items": entity}})
    out["description"] = "An update to the entities displayed in a 3D scene"
    return out


SCENE_SCHEMA: Final = _scene_schema()

JSON_TOPICS: Final = ((EVENTS_TOPIC, EVENT_SCHEMA), (METRICS_TOPIC, METRICS_SCHEMA),
                      (SCENE_TOPIC, SCENE_SCHEMA))
"""The world's JSON topics with their schemas, in the order a log registers them."""
