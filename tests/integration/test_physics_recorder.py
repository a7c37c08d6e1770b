"""The pymunk world (real pymunk) and the MCAP recorder (real files, a real SIGKILL)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from runtime.wire import messages as wire
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.live.scene import scene_update
from sim_bridge.log import schemas as pb
from sim_bridge.log.file import iter_messages
from sim_bridge.log.layout import EVENTS_TOPIC, METRICS_TOPIC, SCENE_TOPIC
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder
from sim_bridge.world.physics import PhysicsError, PhysicsWorld, arena_for_patterns, sample_starts

R = DEFAULT_WORLD.radius_m
ROOT = Path(__file__).resolve().parents[2]


def pairwise_min(p: np.ndarray) -> float:
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    d[np.diag_indices(len(p))] = np.inf
    return float(d.min())


# ----------------------------------------------------------------------- physics


def test_free_motion_is_exactly_p_plus_dt_v() -> None:
    w = PhysicsWorld()
    w.add_robot(3, 2.0, 2.0)
    w.add_robot(1, 7.0, 7.0)
    assert w.ids == [1, 3]
    v = np.array([[0.0, -1.0], [0.6, 0.8]])
    for _ in range(10):
        res = w.step(v)
        assert not res.substepped and not res.new_contacts
    np.testing.assert_allclose(w.positions(), [[7.0, 6.0], [2.6, 2.8]], atol=1e-9)


def test_commands_are_clamped_to_vmax() -> None:
    w = PhysicsWorld()
    w.add_robot(0, 5.0, 5.0)
    w.step(np.array([[30.0, 40.0]]))  # 50 m/s asked, v_max allowed
    np.testing.assert_allclose(w.positions()[0], [5.0 + 0.06, 5.0 + 0.08], atol=1e-9)
    w.step(np.array([[math.nan, 1.0]]))  # a non-finite command holds still on that axis
    assert np.isfinite(w.positions()).all()


def test_discs_driven_into_each_other_do_not_interpenetrate() -> None:
    w = PhysicsWorld()
    # head-on pair, a third from above, all at full speed into one point, for 4 s
    w.add_robot(0, 4.0, 5.0)
    w.add_robot(1, 6.0, 5.0)
    w.add_robot(2, 5.0, 6.5)
    v = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, -1.0]])
    closest = math.inf
    for _ in range(40):
        res = w.step(v)
        closest = min(closest, pairwise_min(res.positions))
    assert closest >= 2 * R - 0.005, closest  # 5 % of a diameter at worst
    assert w.contacts_total >= 2  # the pair met, and the third met them
    assert w.substeps_total > 0


def test_contacts_are_counted_once_per_touch() -> None:
    w = PhysicsWorld()
    w.add_robot(0, 4.0, 5.0)
    w.add_robot(1, 4.5, 5.0)
    res = [w.step(np.array([[1.0, 0.0], [0.0, 0.0]])) for _ in range(10)]  # 0 pushes 1
    assert sum(len(r.new_contacts) for r in res) == 1
    assert [c for r in res for c in r.new_contacts] == [(0, 1)]
    w.step(np.array([[-1.0, 0.0], [1.0, 0.0]]))  # part
    w.step(np.array([[-1.0, 0.0], [1.0, 0.0]]))
    again = [w.step(np.array([[1.0, 0.0], [-1.0, 0.0]])) for _ in range(5)]
    assert sum(len(r.new_contacts) for r in again) == 1
    assert w.contacts_total == 2


@pytest.mark.parametrize("v", [(-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0), (-0.7, 0.7)])
def test_walls_hold(v: tuple[float, float]) -> None:
    w = PhysicsWorld(arena_m=4.0)
    w.add_robot(0, 2.0, 2.0)
    contacts = []
    for _ in range(60):  # 6 m of pushing in a 4 m arena
        contacts += w.step(np.array([v])).new_contacts
        x, y = w.positions()[0]
        assert min(x, y, 4.0 - x, 4.0 - y) >= R - 0.005
    assert contacts and set(contacts) == {(0, "wall")}


def test_robots_join_and_leave() -> None:
    w = PhysicsWorld()
    for rid, (x, y) in enumerate([(1.0, 1.0), (2.0, 2.0), (3.0, 3.0)]):
        w.add_robot(rid, x, y)
    w.remove_robot(1)
    assert w.ids == [0, 2]
    w.add_robot(7, 8.0, 8.0)
    assert w.ids == [0, 2, 7]
    w.step(np.array([[0.0, 1.0], [0.0, 0.0], [-1.0, 0.0]]))
    np.testing.assert_allclose(w.positions(), [[1.0, 1.1], [3.0, 3.0], [7.9, 8.0]], atol=1e-9)
    with pytest.raises(PhysicsError):
        w.add_robot(7, 5.0, 5.0)
    with pytest.raises(PhysicsError):
        w.remove_robot(1)


def test_seeded_starts_are_separated_inside_and_reproducible() -> None:
    a = sample_starts(50, 10.0, np.random.default_rng(4))
    b = sample_starts(50, 10.0, np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)
    assert pairwise_min(a) >= DEFAULT_WORLD.start_separation_m
    assert (a >= R).all() and (a <= 10.0 - R).all()
    extra = sample_starts(3, 10.0, np.random.default_rng(5), avoid=a)
    assert pairwise_min(np.vstack([a, extra])) >= DEFAULT_WORLD.start_separation_m
    with pytest.raises(PhysicsError):
        sample_starts(5000, 2.0, np.random.default_rng(0))


def test_arena_grows_for_large_patterns() -> None:
    from runtime.decision.patterns import make_pattern

    assert arena_for_patterns([make_pattern("circle", 10)]) == DEFAULT_WORLD.arena_m
    big = make_pattern("circle", 500)
    side = arena_for_patterns([big])
    assert side >= 3 * np.ptp(big, axis=0).max()


# ----------------------------------------------------------------------- recorder


@pytest.mark.parametrize("old", [False, True], ids=["protobuf", "old-wire-layout"])
def test_recorder_round_trip(tmp_path: Path, old: bool) -> None:
    """Today's layout and the old one (payloads as wire bytes) read back alike."""
    path = tmp_path / "run.mcap"
    pose = wire.Pose(2, 7, 0.7, 1.5, 2.5, 0.1, -0.2, 3)
    cmd = wire.Command(2, 7, 0.3, 0.4, "abc123", False, 0.0, 12.5)
    pat = wire.PatternMsg(1, "circle", np.array([[0.0, 0.0], [0.4, 0.0]]), 0.025)
    with Recorder(path, wire_layout=old) as rec:
        rec.write_wire("patternrl/s/robot/2/pose", wire.encode(pose))
        rec.write_wire("patternrl/s/robot/2/cmd", wire.encode(cmd))
        rec.write_wire("patternrl/s/pattern", wire.encode(pat))
        rec.write_wire("patternrl/s/something/else", b"\x00raw")
        rec.event("join", 0, 0.0, robot=2, x=1.5, y=2.5)
        rec.metrics(
            {
                "step": 7,
                "time_s": 0.7,
                "n_live": 3,
                "formation_error_m": 0.5,
                "min_separation_m": 0.4,
            }
        )
        rec.scene(scene_update(10**9 + 5, [(2, 1.5, 2.5)], np.zeros((2, 2)), [4], 10.0))

    # any reader: the finished file has its summary
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        # today's layout adds the pose's PoseInFrame and its step's /tf
        assert summary.statistics.message_count == (7 if old else 9)
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
        channels = {c.topic: c.message_encoding for c in summary.channels.values()}
    pose_schema, enc = ("patternrl.Pose", "patternrl-wire") if old else (
        "patternrl.RobotPose", "protobuf")
    assert schemas[pose_schema] == enc
    assert schemas["foxglove.SceneUpdate"] == "jsonschema"
    assert schemas["patternrl.Event"] == "jsonschema"
    assert channels[SCENE_TOPIC] == "json" and channels["patternrl/s/robot/2/pose"] == enc

    data = read_log(path)
    assert data.recovery.finished and data.malformed == 0
    fr = data.frames
    assert fr.steps.tolist() == [7] and fr.ids.tolist() == [2]
    assert fr.xy[fr.row(7), 0].tolist() == [pose.x, pose.y]
    assert data.commands.robot_id.tolist() == [2] and data.commands.brain == ["abc123"]
    assert data.commands.v.tolist() == [[cmd.vx, cmd.vy]]
    assert [m.msg for m in data.patterns] == [pat]
    assert data.events == [
        {"kind": "join", "step": 0, "time_s": 0.0, "robot": 2, "x": 1.5, "y": 2.5}
    ]
    assert data.metrics[0]["formation_error_m"] == 0.5
    other = "patternrl/s/something/else"
    if old:
        assert data.topics[other] == 1
        raw = [(c, p) for c, _, _, _, p in iter_messages(path) if c.topic == other]
        assert raw[0][1] == b"\x00raw" and raw[0][0].schema_name == ""
    else:  # a foreign key's sample is kept whole on /log/other
        assert data.topics["/log/other"] == 1
        raw = [p for c, _, _, _, p in iter_messages(path) if c.topic == "/log/other"]
        sample = pb.parse(pb.RAW_SAMPLE, raw[0])
        assert (sample.key, sample.payload, sample.reason) == (other, b"\x00raw", "")
    ids, xy = fr.at(7)
    assert ids.tolist() == [2] and xy.tolist() == [[pose.x, pose.y]]
    with pytest.raises(KeyError):
        fr.at(6)
    scene = json.loads(next(p for c, _, _, _, p in iter_messages(path) if c.topic == SCENE_TOPIC))
    robot = next(e for e in scene["entities"] if e["id"] == "2")
    cyl = robot["cylinders"][0]
    assert cyl["size"]["x"] == pytest.approx(2 * R)
    assert cyl["pose"]["position"]["x"] == 1.5
    assert robot["timestamp"] == {"sec": 1, "nsec": 5}
    assert {e["id"] for e in scene["entities"]} == {"2", "targets", "arena"}
    assert scene["deletions"] == [{"timestamp": {"sec": 1, "nsec": 5}, "type": 0, "id": "4"}]


