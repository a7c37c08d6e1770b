"""``patternrl replay`` on real logs: a lockstep run of real processes, and logs written here.

* A real run: ``patternrl sim`` with four ``patternrl robot --brain rule:assign``
  processes over loopback Zenoh, two patterns, recorded. Its report must agree
  with the world's own ``phase_end`` figures, and re-running rule:assign on it
  must reproduce the recorded commands.
* Logs written through the recorder API with known poses (a collision, a robot
  joining and one leaving, brain swaps, a deadline miss): the report is checked
  against figures computed here independently (brute-force assignment, travel
  summed from the positions written, overlaps found by fine sampling).
* Damaged logs: truncated at many byte offsets and cut by SIGKILL of a writer
  process; the recovered messages equal what mcap's own reader recovers, and the
  repaired copy opens with mcap's seeking reader and has a summary.
* Play-back, received by a subscriber on loopback (multicast scouting off): the
  same payload bytes on the same keys in the same order; renamed swarm; Ctrl-C.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from support import ROBOT_SILENCE_EXIT_S, ROOT, free_port, wait_for
from support.brains import write_test_brain

from patternrl.cli import main as cli
from runtime.decision.formation import lower_bounds
from runtime.decision.patterns import make_pattern
from runtime.net.session import open_session
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
from sim_bridge.log import schemas as pb
from sim_bridge.log.counterfactual import counterfactual
from sim_bridge.log.file import Recovery, iter_messages, repair
from sim_bridge.log.layout import WIRE_ENCODING, channel_kind
from sim_bridge.log.plots import phase_tracks
from sim_bridge.log.reader import read_log
from sim_bridge.log.recorder import Recorder
from sim_bridge.log.report import report_log

pytestmark = pytest.mark.timeout(120)
W = DEFAULT_WORLD
PY = sys.executable


# ----------------------------------------------------------------------- a real run


@pytest.fixture(scope="module")
def real_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A lockstep run of real processes: world + 4 rule:assign robots, circle then line."""
    d = tmp_path_factory.mktemp("real")
    log = d / "run.mcap"
    port, swarm = free_port(), f"replay{os.getpid()}"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("PATTERNRL_ZENOH_PORT", None)
    sim = subprocess.Popen(
        [PY, "-m", "patternrl.cli", "sim", "--swarm", swarm, "--robots", "4",
         "--patterns", "circle,line", "--seed", "1", "--record", str(log), "--json",
         "--zenoh-port", str(port), "--wait-robots-s", "60", "--insecure"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    robots = [subprocess.Popen(
        [PY, "-m", "patternrl.cli", "robot", "--swarm", swarm, "--id", str(i), "--brain",
         "rule:assign", "--zenoh-port", str(port), "--exit-after-silence-s",
         ROBOT_SILENCE_EXIT_S, "--insecure"],
        cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for i in range(4)]
    try:
        out, err = sim.communicate(timeout=90)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
        for r in robots:
            if r.poll() is None:
                r.send_signal(signal.SIGINT)
        for r in robots:
            try:
                r.wait(timeout=10)
            except subprocess.TimeoutExpired:
                r.kill()
                r.wait()
    assert sim.returncode == 0, err[-2000:]
    return log, json.loads(out.strip().splitlines()[-1])


def test_real_run_report_agrees_with_the_world(real_run: tuple[Path, dict[str, Any]]) -> None:
    log, result = real_run
    rep = report_log(log)
    assert rep.finished and rep.outcome == "done" and rep.mode == "lockstep"
    assert rep.robots == [0, 1, 2, 3]
    assert [p.pattern for p in rep.phases] == ["circle", "line"]
    for mine, world in zip(rep.phases, result["phases"], strict=True):
        assert mine.mismatches == []
        assert mine.formed == world["formed"] is True
        assert mine.steps == world["steps"]
        assert mine.lower_bound_steps == world["lower_bound_steps"]
        assert mine.lower_bound_travel_m == pytest.approx(world["lower_bound_travel_m"], abs=1e-5)
        assert mine.travel_m == pytest.approx(world["travel_m"], abs=1e-4)
        assert mine.collisions == world["collisions"]
        assert mine.min_separation_m == pytest.approx(world["min_separation_m"], abs=1e-5)
        assert mine.deadline_misses == world["deadline_misses"]
        assert (mine.start_step, mine.end_step) == (world["start_step"], world["end_step"])
        assert set(mine.brains) == {"rule:assign"}
        assert mine.commands_missing == world["deadline_misses"]
    # the reader reads exactly what mcap's own reader reads
    ours = [(c.topic, t, bytes(p)) for c, t, _, _, p in iter_messages(log)]
    theirs, complete = _mcap_reads(log)
    assert complete and ours == theirs and rep.messages == len(theirs)


def test_real_run_cli_table_json_and_pictures(real_run: tuple[Path, dict[str, Any]],
                                              tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    log, _ = real_run
    traj, err, gif = tmp_path / "traj.png", tmp_path / "err.png", tmp_path / "run.gif"
    assert cli(["replay", str(log), "--plot", str(traj), "--error-plot", str(err),
                "--animate", str(gif), "--max-frames", "20"]) == 0
    out = capsys.readouterr().out
    assert "circle" in out and "line" in out and "log finished" in out
    assert "agree with the world's phase_end" in out
    for p in (traj, err):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    with Image.open(gif) as im:
        assert im.format == "GIF" and 2 <= getattr(im, "n_frames", 1) <= 21
    assert cli(["replay", str(log), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["finished"] and [p["pattern"] for p in d["phases"]] == ["circle", "line"]
    assert all(p["mismatches"] == [] for p in d["phases"])


def test_counterfactual_same_brain_reproduces_other_brain_differs(
        real_run: tuple[Path, dict[str, Any]], tmp_path: Path) -> None:
    log, _ = real_run
    data = read_log(log)
    same = counterfactual(data, "rule:assign")
    n_cmds = len(set(zip(data.commands.step.tolist(), data.commands.robot_id.tolist(),
                         strict=True)))
    assert same.overall.steps == n_cmds  # every recorded command compared
    assert same.overall.max_mps < 1e-9
    assert {pi for pi, _, _ in same.per_phase} == {0, 1}
    assert {rid for (_, rid) in same.per_robot} == {0, 1, 2, 3}
    other = counterfactual(data, str(write_test_brain(tmp_path, "other", seed=3)))
    assert other.overall.steps == same.overall.steps
    assert other.overall.max_mps > 0.05 and other.overall.mean_mps > 0.01
    # without the filter, rule:assign differs exactly where the robots' filter acted
    raw = counterfactual(data, "rule:assign", safety=False)
    filtered = bool(data.commands.safety_changed.any())
    assert (raw.overall.max_mps > 1e-9) == filtered


def test_counterfactual_cli(real_run: tuple[Path, dict[str, Any]],
                            capsys: pytest.CaptureFixture[str]) -> None:
    log, _ = real_run
    assert cli(["replay", str(log), "--brain", "rule:assign", "--json"]) == 0
    cf = json.loads(capsys.readouterr().out)["counterfactual"]
    assert cf["brain"] == "rule:assign" and cf["safety"] is True
    assert cf["overall"]["max_mps"] < 1e-9
    assert [p["pattern"] for p in cf["phases"]] == ["circle", "line"]
    assert set(cf["phases"][0]["robots"]) == {"0", "1", "2", "3"}
    assert cli(["replay", str(log), "--brain", "missing.onnx"]) == 2
    assert "brain file not found" in capsys.readouterr().err


def test_compare_two_runs(real_run: tuple[Path, dict[str, Any]], tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
    log, _ = real_run
    other = tmp_path / "synthetic.mcap"
    write_synthetic(other)
    assert cli(["replay", str(log), str(other)]) == 0
    out = capsys.readouterr().out
    assert f"a: {log}" in out and f"b: {other}" in out
    assert "circle" in out and "line|line" not in out and "total: steps" in out
    assert cli(["replay", str(log), str(other), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["a"]["path"] == str(log) and d["b"]["path"] == str(other)


# ------------------------------------------------------------ logs with known poses

SWARM = "known"
Frames = list[tuple[int, dict[int, tuple[float, float]]]]


def _script() -> list[tuple[int, dict[int, tuple[float, float]]]]:
    """(step, robot -> position) of a run with a collision, a join and a leave.

    Phase 0, "line" (steps 0-10): robots 0 and 1 pass through each other (a
    collision), robot 2 drives to its slot; all reach the line at step 10.
    Phase 1, "circle" (steps 10-20): robot 3 joins at step 12, robot 2 leaves
    after step 14; the three left reach the circle at step 20.
    """
    line = make_pattern("line", 3)
    c = np.array([5.0, 5.0])
    goal0 = line - line.mean(axis=0) + c  # slots left to right: robots 1, 0, 2 end there
    start0 = {0: (4.0, 5.02), 1: (5.8, 4.98), 2: (5.0, 7.0)}
    end0 = {0: tuple(goal0[1]), 1: tuple(goal0[0]), 2: tuple(goal0[2])}
    frames = []
    for k in range(11):
        f = k / 10
        frames.append((k, {r: (start0[r][0] + f * (end0[r][0] - start0[r][0]),
                               start0[r][1] + f * (end0[r][1] - start0[r][1])) for r in start0}))
    circle3 = make_pattern("circle", 3)
    rng = np.random.default_rng(7)
    pos = dict(frames[-1][1])
    for s in range(11, 21):
        if s == 12:
            pos[3] = (7.0, 7.0)
        if s == 15:
            del pos[2]
        if s < 20:
            pos = {r: (x + float(rng.uniform(-0.05, 0.05)), y + float(rng.uniform(-0.05, 0.05)))
                   for r, (x, y) in pos.items()}
        else:
            ids = sorted(pos)
            cen = np.mean([pos[r] for r in ids], axis=0)
            slots = circle3 - circle3.mean(axis=0) + cen
            pos = {r: (float(slots[k][0]), float(slots[k][1])) for k, r in enumerate(ids)}
        frames.append((s, dict(pos)))
    return frames


def write_synthetic(path: Path, events: bool = True, chunk_size: int = 64 * 1024,
                    wrong_steps: bool = False) -> tuple[Frames, int]:
    """The script above through the recorder API, with the world's events and wire messages.

    Returns the frames and the log time of step 0 (ns); step s is 0.1 s later per step.
    """
    frames = _script()
    T0 = time.time_ns()
    line, circle3, circle4 = (make_pattern("line", 3), make_pattern("circle", 3),
                              make_pattern("circle", 4))
    with Recorder(path, chunk_size=chunk_size) as rec:
        def ev(kind: str, step: int, **kw: Any) -> None:
            if events:
                rec.event(kind, step, step * W.dt_s, **kw)

        def pattern(version: int, name: str, pts: np.ndarray, step: int, reason: str) -> None:
            rec.write_wire(keys.pattern_key(SWARM), encode_pattern(
                PatternMsg(version, name, pts, W.formed_tol_m)), T0 + step * 10**8)
            ev("pattern", step, version=version, name=name, n=len(pts), reason=reason,
               points=pts.tolist(), formed_tol_m=W.formed_tol_m)

        ev("run_start", 0, swarm=SWARM, robots=3, patterns=["line", "circle"], mode="lockstep",
           world=asdict(W))
        for r in range(3):
            ev("join", 0, robot=r)
        pattern(1, "line", line, 0, "phase")
        ev("phase_start", 0, phase=0, pattern="line", n=3)
        for step, pos in frames:
            if step == 10:
                ev("phase_end", 10, index=0, pattern="line", formed=True,
                   steps=11 if wrong_steps else 10, start_step=0, end_step=10)
                ev("brain_swap", 10, robot=0, brain="b.onnx", accepted=True, reason="ok")
                ev("brain_swap", 10, robot=1, brain="b.onnx", accepted=False, reason="shape")
                ev("brain_swap", 10, robot=2, brain="b.onnx", brain_id="b", old_brain_id="b",
                   accepted=True, reason="already running")
                pattern(2, "circle", circle3, 10, "phase")
                ev("phase_start", 10, phase=1, pattern="circle", n=3)
            if step == 12:
                ev("join", 12, robot=3)
                pattern(3, "circle", circle4, 12, "resize")
            if step == 15:
                ev("leave", 15, robot=2)
                pattern(4, "circle", circle3, 15, "resize")
            if step == 17:
                ev("deadline_miss", 17, robots=[1], missed_step=16)
            t = T0 + step * 10**8
            for r, (x, y) in sorted(pos.items()):
                rec.write_wire(keys.pose_key(SWARM, r), encode_pose(
                    Pose(r, step, step * W.dt_s, x, y, 0.0, 0.0, len(pos))), t + r)
            if step < 20:
                brain = "rule:assign" if step < 10 else "b" * 64
                for r in sorted(pos):
                    if step == 16 and r == 1:
                        continue  # the deadline miss: no command
                    rec.write_wire(keys.cmd_key(SWARM, r), encode_command(Command(
                        r, step, 0.5, 0.0, brain, r == 0, 0.1 if r == 0 else 0.0, 10.0)),
                        t + 1000 + r)
        ev("phase_end", 20, index=1, pattern="circle", formed=True, steps=10, start_step=10,
           end_step=20)
        ev("run_end", 20, outcome="done", steps=20)
    return frames, T0


def _formed_brute(P: np.ndarray, C: np.ndarray) -> bool:
    """Every robot within tolerance of its slot, for the best of all assignments (by SSE)."""
    Pc, Cc = P - P.mean(axis=0), C - C.mean(axis=0)
    best = min(itertools.permutations(range(len(P))),
               key=lambda s: sum(float(np.sum((Pc[i] - Cc[j]) ** 2)) for i, j in enumerate(s)))
    return max(math.dist(Pc[i], Cc[j]) for i, j in enumerate(best)) <= W.formed_tol_m


def _overlapping(a0: dict[int, tuple[float, float]], a1: dict[int, tuple[float, float]]
                 ) -> set[tuple[int, int]]:
    """Pairs closer than 2R at any of 200 instants of the straight move a0 -> a1."""
    ids = sorted(set(a0) & set(a1))
    out = set()
    for f in np.linspace(0.0, 1.0, 201):
        p = {r: (a0[r][0] + f * (a1[r][0] - a0[r][0]), a0[r][1] + f * (a1[r][1] - a0[r][1]))
             for r in ids}
        for i, j in itertools.combinations(ids, 2):
            if math.dist(p[i], p[j]) < W.min_separation_m - 1e-6:
                out.add((i, j))
    return out


@pytest.mark.parametrize("events", [True, False], ids=["events", "wire-only"])
def test_report_matches_independent_figures(tmp_path: Path, events: bool) -> None:
    log = tmp_path / "known.mcap"
    frames, _ = write_synthetic(log, events=events)
    rep = report_log(log)
    assert rep.finished and len(rep.phases) == 2
    patterns = {0: make_pattern("line", 3)}
    bounds = [(0, 10), (10, 20)]
    for ph, (s0, s1) in zip(rep.phases, bounds, strict=True):
        span = [(s, pos) for s, pos in frames if s0 <= s <= s1]

        def pattern_at(s: int, n: int, phase: int = ph.index) -> np.ndarray:
            return patterns[0] if phase == 0 else make_pattern("circle", n)

        formed_at = next(s for s, pos in span if _formed_brute(
            np.array([pos[r] for r in sorted(pos)]), pattern_at(s, len(pos))))
        assert ph.formed and ph.steps == formed_at - s0 == s1 - s0
        travel: dict[int, float] = {}
        for (_, a), (_, b) in itertools.pairwise(span):
            for r in set(a) & set(b):
                travel[r] = travel.get(r, 0.0) + math.dist(a[r], b[r])
        assert ph.travel_per_robot_m == pytest.approx(travel, abs=1e-6)
        assert ph.travel_m == pytest.approx(sum(travel.values()), abs=1e-5)
        seps = [math.dist(pos[i], pos[j]) for s, pos in span[1:]
                for i, j in itertools.combinations(sorted(pos), 2)]
        assert ph.min_separation_m == pytest.approx(min(seps), abs=1e-6)
        collisions, prev = 0, set[tuple[int, int]]()
        for (_, a), (_, b) in itertools.pairwise(span):
            now = _overlapping(a, b)
            collisions += len(now - prev)
            prev = now
        assert ph.collisions == collisions
        P0 = np.array([span[0][1][r] for r in sorted(span[0][1])])
        lbt, lbs = lower_bounds(P0, pattern_at(s0, len(P0)))
        assert ph.lower_bound_steps == lbs and ph.lower_bound_travel_m == pytest.approx(lbt)
    line, circle = rep.phases
    assert line.collisions == 1  # robots 0 and 1 pass through each other once
    # the pictures' paths (launch and replay draw the same): the report's phases, cut by step
    tracks = phase_tracks(rep, read_log(log))
    assert [(t.pattern, t.formed, t.steps) for t in tracks] == [("line", True, 10),
                                                                ("circle", True, 10)]
    assert tracks[0].ids == [0, 1, 2] and tracks[1].ids == [0, 1, 2, 3]
    assert tracks[1].track.shape == (11, 4, 2) and np.isnan(tracks[1].track[-1, 2]).all()
    final = np.array([frames[-1][1][r] for r in (0, 1, 3)])
    assert np.allclose(tracks[1].track[-1, [0, 1, 3]], final)
    assert np.allclose(np.sort(tracks[1].targets, axis=0), np.sort(final, axis=0))
    assert set(line.travel_per_robot_m) == {0, 1, 2}
    assert set(circle.travel_per_robot_m) == {0, 1, 2, 3}
    assert line.brains == {"rule:assign": 30} and circle.brains == {"b" * 64: 32}
    assert line.safety_interventions == 10 and circle.safety_interventions == 10
    assert circle.commands_missing == 1
    if events:
        assert (circle.joined, circle.lost) == ([3], [2])
        assert (line.joined, line.lost) == ([], [])
        assert circle.deadline_misses == 1 and line.deadline_misses == 0
        assert (circle.swaps_accepted, circle.swaps_refused, circle.swaps_unchanged) == (1, 1, 1)
        assert circle.swapped_to == ["b.onnx"]
        assert line.mismatches == [] and circle.mismatches == []
        assert rep.outcome == "done" and rep.mode == "lockstep"


def test_mismatch_with_the_world_is_reported(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "wrong.mcap"
    write_synthetic(log, wrong_steps=True)
    rep = report_log(log)
    assert rep.phases[0].mismatches == ["steps"] and rep.phases[1].mismatches == []
    assert cli(["replay", str(log)]) == 0
    assert "phase 0: differs from the world's phase_end in steps" in capsys.readouterr().out


# -------------------------------------------------------------------- damaged logs


def _mcap_reads(path: Path) -> tuple[list[tuple[str, int, bytes]], bool]:
    """What mcap's own non-seeking reader gets out of a file before it fails, and if it failed."""
    from mcap.reader import NonSeekingReader

    msgs: list[tuple[str, int, bytes]] = []
    with open(path, "rb") as f:
        it = NonSeekingReader(f).iter_messages(log_time_order=False)
        while True:
            try:
                _, ch, m = next(it)
            except StopIteration:
                return msgs, True
            except Exception:  # mcap raises McapError, struct.error, EOFError... on a cut
                return msgs, False
            msgs.append((ch.topic, m.log_time, m.data))


def _seeking_read(path: Path) -> tuple[list[tuple[str, int, bytes]], Any]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(
            log_time_order=False)]
    return msgs, summary


def test_truncated_logs_recover_what_mcap_recovers_and_repair(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    write_synthetic(full, chunk_size=600)
    data = full.read_bytes()
    everything, _ = _mcap_reads(full)
    cut = tmp_path / "cut.mcap"
    fixed = tmp_path / "fixed.mcap"
    rng = np.random.default_rng(0)
    offsets = sorted({int(x) for x in rng.integers(len(data) // 5, len(data) - 1, 12)})
    recovered_counts = []
    for off in offsets:
        cut.write_bytes(data[:off])
        theirs, complete = _mcap_reads(cut)
        assert not complete
        rec = Recovery()
        ours = [(c.topic, t, bytes(p)) for c, t, _, _, p in iter_messages(cut, rec)]
        assert ours == theirs == everything[: len(theirs)]
        assert not rec.finished and rec.error and rec.messages == len(theirs)
        rep = report_log(cut)
        assert not rep.finished and rep.messages == len(theirs)
        steps = {pb.parse(pb.ROBOT_POSE, p).step for t, _, p in theirs
                 if t.startswith("patternrl/") and _kind(t) == keys.POSE}
        assert rep.steps_recorded == len(steps)
        assert rep.recovery.bytes_read <= off == rep.recovery.file_bytes
        assert repair(cut, fixed).messages == len(theirs)
        seek, summary = _seeking_read(fixed)
        assert seek == theirs
        assert summary is not None and summary.statistics.message_count == len(theirs)
        assert report_log(fixed).finished
        recovered_counts.append(len(theirs))
    assert len(set(recovered_counts)) > 3  # the cuts fell in different chunks


WRITER = r"""
import sys, time
from runtime.wire import keys
from runtime.wire.messages import Pose, encode_pose
from sim_bridge.log.recorder import Recorder
rec = Recorder(sys.argv[1], chunk_size=2048, flush_period_s=0.02)
rec.event("run_start", 0, 0.0, swarm="kill", robots=3, mode="lockstep")
step = 0
while True:
    for r in range(3):
        rec.write_wire(keys.pose_key("kill", r), encode_pose(
            Pose(r, step, step * 0.1, float(r), step * 0.01, 0.0, 0.1, 3)))
    step += 1
    if step % 20 == 0:
        rec.flush()
        print(rec.messages_written, step, flush=True)
"""


def test_sigkilled_writer_log_is_read_and_repaired(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    log, fixed = tmp_path / "killed.mcap", tmp_path / "fixed.mcap"
    proc = subprocess.Popen([PY, "-c", WRITER, str(log)], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    try:
        assert proc.stdout is not None
        flushed = 0
        for line in proc.stdout:  # blocks on the child's output, no sleeping
            flushed = int(line.split()[0])
            if flushed >= 300:
                break
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    theirs, complete = _mcap_reads(log)
    assert not complete and len(theirs) >= flushed
    rep = report_log(log)
    assert not rep.finished and rep.messages == len(theirs)
    steps = {pb.parse(pb.ROBOT_POSE, p).step for t, _, p in theirs
             if t.startswith("patternrl/") and _kind(t) == keys.POSE}
    assert rep.outcome == "cut short" and rep.steps_recorded == len(steps) >= (flushed - 1) // 7
    assert cli(["replay", str(log), "--repair", str(fixed)]) == 0
    out = capsys.readouterr().out
    assert "NOT finished" in out and f"recovered {len(theirs)} messages" in out
    assert f"repaired copy {fixed}: {len(theirs)} messages" in out
    seek, summary = _seeking_read(fixed)
    assert seek == theirs and summary is not None
    assert summary.statistics.message_count == len(theirs)
    assert cli(["replay", str(fixed), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["finished"] and d["messages"] == len(theirs)


@pytest.mark.parametrize("content", [None, b"", b"hello, not a log\n", b"\x89MCAP0\r\n\x00\x01"],
                         ids=["missing", "empty", "text", "magic-then-junk"])
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, content: bytes | None,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    assert cli(["replay", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("patternrl replay: error: ") and "\n" not in err and str(path) in err


def test_bad_options_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "k.mcap"
    write_synthetic(log)
    for argv in ([str(log), "--plot", "x.png"], ["--rate", "2"], ["--play", "--rate", "0"],
                 ["--play", "--swarm", "bad name"], ["--play", "--topics", "nonsense"],
                 ["--animate", str(tmp_path / "x.avi")]):
        args = ["replay", str(log), *argv]
        assert cli(args) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("patternrl replay: error: ") and "\n" not in err, argv


# ------------------------------------------------------------------------ play-back


class Listener:
    """A subscriber on its own loopback endpoint, recording (key, payload) in arrival order."""

    def __init__(self, key_expr: str) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.session = open_session("peer", connect=[], listen=[self.endpoint])
        self.got: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.sub = self.session.declare_subscriber(key_expr, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))

    def count(self) -> int:
        with self.lock:
            return len(self.got)

    def close(self) -> None:
        self.sub.undeclare()  # type: ignore[no-untyped-call]
        self.session.close()  # type: ignore[no-untyped-call]


@pytest.fixture
def listener() -> Iterator[Any]:
    made: list[Listener] = []

    def make(key_expr: str) -> Listener:
        made.append(Listener(key_expr))
        return made[-1]

    yield make
    for m in made:
        m.close()


def _player(log: Path, listener: Listener, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [PY, "-m", "patternrl.cli", "replay", str(log), "--play", "--connect", listener.endpoint,
         "--listen", "tcp/127.0.0.1:0", "--wait-subscribers", "20", "--insecure", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wire(log: Path, kinds: tuple[str, ...] = ("pose", "cmd", "status", "pattern", "brain"),
          after_ns: int = 0) -> list[tuple[str, bytes]]:
    """The Zenoh messages a log stands for (protobuf channels encoded back), in file order."""
    return [(c.topic, bytes(p) if c.message_encoding == WIRE_ENCODING
             else pb.to_wire(c.schema_name, bytes(p)))
            for c, t, _, _, p in iter_messages(log)
            if channel_kind(c.topic, c.message_encoding, c.schema_name)[0] in kinds
            and t >= after_ns]


def _kind(key: str) -> str:
    k = keys.parse_key(key)
    return "" if k is None else k.kind


def test_play_back_delivers_the_recorded_bytes_in_order(
        real_run: tuple[Path, dict[str, Any]], listener: Any) -> None:
    log, _ = real_run
    expected = _wire(log)
    parsed = keys.parse_key(expected[0][0])
    assert parsed is not None
    swarm = parsed.swarm
    lis = listener(f"patternrl/{swarm}/**")
    proc = _player(log, lis, "--rate", "20")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    wait_for(lambda: lis.count() >= len(expected), 20, "every played message")
    assert lis.got == expected
    assert f"played {len(expected)} messages, 1 full loop(s)" in err


def test_play_back_renamed_swarm_topics_start_and_loops(tmp_path: Path, listener: Any) -> None:
    log = tmp_path / "known.mcap"
    write_synthetic(log)
    poses = [(keys.with_swarm(k, "other"), p) for k, p in _wire(log, ("pose",))]
    lis = listener("patternrl/other/**")
    proc = _player(log, lis, "--rate", "50", "--swarm", "other", "--topics", "pose",
                   "--loop", "2")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    wait_for(lambda: lis.count() >= 2 * len(poses), 20, "two loops of poses")
    assert lis.got == poses + poses
    # --start skips the log's first seconds; key expressions select channels
    lis2 = listener(f"patternrl/{SWARM}/**")
    proc = _player(log, lis2, "--rate", "50", "--start", "1.05", "--topics",
                   f"patternrl/{SWARM}/robot/*/cmd")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    first = next(iter(iter_messages(log)))[1]  # --start counts from the log's start
    cmds = _wire(log, ("cmd",), first + int(1.05e9))
    assert cmds and _kind(cmds[0][0]) == keys.CMD
    wait_for(lambda: lis2.count() >= len(cmds), 20, "the commands after 1.05 s")
    assert lis2.got == cmds


def test_play_back_stops_cleanly_on_ctrl_c(tmp_path: Path, listener: Any) -> None:
    log = tmp_path / "known.mcap"
    write_synthetic(log)
    lis = listener(f"patternrl/{SWARM}/**")
    proc = _player(log, lis, "--loop")  # forever, at the recorded pace
    try:
        wait_for(lambda: lis.count() >= 10, 30, "play-back to start")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert "stopped: played" in err and "Traceback" not in err


@pytest.mark.parametrize(("compression", "chunked"), [("none", True), ("lz4", True),
                                                      ("zstd", False)])
def test_reader_handles_other_writers_settings(tmp_path: Path, compression: str,
                                               chunked: bool) -> None:
    """Uncompressed and lz4 chunks, and a chunkless file, read like mcap's own reader reads."""
    from mcap.writer import CompressionType, Writer

    src, log = tmp_path / "src.mcap", tmp_path / "other.mcap"
    write_synthetic(src)
    with open(log, "wb") as f:
        w = Writer(f, chunk_size=700, compression=CompressionType[compression.upper()],
                   use_chunking=chunked)
        w.start()
        ids: dict[int, int] = {}
        for ch, t, pt, seq, payload in iter_messages(src):
            if ch.id not in ids:
                sid = w.register_schema(ch.schema_name, ch.schema_encoding, ch.schema_data) \
                    if ch.schema_id else 0
                ids[ch.id] = w.register_channel(ch.topic, ch.message_encoding, sid, ch.metadata)
            w.add_message(ids[ch.id], t, payload, pt, seq)
        w.finish()  # type: ignore[no-untyped-call]
    theirs, complete = _mcap_reads(log)
    ours = [(c.topic, t, bytes(p)) for c, t, _, _, p in iter_messages(log)]
    assert complete and ours == theirs and len(ours) == sum(1 for _ in iter_messages(src))
    a, b = report_log(src), report_log(log)
    assert b.finished and [asdict(p) for p in a.phases] == [asdict(p) for p in b.phases]


def test_to_rosbag2_is_read_back_by_rosbags_with_types_counts_and_times(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader  # the ros2 extra (the test command installs it)

    log, bag = tmp_path / "known.mcap", tmp_path / "bag"
    frames, t0 = write_synthetic(log)
    r = subprocess.run([PY, "-m", "patternrl.cli", "replay", str(log), "--to-rosbag2", str(bag),
                        "--json"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    written = json.loads(r.stdout)["rosbag2"]["topics"]
    # expected, from the script: a pose per robot and step, a command per robot and step < 20
    # but robot 1's at step 16 (the deadline miss)
    poses: dict[int, list[tuple[int, tuple[float, float]]]] = {}
    cmds: dict[int, list[int]] = {}
    for step, pos in frames:
        for rid, xy in pos.items():
            poses.setdefault(rid, []).append((step, xy))
            if step < 20 and (step, rid) != (16, 1):
                cmds.setdefault(rid, []).append(step)
    want = {f"/robot_{i}/pose": len(p) for i, p in poses.items()}
    want |= {f"/robot_{i}/cmd_vel": len(c) for i, c in cmds.items()}
    want |= {"/swarm/poses": len(frames), "/swarm/markers": len(frames)}
    assert written == want
    with AnyReader([bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types["/robot_0/pose"] == "geometry_msgs/msg/PoseStamped"
        assert types["/robot_3/cmd_vel"] == "geometry_msgs/msg/Twist"
        assert types["/swarm/poses"] == "geometry_msgs/msg/PoseArray"
        assert types["/swarm/markers"] == "visualization_msgs/msg/MarkerArray"
        assert {c.topic: c.msgcount for c in reader.connections} == want
        got: dict[str, list[Any]] = {}
        for conn, stamp, raw in reader.messages():
            got.setdefault(conn.topic, []).append((stamp, reader.deserialize(raw, conn.msgtype)))
    for rid, seq in poses.items():
        msgs = got[f"/robot_{rid}/pose"]
        for (step, (x, y)), (stamp, m) in zip(seq, msgs, strict=True):
            assert stamp == t0 + step * 10**8  # the step's simulated time
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == stamp
            assert m.header.frame_id == "world"
            assert (m.pose.position.x, m.pose.position.y) == (x, y)
    for rid, steps in cmds.items():
        tw = got[f"/robot_{rid}/cmd_vel"]
        assert [s for s, _ in tw] == [t0 + s * 10**8 for s in steps]
        assert all((m.linear.x, m.linear.y) == (0.5, 0.0) for _, m in tw)
    stamp, arr = got["/swarm/poses"][12]  # robot 3 joined at step 12: 4 robots, id order
    assert stamp == t0 + 12 * 10**8
    assert [(p.position.x, p.position.y) for p in arr.poses] == [frames[12][1][i]
                                                                for i in sorted(frames[12][1])]
    _, marks = got["/swarm/markers"][12]
    robots_m, targets_m = marks.markers
    assert (robots_m.ns, targets_m.ns) == ("robots", "targets")
    assert len(robots_m.points) == 4 and len(targets_m.points) == 4  # circle of 4 (resize)
    # a second write to the same folder is refused, in one line
    r = subprocess.run([PY, "-m", "patternrl.cli", "replay", str(log), "--to-rosbag2", str(bag)],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "exists already" in r.stderr and len(r.stderr.splitlines()) == 1
