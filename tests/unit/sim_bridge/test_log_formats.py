"""Today's log layout: protobuf every tool decodes, sizes refused, forged steps and ids
skipped, damage told from a cut, other writers' logs read without a traceback."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory

from patternrl.cli import main as cli
from runtime.wire import keys
from runtime.wire.fields import COMMAND, POSE, FieldTable
from runtime.wire.messages import Command, Pose, decode_command, encode_command, encode_pose
from sim_bridge.log import schemas as pb
from sim_bridge.log.columns import decode_commands_pb, decode_poses_pb
from sim_bridge.log.layout import MAX_PAYLOAD_BYTES
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder, SimTime

POSES = [Pose(3, 12, 1.2, 0.5, 0.0, -1.0, 0.0, 4), Pose(0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0),
         Pose(2**32 - 1, 2**64 - 1, -1e300, 1e-300, 7.0, 0.25, -0.0, 2**32 - 1)]
COMMANDS = [Command(3, 12, 0.0, 1.0, "abc", False, 0.0, 12.5),
            Command(0, 0, -0.3, 0.4, "", True, 0.2, 0.0),
            Command(7, 2**64 - 1, 0.1, 0.0, "x" * 64, True, 1e9, 3.5),
            Command(2, 5, 0.5, 0.0, "rule:assign", True, 0.7, 9.0, 1.2, 0.0)]


@pytest.mark.parametrize("pose", POSES)
def test_a_pose_in_the_fixed_layout_parses_with_protobuf(pose: Pose) -> None:
    m = pb.parse(pb.ROBOT_POSE, pb.encode_pose_pb(pose))
    assert (m.robot_id, m.step, m.time_s, m.x, m.y, m.vx, m.vy, m.n_live) == (
        pose.robot_id, pose.step, pose.time_s, pose.x, pose.y, pose.vx, pose.vy, pose.n_live)
    assert pb.to_wire(pb.ROBOT_POSE, pb.encode_pose_pb(pose)) == encode_pose(pose)


@pytest.mark.parametrize("cmd", COMMANDS)
def test_a_command_in_the_fixed_layout_parses_with_protobuf(cmd: Command) -> None:
    data = pb.encode_command_pb(cmd)
    m = pb.parse(pb.ROBOT_COMMAND, data)
    assert (m.robot_id, m.step, m.vx, m.vy, m.brain_id, m.safety_changed,
            m.safety_change_mps, m.decision_us) == (
        cmd.robot_id, cmd.step, cmd.vx, cmd.vy, cmd.brain_id, cmd.safety_changed,
        cmd.safety_change_mps, cmd.decision_us)
    assert m.HasField("brain_vx") and m.HasField("brain_vy")  # written even when zero
    assert (m.brain_vx, m.brain_vy) == (cmd.brain_vx, cmd.brain_vy)
    assert pb.to_wire(pb.ROBOT_COMMAND, data) == encode_command(cmd)
    c, bad = decode_commands_pb([data], [cmd.robot_id], [0])
    assert bad == 0 and c.brain_v.tolist() == [[cmd.brain_vx, cmd.brain_vy]]


def _values(table: FieldTable, version: int) -> dict[str, object]:
    """A distinct value for each field of ``table`` of format ``version``."""
    out: dict[str, object] = {}
    for k, f in enumerate(table.at(version), start=1):
        out[f.name] = {"u32": 2**32 - k, "u64": 2**64 - k, "f64": -1.5 * k - 0.25,
                       "bool": True, "str": "brain-" * k}[f.kind]
    return out


@pytest.mark.parametrize(("table", "version"), [(POSE, 1), (COMMAND, 1), (COMMAND, 2)])
def test_the_descriptor_of_a_table_parses_its_fixed_layout(table: FieldTable,
                                                           version: int) -> None:
    """The fixed layout derived from a field table, packed with struct, parses field by
    field with the protobuf descriptor derived from the same table; fields added by a
    later format are absent (no presence), not zero."""
    layout = pb.fixed_layout(table, version)
    fmt = struct.Struct("<" + "".join("B" + code for _, _, code in layout))
    values = _values(table, version)
    args: list[object] = []
    tail = b""
    for (col, tag, _), f in zip(layout, [*(f for f in table.at(version) if not f.variable),
                                         *(f for f in table.at(version) if f.variable)],
                                strict=True):
        v = values[f.name]
        if isinstance(v, str):
            raw = v.encode()
            args += [tag, len(raw)]
            tail += raw
            assert col == f.col + "_len"
        else:
            args += [tag, v]
            assert col == f.col
    data = fmt.pack(*args) + tail
    m = pb.parse(f"patternrl.{table.proto}", data)
    for f in table.fields:
        if f.since <= version:
            assert getattr(m, f.name) == values[f.name], f.name
        if f.since > 1:  # proto3 optional: present only where the format has it
            assert m.HasField(f.name) == (f.since <= version), f.name
    # the dtype of the fixed layout views the very same bytes
    blen = len(tail)
    dt = (pb.POSE_PB_DTYPE if table is POSE else pb.command_pb_dtype(blen, old=version == 1))
    assert dt.itemsize == len(data) and fmt.size == dt.itemsize - blen
    (rec,) = np.frombuffer(data, dt)
    tags = pb.POSE_PB_TAGS if table is POSE else (
        pb.COMMAND_PB_TAGS if version == 2 else pb.COMMAND_PB_TAGS_V1)
    assert {t: int(rec[t]) for t in tags} == tags
    for f in table.at(version):
        if not f.variable:
            assert rec[f.col] == values[f.name], f.name


def test_the_encoders_write_the_derived_fixed_layouts() -> None:
    """encode_pose_pb and encode_command_pb write what the tables' layouts pack."""
    values = _values(POSE, 1)
    p = Pose(**values)  # type: ignore[arg-type]
    # every value non-zero: the protobuf library writes the same bytes
    assert pb.encode_pose_pb(p) == pb.message_class(pb.ROBOT_POSE)(**values).SerializeToString()
    c = COMMANDS[3]
    rec = np.frombuffer(pb.encode_command_pb(c), pb.command_pb_dtype(len(c.brain_id)))[0]
    for f in COMMAND.fields:
        if not f.variable:
            assert rec[f.col] == getattr(c, f.name), f.name
    assert bytes(rec["brain"]).decode() == c.brain_id