_WRITER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from runtime.wire import messages as wire
    from sim_bridge.log.recorder import Recorder
    from sim_bridge.live.scene import scene_update
    rec = Recorder(sys.argv[1], chunk_size=4096, flush_period_s=0.05)
    step = 0
    while True:
        pose = wire.Pose(0, step, step * 0.1, 1.0, float(step), 0.0, 0.0, 1)
        rec.write_wire("patternrl/k/robot/0/pose", wire.encode(pose))
        rec.event("tick", step, step * 0.1)
        rec.scene(scene_update(time.time_ns(), [(0, 1.0, float(step))], None))
        if step == 300:
            rec.flush()
            print("flushed", flush=True)
        step += 1
        time.sleep(0.0005)
    """
)


def test_sigkilled_writer_leaves_a_readable_log(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-c", _WRITER, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "flushed"  # waits for the writer, no sleep
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    data = read_log(path)
    assert not data.recovery.finished  # no footer: cut short
    steps = data.frames.steps.tolist()
    assert len(steps) >= 301  # everything up to the explicit flush, at least
    assert steps == list(range(len(steps)))  # a prefix, nothing skipped
    assert data.frames.xy[:, 0, 1].tolist() == [float(s) for s in steps]
    assert [e["step"] for e in data.events_of("tick")][:301] == list(range(301))
    assert data.topics[EVENTS_TOPIC] >= 301 and METRICS_TOPIC not in data.topics
