"""Views in the log: the recorder writes the view channel into a real MCAP file, the reader
reads it back (today's layout and the old wire one), and replay reports the estimation error
of hand-built views against the world's poses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from patternrl.cli import main as cli
from runtime.wire import keys
from runtime.wire.messages import Pose, View, encode_pose, encode_view
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log import schemas as pb
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder
from sim_bridge.log.report import report_log

W = DEFAULT_WORLD
SWARM = "s"
STEPS = 10


def truth(rid: int, step: int) -> tuple[float, float]:
    """Where robot ``rid`` is at ``step`` in the hand-built logs (metres)."""
    return 1.0 + rid + 0.05 * step, 2.0 - 0.03 * step * rid


OFFSETS = {  # (viewer, peer) -> the error of the viewer's estimate of the peer, as (dx, dy)
    (0, 1): (0.03, 0.04), (0, 2): (0.06, 0.08),
    (1, 0): (0.0, 0.2), (1, 2): (-0.12, 0.16),
    (2, 0): (0.0, 0.0), (2, 1): (0.3, -0.4),
}
VIEW_STEPS = (0, 4, 8)


def write_log(path: Path, with_views: bool = True, wire_layout: bool = False) -> None:
    with Recorder(path, wire_layout=wire_layout) as rec:
        for step in range(STEPS):
            t = step * 10**8
            for rid in range(3):
                x, y = truth(rid, step)
                rec.write_wire(keys.pose_key(SWARM, rid),
                               encode_pose(Pose(rid, step, step * W.dt_s, x, y, 0.0, 0.0, 3)), t)
            if not with_views or step not in VIEW_STEPS:
                continue
            for me in range(3):
                ids = [0, 1, 2, 7]  # robot 7 has no pose in the log: not measured
                xy = []
                for rid in ids:
                    if rid == 7:
                        xy.append((50.0, 50.0))
                    elif rid == me:
                        xy.append((truth(me, step)[0] + 5.0, 0.0))  # its own row: not measured
                    else:
                        dx, dy = OFFSETS[(me, rid)]
                        x, y = truth(rid, step)
                        xy.append((x + dx, y + dy))
                rec.write_wire(keys.view_key(SWARM, me), encode_view(
                    View(me, step, ids, np.array(xy), [1, 1, 1, 3])), t + 1)


def expected() -> tuple[dict[int, np.ndarray], np.ndarray]:
    per = {me: np.array([np.hypot(*OFFSETS[(me, p)]) for _ in VIEW_STEPS
                         for p in range(3) if p != me]) for me in range(3)}
    return per, np.concatenate([per[me] for me in range(3)])


@pytest.mark.parametrize("wire_layout", [False, True])
def test_recorder_writes_and_reader_reads_the_view_channel(tmp_path: Path,
                                                           wire_layout: bool) -> None:
    path = tmp_path / "v.mcap"
    write_log(path, wire_layout=wire_layout)
    with open(path, "rb") as f:
        channels = {c.topic: c for c in make_reader(f).get_summary().channels.values()}
    topic = keys.view_key(SWARM, 1)
    assert topic in channels
    if not wire_layout:  # any MCAP tool decodes it with the schema the log carries
        assert channels[topic].message_encoding == "protobuf"
        with open(path, "rb") as f:
            from mcap_protobuf.decoder import DecoderFactory

            msgs = [msg for _, _, _, msg in make_reader(f, decoder_factories=[DecoderFactory()])
                    .iter_decoded_messages(topics=[topic])]
        assert [int(v.step) for v in msgs] == list(VIEW_STEPS)
        assert list(msgs[0].ids) == [0, 1, 2, 7] and list(msgs[0].age_steps) == [1, 1, 1, 3]
    run = read_log(path)
    v = run.views
    assert len(v) == 3 * len(VIEW_STEPS) and run.topics[topic] == len(VIEW_STEPS)
    assert run.malformed == 0 and run.wire_layout == wire_layout
    assert v.robot_id.tolist() == [0, 1, 2] * len(VIEW_STEPS)
    assert v.step.tolist() == [s for s in VIEW_STEPS for _ in range(3)]
    assert v.start.tolist() == list(range(0, 4 * len(v) + 1, 4))
    assert v.peer[:4].tolist() == [0, 1, 2, 7] and v.age[:4].tolist() == [1, 1, 1, 3]
    x, y = truth(2, 0)
    np.testing.assert_allclose(v.xy[2], [x + 0.06, y + 0.08])


def test_views_play_back_as_the_payloads_recorded() -> None:
    msg = View(2, 9, [1, 2, 5], np.array([[0.5, 1.5], [2.0, 3.0], [-1.0, 4.25]]), [2, 0, 1])
    raw = encode_view(msg)
    assert pb.to_wire(pb.ROBOT_VIEW, pb.view_pb(msg)) == raw


def test_malformed_or_misplaced_views_are_counted_not_read(tmp_path: Path) -> None:
    path = tmp_path / "bad.mcap"
    good = View(1, 3, [0, 1], np.zeros((2, 2)), [0, 0])
    with Recorder(path) as rec:
        for step in range(2):
            rec.write_wire(keys.pose_key(SWARM, 0), encode_pose(
                Pose(0, step, 0.1 * step, 0.0, 0.0, 0.0, 0.0, 1)), step * 10**8)
        rec.write_wire(keys.view_key(SWARM, 1), b"\x07\x01junk")  # kept on /log/other
        rec.write_wire(keys.view_key(SWARM, 2), encode_view(good))  # robot 1's on 2's key
        rec.write_wire(keys.view_key(SWARM, 1), encode_view(good))
    run = read_log(path)
    assert len(run.views) == 1 and run.malformed == 2
    assert run.views.robot_id.tolist() == [1]


def test_replay_reports_the_estimation_error_of_known_offsets(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "est.mcap"
    write_log(path)
    per, everything = expected()
    est = report_log(path).estimation
    assert est is not None and est.views == 3 * len(VIEW_STEPS)
    for me, errs in per.items():
        s = est.per_robot[me]
        assert s.views == len(VIEW_STEPS) and s.peers == len(errs)
        assert s.mean_m == pytest.approx(errs.mean(), abs=1e-6)
        assert s.p95_m == pytest.approx(np.percentile(errs, 95), abs=1e-6)
        assert s.max_m == pytest.approx(errs.max(), abs=1e-6)
    o = est.overall
    assert o.max_m == pytest.approx(0.5, abs=1e-6)  # robot 2's view of robot 1: (0.3, -0.4)
    assert o.mean_m == pytest.approx(everything.mean(), abs=1e-6)
    assert o.p95_m == pytest.approx(np.percentile(everything, 95), abs=1e-6)
    assert o.peers == len(everything) and o.views == 3 * len(VIEW_STEPS)

    assert cli(["replay", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["estimation"]
    assert d["views"] == 9 and d["overall"]["max_m"] == pytest.approx(0.5)
    assert d["per_robot"]["0"]["mean_m"] == pytest.approx(0.075)  # 0.05 and 0.1 alike
    assert d["per_robot"]["1"]["max_m"] == pytest.approx(0.2)
    assert cli(["replay", str(path)]) == 0
    text = capsys.readouterr().out
    assert "estimation error (m)" in text
    last = [ln for ln in text.splitlines() if ln.startswith("all")][-1].split()
    assert last[1:3] == ["9", "18"] and float(last[5]) == pytest.approx(0.5)


def test_a_log_without_views_says_nothing_of_estimation(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "plain.mcap"
    write_log(path, with_views=False)
    run = read_log(path)
    assert len(run.views) == 0 and report_log(path).estimation is None
    assert cli(["replay", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["estimation"] is None
    assert cli(["replay", str(path)]) == 0
    assert "estimation" not in capsys.readouterr().out
