"""Every Zenoh key expression of Pattern-RL, built in this one module.

Layout (``<swarm>`` is one name of ``[A-Za-z0-9_-]+``, ``<id>`` a robot id >= 0)::

    patternrl/<swarm>/robot/<id>/pose     world -> robots    position, velocity, step, n_live
    patternrl/<swarm>/poses               world -> robots    every live robot's pose of a step
    patternrl/<swarm>/robot/<id>/cmd      robot -> world     commanded velocity, step, brain id
    patternrl/<swarm>/robot/<id>/status   robot -> anyone    brain id, latency, errors, swaps
    patternrl/<swarm>/robot/<id>/view     robot -> anyone    the team as the robot perceived it
    patternrl/<swarm>/robot/<id>/slots    robot -> robots    its slot; the leader its assignment
    patternrl/<swarm>/pattern             world -> all       target pattern, version (phases)
    patternrl/<swarm>/operator/pattern    operator -> all    a target between the world's
    patternrl/<swarm>/brain               operator -> robots  a new brain to swap in
    patternrl/<swarm>/alive/<id>          liveliness token; the world uses id "world"

Nothing else in the project formats or parses a key by hand: build keys with the
functions here and read them back with :func:`parse_key`, so that a change of
layout is a change of this file only.
"""

from __future__ import annotations

import re
from typing import Final, NamedTuple

PREFIX: Final = "patternrl"
WORLD_ID: Final = "world"

POSE: Final = "pose"
CMD: Final = "cmd"
STATUS: Final = "status"
VIEW: Final = "view"
SLOTS: Final = "slots"
ROBOT_CHANNELS: Final = (POSE, CMD, STATUS, VIEW, SLOTS)
PATTERN: Final = "pattern"
POSES: Final = "poses"
BRAIN: Final = "brain"
ALIVE: Final = "alive"
OPERATOR_PATTERN: Final = "operator_pattern"
KINDS: Final = (POSE, CMD, STATUS, PATTERN, BRAIN, ALIVE, POSES, OPERATOR_PATTERN, VIEW,
                 SLOTS)
"""Every kind of key, as :attr:`Key.kind` names it."""

_SWARM_RE: Final = re.compile(r"[A-Za-z0-9_-]+")
_ALIVE_ID_RE: Final = re.compile(r"[A-Za-z0-9_-]+")
_ANY_KEY_RE: Final = re.compile(
    r"patternrl/([A-Za-z0-9_-]+)/(?:robot/(0|[1-9][0-9]*)/(pose|cmd|status|view|slots)"
    r"|(pattern|brain|poses|operator/pattern)|alive/([A-Za-z0-9_-]+))"
)
_ROBOT_ID_RE: Final = re.compile(r"0|[1-9][0-9]*")


def validate_swarm(swarm: str) -> str:
    """Return ``swarm`` unchanged if it is a valid swarm name, else raise ValueError."""
    if not isinstance(swarm, str) or _SWARM_RE.fullmatch(swarm) is None:
        raise ValueError(f"invalid swarm name {swarm!r}: must be non-empty and only [A-Za-z0-9_-]")
    return swarm


def _robot_id(robot_id: int) -> int:
    if isinstance(robot_id, bool) or not isinstance(robot_id, int) or robot_id < 0:
        raise ValueError(f"invalid robot id {robot_id!r}: must be an int >= 0")
    return robot_id


def swarm_root(swarm: str) -> str:
    """Every key of one swarm: ``patternrl/<swarm>/**``."""
    return f"{PREFIX}/{validate_swarm(swarm)}/**"


def _robot_key(swarm: str, robot_id: int, channel: str) -> str:
    return f"{PREFIX}/{validate_swarm(swarm)}/robot/{_robot_id(robot_id)}/{channel}"


def _all_robots(swarm: str, channel: str) -> str:
    return f"{PREFIX}/{validate_swarm(swarm)}/robot/*/{channel}"


def pose_key(swarm: str, robot_id: int) -> str:
    """Pose of one robot, published by the world."""
    return _robot_key(swarm, robot_id, POSE)


def all_poses(swarm: str) -> str:
    """Poses of every robot of the swarm."""
    return _all_robots(swarm, POSE)


def poses_key(swarm: str) -> str:
    """Every live robot's pose of one step in one message
    (:class:`runtime.wire.messages.PoseBatch`), published by the world: what a simulated robot
    subscribes to (O(1) receives per step)."""
    return f"{PREFIX}/{validate_swarm(swarm)}/poses"


def cmd_key(swarm: str, robot_id: int) -> str:
    """Commanded velocity of one robot, published by that robot."""
    return _robot_key(swarm, robot_id, CMD)


def all_cmds(swarm: str) -> str:
    """Commands of every robot of the swarm."""
    return _all_robots(swarm, CMD)