def _old_command_pb(c: Command) -> bytes:
    """``c`` in the fixed layout logs had before fields 9 and 10 (brain_vx, brain_vy)."""
    brain = c.brain_id.encode()
    return struct.pack("<BIBQBdBdBBBdBdBB", 0x0D, c.robot_id, 0x11, c.step, 0x19, c.vx, 0x21,
                       c.vy, 0x28, int(c.safety_changed), 0x31, c.safety_change_mps, 0x39,
                       c.decision_us, 0x42, len(brain)) + brain


def test_old_command_layouts_still_read_with_the_brain_velocity_as_the_command() -> None:
    """Logs written before the brain velocity: its fixed layout, and another writer's."""
    old = [_old_command_pb(c) for c in COMMANDS]
    other = bytes(pb.message_class(pb.ROBOT_COMMAND)(
        robot_id=1, step=3, vx=0.25, vy=-0.5, brain_id="z").SerializeToString())
    new = pb.encode_command_pb(COMMANDS[3])
    raw = [old[0], new, other, old[1], old[2], old[3]]
    rids = [3, 2, 1, 0, 7, 2]
    c, bad = decode_commands_pb(raw, rids, list(range(6)))
    assert bad == 0 and c.robot_id.tolist() == rids
    assert c.brain == ["abc", "rule:assign", "z", "", "x" * 64, "rule:assign"]
    assert c.v.tolist() == [[0.0, 1.0], [0.5, 0.0], [0.25, -0.5], [-0.3, 0.4], [0.1, 0.0],
                            [0.5, 0.0]]
    brain_v = c.v.copy()
    brain_v[1] = [1.2, 0.0]
    assert c.brain_v.tolist() == brain_v.tolist()
    for cmd, data in zip(COMMANDS, old, strict=True):  # play-back puts back version 2
        back = decode_command(pb.to_wire(pb.ROBOT_COMMAND, data))
        assert (back.vx, back.vy, back.brain_vx, back.brain_vy) == (
            cmd.vx, cmd.vy, cmd.vx, cmd.vy)


