"""The log's layout (channels by key), its command columns and its phase slicing."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from runtime.decision.patterns import make_pattern
from runtime.wire import keys
from runtime.wire.messages import (
    Command,
    PatternMsg,
    Pose,
    encode_command,
    encode_pattern,
    encode_pose,
)
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.columns import decode_commands
from sim_bridge.log.layout import (
    EVENTS_TOPIC,
    WIRE_ENCODING,
    WIRE_SCHEMAS,
    wire_kind,
    wire_schema,
)
from sim_bridge.log.phases import phases_of
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder

W = DEFAULT_WORLD


def test_wire_channels_are_told_apart_by_their_keys() -> None:
    assert wire_schema(keys.pose_key("s", 3)) == WIRE_SCHEMAS[keys.POSE] == "patternrl.Pose"
    assert wire_schema(keys.cmd_key("s", 0)) == "patternrl.Command"
    assert wire_schema(keys.pattern_key("s")) == "patternrl.Pattern"
    assert wire_schema(keys.alive_key("s", 1)) is None  # a key of ours without a schema
    assert wire_schema("patternrl/s/something/else") is None  # raw bytes
    assert wire_kind(keys.status_key("s", 12), WIRE_ENCODING) == (keys.STATUS, 12)
    assert wire_kind(keys.brain_key("s"), WIRE_ENCODING) == (keys.BRAIN, -1)
    assert wire_kind(keys.pose_key("s", 3), "json") == ("", -1)
    assert wire_kind(EVENTS_TOPIC, "json") == ("", -1)
    assert wire_kind("patternrl/s/robot/03/pose", WIRE_ENCODING) == ("", -1)


def _log(path: Path, events: bool) -> None:
    """Steps 0-5 of two robots; line from step 0, resized at 2 (events only), circle from 3."""
    line, circle = make_pattern("line", 2), make_pattern("circle", 2)
    with Recorder(path) as rec:
        for step in range(6):
            t = step * 10**8
            if step in (0, 3):
                name, pts = ("line", line) if step == 0 else ("circle", circle)
                version = 1 if step == 0 else 3
                rec.write_wire(keys.pattern_key("s"), encode_pattern(
                    PatternMsg(version, name, pts, W.formed_tol_m)), t)
                if events:
                    rec.event("pattern", step, step * W.dt_s, version=version, name=name,
                              reason="phase", points=pts.tolist(), formed_tol_m=W.formed_tol_m)
                    rec.event("brain_swap", step, step * W.dt_s, robot=0, accepted=True)
            if step == 2 and events:
                rec.event("pattern", 2, 0.2, version=2, name="line", reason="resize",
                          points=(line * 1.5).tolist(), formed_tol_m=W.formed_tol_m)
                rec.event("phase_end", 2, 0.2, end_step=2)
                rec.event("brain_swap", 2, 0.2, robot=1, accepted=False)
            for rid in range(2):
                rec.write_wire(keys.pose_key("s", rid), encode_pose(
                    Pose(rid, step, step * W.dt_s, float(rid), float(step), 0.0, 0.0, 2)), t + 1)


def test_phases_sliced_from_events(tmp_path: Path) -> None:
    _log(tmp_path / "e.mcap", events=True)
    data = read_log(tmp_path / "e.mcap")
    assert data.frames.rows(1, 4).tolist() == [1, 2, 3, 4]
    assert data.frames.rows(7, 9).tolist() == [] and data.frames.row(5) == 5
    line, circle = phases_of(data)
    assert (line.name, line.start_step, line.end_step) == ("line", 0, 2)
    assert [p.step for p in line.patterns] == [0, 2]  # the resize is the same phase
    assert line.pattern_rows(np.arange(4)).tolist() == [0, 0, 1, 1]
    assert (circle.name, circle.start_step, circle.end_step) == ("circle", 3, None)
    # a swap between two phases belongs to the next one
    assert [s["robot"] for s in line.swaps] == [0]
    assert [s["robot"] for s in circle.swaps] == [1, 0]


def test_phases_sliced_from_the_wire_without_events(tmp_path: Path) -> None:
    _log(tmp_path / "w.mcap", events=False)
    data = read_log(tmp_path / "w.mcap")
    line, circle = phases_of(data)
    assert (line.name, line.start_step, circle.name, circle.start_step) == ("line", 0, "circle", 3)
    assert [p.version for p in line.patterns] == [1] and line.end_step is None


def test_frames_give_the_robots_present_at_a_step_in_id_order(tmp_path: Path) -> None:
    path = tmp_path / "f.mcap"
    with Recorder(path) as rec:
        for step, rids in ((0, (3, 1)), (1, (1,)), (3, (3, 1))):
            for rid in rids:
                rec.write_wire(keys.pose_key("s", rid), encode_pose(
                    Pose(rid, step, step * W.dt_s, 10.0 * rid, float(step), 0.0, 0.0, 2)))
    fr = read_log(path).frames
    ids, xy = fr.at(0)
    assert ids.tolist() == [1, 3] and xy.tolist() == [[10.0, 0.0], [30.0, 0.0]]
    ids, xy = fr.at(1)
    assert ids.tolist() == [1] and xy.shape == (1, 2) and xy.tolist() == [[10.0, 1.0]]
    with pytest.raises(KeyError):
        fr.at(2)  # no pose of step 2 on the log


def test_command_columns_keep_file_order_across_brain_id_lengths() -> None:
    brains = ["b" * 64, "rule:assign", "", "b" * 64, "rule:assign", "b" * 64]
    raw = [encode_command(Command(k % 3, k, 0.1 * k, -0.1 * k, b, k == 1, 0.0, 5.0))
           for k, b in enumerate(brains)]
    raw.insert(2, raw[0][:-1])  # a command whose length says its brain id is cut short
    rid = [k % 3 for k in range(len(brains))]
    rid.insert(2, 0)
    cmds, bad = decode_commands(raw, rid)
    assert bad == 1
    assert cmds.step.tolist() == list(range(6)) and cmds.brain == brains
    assert cmds.v[:, 0].tolist() == [0.1 * k for k in range(6)]
    assert cmds.safety_changed.tolist() == [False, True, False, False, False, False]
    everything = np.ones(6, bool)
    assert list(cmds.brain_counts(everything).items()) == [
        ("b" * 64, 3), ("rule:assign", 2), ("", 1)]
    assert cmds.brain_counts(cmds.step >= 4) == {"rule:assign": 1, "b" * 64: 1}
    assert list(cmds.brain_counts(cmds.step >= 4)) == ["rule:assign", "b" * 64]


def test_command_columns_read_wire_versions_1_and_2_together() -> None:
    """An old log's version 1 commands beside version 2 ones, of the same brain id length
    and of another: the brain velocity of a version 1 command is its own velocity."""
    cmds = [Command(k, k, 0.1 * k, 0.2, b, False, 0.0, 1.0, -0.5 * k, 0.25)
            for k, b in enumerate(["ab", "cd", "xyz", "ef"])]

    def v1(c: Command) -> bytes:
        brain = c.brain_id.encode()
        return struct.pack("<BBIQddBddH", 2, 1, c.robot_id, c.step, c.vx, c.vy, 0,
                           0.0, 1.0, len(brain)) + brain

    raw = [encode_command(cmds[0]), v1(cmds[1]), v1(cmds[2]), encode_command(cmds[3]),
           b"\x02\x03" + encode_command(cmds[3])[2:]]  # an unknown version: malformed
    got, bad = decode_commands(raw, [0, 1, 2, 3, 3])
    assert bad == 1 and got.step.tolist() == [0, 1, 2, 3] and got.brain == ["ab", "cd", "xyz", "ef"]
    assert got.v.tolist() == [[0.1 * k, 0.2] for k in range(4)]
    assert got.brain_v.tolist() == [[0.0, 0.25], [0.1, 0.2], [0.2, 0.2], [-1.5, 0.25]]