def status_key(swarm: str, robot_id: int) -> str:
    """Status (health, latency, swap answers) of one robot."""
    return _robot_key(swarm, robot_id, STATUS)


def all_status(swarm: str) -> str:
    """Status of every robot of the swarm."""
    return _all_robots(swarm, STATUS)


def view_key(swarm: str, robot_id: int) -> str:
    """The team as one robot perceived it (:class:`runtime.wire.messages.View`), published
    by that robot now and then under imperfect sensing."""
    return _robot_key(swarm, robot_id, VIEW)


def all_views(swarm: str) -> str:
    """Perceived teams of every robot of the swarm."""
    return _all_robots(swarm, VIEW)


def slots_key(swarm: str, robot_id: int) -> str:
    """What one robot tells its team of the slots it goes by
    (:class:`runtime.wire.messages.Slots`, :mod:`runtime.decision.agreement`), published by
    that robot each step it decides under imperfect sensing with ``--agree``."""
    return _robot_key(swarm, robot_id, SLOTS)


def all_slots(swarm: str) -> str:
    """What every robot of the swarm tells of its slots."""
    return _all_robots(swarm, SLOTS)


def pattern_key(swarm: str) -> str:
    """Current target pattern of the swarm."""
    return f"{PREFIX}/{validate_swarm(swarm)}/pattern"


def operator_pattern_key(swarm: str) -> str:
    """A target pattern of an operator's, between the world's phases (versions: see
    :mod:`runtime.decision.team_pattern`)."""
    return f"{PREFIX}/{validate_swarm(swarm)}/operator/pattern"


def brain_key(swarm: str) -> str:
    """New brains for robots to swap in."""
    return f"{PREFIX}/{validate_swarm(swarm)}/brain"


def alive_key(swarm: str, id: int | str) -> str:
    """Liveliness token of one robot (an int id) or of the world (``"world"``)."""
    if isinstance(id, str):
        if _ALIVE_ID_RE.fullmatch(id) is None:
            raise ValueError(f"invalid liveliness id {id!r}: must be only [A-Za-z0-9_-]")
        return f"{PREFIX}/{validate_swarm(swarm)}/alive/{id}"
    return f"{PREFIX}/{validate_swarm(swarm)}/alive/{_robot_id(id)}"


def all_alive(swarm: str) -> str:
    """Liveliness tokens of the whole swarm (robots and world)."""
    return f"{PREFIX}/{validate_swarm(swarm)}/alive/*"


def parse_robot_id(key: str) -> int | None:
    """The robot id in a robot key (pose, cmd, status, view, slots or an int alive id), else
    None.

    ``None`` for any key not built by this module for one robot: another prefix, an
    invalid swarm name, a wildcard, a non-decimal or zero-padded id, the world's alive key.
    """
    k = parse_key(key)
    return None if k is None else k.robot_id


class Key(NamedTuple):
    """A key taken apart by :func:`parse_key`."""

    swarm: str
    kind: str
    """One of :data:`KINDS`."""
    robot_id: int | None
    """The robot a pose, cmd, status, view, slots or alive key belongs to; None otherwise (and for
    the world's alive key)."""
    alive_id: str | None = None
    """The raw id of an alive key (``"world"`` or a robot id), else None."""


def parse_key(key: str) -> Key | None:
    """Take apart any key this module builds; None for anything else.

    The inverse of the builders: ``parse_key(pose_key("s", 3))`` is
    ``Key("s", "pose", 3)``. Wildcards, other prefixes, zero-padded ids and
    unknown channels give None.
    """
    if not isinstance(key, str):
        return None
    m = _ANY_KEY_RE.fullmatch(key)
    if m is None:
        return None
    swarm, rid, channel, shared, alive = m.groups()
    if channel is not None:
        return Key(swarm, channel, int(rid))
    if shared is not None:
        return Key(swarm, OPERATOR_PATTERN if shared == "operator/pattern" else shared, None)
    robot = int(alive) if _ROBOT_ID_RE.fullmatch(alive) else None
    return Key(swarm, ALIVE, robot, alive)


def with_swarm(key: str, swarm: str) -> str | None:
    """The same key in another swarm (playing a log into a new swarm); None if not ours."""
    k = parse_key(key)
    if k is None:
        return None
    if k.kind in ROBOT_CHANNELS:
        assert k.robot_id is not None
        return _robot_key(swarm, k.robot_id, k.kind)
    if k.kind == PATTERN:
        return pattern_key(swarm)
    if k.kind == BRAIN:
        return brain_key(swarm)
    if k.kind == OPERATOR_PATTERN:
        return operator_pattern_key(swarm)
    if k.kind == POSES:
        return poses_key(swarm)
    assert k.alive_id is not None
    return alive_key(swarm, k.robot_id if k.robot_id is not None else k.alive_id)