def test_a_recorded_log_carries_the_brain_velocity(tmp_path: Path) -> None:
    """Robots of either wire version, recorded, decoded by mcap's own protobuf decoder."""
    log = tmp_path / "run.mcap"
    sent = [Command(0, 0, 0.3, 0.0, "b", True, 0.9, 5.0, 1.2, 0.0),
            Command(1, 0, 0.1, -0.2, "b", False, 0.0, 5.0)]
    v1 = struct.pack("<BBIQddBddH", 2, 1, 2, 0, -0.4, 0.0, 0, 0.0, 5.0, 1) + b"b"
    with Recorder(log) as rec:
        for k in range(3):
            rec.write_wire(keys.pose_key("s", k), encode_pose(Pose(k, 0, 0.0, k, 0, 0, 0, 3)))
        for c in sent:
            rec.write_wire(keys.cmd_key("s", c.robot_id), encode_command(c))
        rec.write_wire(keys.cmd_key("s", 2), v1)
    got = {}
    factory = DecoderFactory()
    with open(log, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema is not None and schema.name == pb.ROBOT_COMMAND:
                decode = factory.decoder_for(channel.message_encoding, schema)
                assert decode is not None
                m = decode(message.data)
                got[m.robot_id] = (m.vx, m.vy, m.brain_vx, m.brain_vy)
    assert got == {0: (0.3, 0.0, 1.2, 0.0), 1: (0.1, -0.2, 0.1, -0.2),
                   2: (-0.4, 0.0, -0.4, 0.0)}
    cmds = read_log(log).commands
    assert cmds.robot_id.tolist() == [0, 1, 2]
    assert cmds.brain_v.tolist() == [[1.2, 0.0], [0.1, -0.2], [-0.4, 0.0]]


def test_columns_read_the_fixed_layout_and_another_writers_alike() -> None:
    """The library leaves proto3 zeros out: those payloads take the one-by-one path."""
    poses = POSES[:2]
    ours = [pb.encode_pose_pb(p) for p in poses]
    theirs = [bytes(pb.message_class(pb.ROBOT_POSE)(
        robot_id=p.robot_id, step=p.step, time_s=p.time_s, x=p.x, y=p.y, vx=p.vx, vy=p.vy,
        n_live=p.n_live).SerializeToString()) for p in poses]
    assert theirs[1] == b""  # every field zero
    rids = [p.robot_id for p in poses]
    a, ia, bad_a = decode_poses_pb(ours, [0, 1], rids)
    b, ib, bad_b = decode_poses_pb(theirs, [0, 1], rids)
    assert bad_a == bad_b == 0 and a.tobytes() == b.tobytes() and ia.tolist() == ib.tolist()
    cmds = COMMANDS[:2]
    mixed = [pb.encode_command_pb(cmds[0]), bytes(pb.message_class(pb.ROBOT_COMMAND)(
        robot_id=0, step=0, vx=-0.3, vy=0.4, brain_id="", safety_changed=True,
        safety_change_mps=0.2).SerializeToString())]
    c, bad = decode_commands_pb(mixed, [3, 0], [0, 1])
    assert bad == 0 and c.robot_id.tolist() == [3, 0] and c.brain == ["abc", ""]
    assert c.v.tolist() == [[0.0, 1.0], [-0.3, 0.4]] and c.safety_changed.tolist() == [0, 1]


def _synthetic(path: Path, steps: int = 10, n: int = 3, lockstep: bool = True) -> int:
    """A run through the recorder: poses and commands of ``steps`` steps, metrics, run_end."""
    step = 0
    st = SimTime(1_700_000_000_000_000_000, 100_000_000, lambda: step) if lockstep else None
    with Recorder(path, sim_time=st) as rec:
        rec.event("run_start", 0, 0.0, swarm="s", robots=n, mode="lockstep")
        for step in range(steps):
            for r in range(n):
                rec.write_wire(keys.pose_key("s", r), encode_pose(
                    Pose(r, step, step * 0.1, float(r), step * 0.01, 0.0, 0.1, n)))
                rec.write_wire(keys.cmd_key("s", r), encode_command(
                    Command(r, step, 0.0, 0.1, "brain", False, 0.0, 10.0)))
            rec.metrics({"step": step + 1, "time_s": (step + 1) * 0.1, "n_live": n,
                         "formation_error_m": 1.0, "min_separation_m": 0.5},
                        rec.log_time(step + 1))
        rec.event("run_end", steps, steps * 0.1, outcome="done", steps=steps)
    return steps


def test_every_channel_decodes_with_mcaps_own_decoders_and_lockstep_time_steps_by_dt(
        tmp_path: Path) -> None:
    import jsonschema

    log = tmp_path / "run.mcap"
    _synthetic(log)
    seen: dict[str, int] = {}
    pose_times: list[tuple[int, int, int]] = []
    factory = DecoderFactory()  # mcap's protobuf decoder; JSON is json
    with open(log, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None, channel.topic  # every channel has a real schema
            if channel.message_encoding == "json":
                assert schema.encoding == "jsonschema"
                jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            else:
                assert (channel.message_encoding, schema.encoding) == ("protobuf", "protobuf")
                decode = factory.decoder_for(channel.message_encoding, schema)
                assert decode is not None
                m = decode(message.data)
                if schema.name == "patternrl.RobotPose":
                    pose_times.append((m.step, message.log_time, message.publish_time))
                elif schema.name == "foxglove.PoseInFrame":
                    assert m.frame_id == "world"
            seen[schema.name] = seen.get(schema.name, 0) + 1
    assert {"patternrl.RobotPose", "patternrl.RobotCommand", "foxglove.PoseInFrame",
            "foxglove.FrameTransforms", "patternrl.Event", "patternrl.StepMetrics"} <= set(seen)
    assert seen["foxglove.FrameTransforms"] == 10  # one per step
    assert len(pose_times) == 30
    start = 1_700_000_000_000_000_000
    assert all(lt == start + s * 100_000_000 for s, lt, _ in pose_times)
    assert all(pt != lt for _, lt, pt in pose_times)  # the wall clock is the publish time


def test_oversized_payloads_are_refused_and_said(tmp_path: Path) -> None:
    log = tmp_path / "big.mcap"
    with Recorder(log) as rec:
        rec.write_wire(keys.cmd_key("s", 0), b"\x02\x01" + bytes(MAX_PAYLOAD_BYTES))
        rec.write_wire("patternrl/s/other", bytes(MAX_PAYLOAD_BYTES + 1))
        rec.write_wire(keys.pose_key("s", 0), encode_pose(Pose(0, 0, 0.0, 1, 1, 0, 0, 1)))
    assert log.stat().st_size < MAX_PAYLOAD_BYTES // 4
    data = read_log(log)
    refused = data.events_of("payload_refused")
    assert [(e["key"], e["bytes"]) for e in refused] == [
        (keys.cmd_key("s", 0), MAX_PAYLOAD_BYTES + 2), ("patternrl/s/other", MAX_PAYLOAD_BYTES + 1)]
    assert data.frames.ids.tolist() == [0]


def test_forged_steps_and_ids_are_skipped_and_said(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "forged.mcap"
    step = 0
    with Recorder(log) as rec:
        for step in range(5):
            for r in range(2):
                rec.write_wire(keys.pose_key("s", r), encode_pose(
                    Pose(r, step, step * 0.1, float(r), 0.0, 0.0, 0.0, 2)))
                rec.write_wire(keys.cmd_key("s", r), encode_command(
                    Command(r, step, 0.0, 0.0, "good", False, 0.0, 1.0)))
        rec.write_wire(keys.pose_key("s", 0), encode_pose(Pose(0, 2**63 + 7, 0, 1, 1, 0, 0, 2)))
        rec.write_wire(keys.pose_key("s", 70000), encode_pose(Pose(70000, 3, 0, 1, 1, 0, 0, 2)))
        rec.write_wire(keys.cmd_key("s", 0), encode_command(
            Command(0, 7 * 10**18, 0.0, 0.0, "evil", False, 0.0, 1.0)))
        rec.write_wire(keys.cmd_key("s", 9), encode_command(
            Command(9, 3, 0.0, 0.0, "evil", False, 0.0, 1.0)))
        rec.event("run_end", 5, 0.5, outcome="done", steps=5)
    data = read_log(log)
    assert data.frames.steps.tolist() == [0, 1, 2, 3, 4] and data.frames.ids.tolist() == [0, 1]
    assert set(data.commands.brain) == {"good"}
    assert data.skipped == {"poses with a step outside 0..6": 1,
                            "poses with a robot id above 65535": 1,
                            "commands with a step outside 0..6": 1,
                            "commands of robots the world never placed": 1}
    assert cli(["replay", str(log)]) == 0
    out = capsys.readouterr().out
    assert "skipped 1 commands of robots the world never placed" in out


def test_damaged_bytes_inside_a_log_are_reported_as_corrupted(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "run.mcap"
    _synthetic(log, steps=300, n=4)
    raw = bytearray(log.read_bytes())
    mid = len(raw) // 2
    raw[mid : mid + 3000] = np.random.default_rng(0).integers(0, 256, 3000, np.uint8).tobytes()
    log.write_bytes(bytes(raw))
    assert cli(["replay", str(log)]) == 1
    out = capsys.readouterr().out
    assert "log CORRUPTED" in out and "writer killed" not in out
    data = read_log(log)
    assert data.recovery.corrupted and data.recovery.messages > 0
    # a log merely cut short is still "NOT finished", exit 0
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: mid - 10])
    assert cli(["replay", str(cut)]) == 0
    assert "NOT finished" in capsys.readouterr().out


def test_another_writers_log_with_a_non_integer_step_is_one_clear_report(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "other.mcap"
    with open(log, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("patternrl.Event", "jsonschema", b"{}")
        ev = w.register_channel("/world/events", "json", sid)
        met = w.register_channel("/world/metrics", "json", sid)
        for k, obj in enumerate([{"kind": "pattern", "step": 1.5, "points": [[0, 0]]},
                                 {"kind": "run_end", "step": "x", "steps": "many"},
                                 {"kind": "pattern", "step": 0, "points": "nope",
                                  "version": 1.5}]):
            w.add_message(ev, k, json.dumps(obj).encode(), k)
        w.add_message(met, 9, b'{"step": 2.5, "formation_error_m": "x"}', 9)
        w.finish()
    assert cli(["replay", str(log)]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "skipped 2 events whose step is not an integer" in out
    assert cli(["replay", str(log), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["skipped"]
