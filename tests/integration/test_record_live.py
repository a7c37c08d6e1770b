"""A real run watched live over Foxglove's WebSocket protocol and recorded from outside.

One lockstep run of real processes (a world with ``--foxglove`` on a free loopback
port and ``--record``, ``patternrl record`` on the same swarm, three rule robots):
a WebSocket client subscribes to the scene and robot 0's pose and decodes what
arrives; the outside recording replays like the world's own log.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory
from support import ROBOT_SILENCE_EXIT_S, ROOT, free_port, wait_for

from patternrl.cli import main as cli
from sim_bridge.launch.swarm_keys import create_swarm_keys
from sim_bridge.live.foxglove_client import FoxgloveClient
from sim_bridge.log import schemas as pb
from sim_bridge.log.file import iter_messages
from sim_bridge.log.report import report_log

pytestmark = pytest.mark.timeout(180)
PY = sys.executable


class Lines:
    """A child's stream read on a thread: no pipe ever fills, lines can be waited on."""

    def __init__(self, stream: IO[str]) -> None:
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._t.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self.lines.append(line)

    def find(self, pattern: str) -> re.Match[str] | None:
        for line in list(self.lines):
            m = re.search(pattern, line)
            if m:
                return m
        return None

    def text(self) -> str:
        self._t.join(timeout=10)
        return "".join(self.lines)


def _stop(p: subprocess.Popen[str], sig: int = signal.SIGINT) -> None:
    if p.poll() is None:
        p.send_signal(sig)
    try:
        p.wait(timeout=20)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


@contextlib.contextmanager
def _telling(err: Lines) -> Iterator[None]:
    """A failure in the block says what the world printed (its warnings, its end)."""
    try:
        yield
    except (ConnectionError, TimeoutError) as e:
        raise AssertionError(f"{e}; the world said:\n{''.join(err.lines)[-3000:]}") from e


def test_live_view_and_outside_recording_of_a_running_swarm(tmp_path: Path) -> None:
    world_log, outside_log = tmp_path / "world.mcap", tmp_path / "outside.mcap"
    port, swarm = free_port(), f"live{os.getpid()}"
    keys_dir = tmp_path / "keys"  # secure by default: world, robots and recorder prove who they are
    create_swarm_keys(keys_dir, swarm, 3)
    tls = ["--tls-dir", str(keys_dir)]
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=str(ROOT))
    env.pop("PATTERNRL_ZENOH_PORT", None)
    sim = subprocess.Popen(
        [PY, "-m", "patternrl.cli", "sim", "--swarm", swarm, "--robots", "3", "--patterns",
         "line", "--seed", "2", "--record", str(world_log), "--json", "--zenoh-port", str(port),
             # the world steps on after the line forms: the viewer has the time to subscribe
             "--hold-steps", "1000",
         "--wait-robots-s", "90", "--foxglove", "127.0.0.1:0", *tls],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs: list[subprocess.Popen[str]] = [sim]
    sim_err = Lines(sim.stderr)  # type: ignore[arg-type]
    try:
        url = wait_for(lambda: sim_err.find(r"ws://127\.0\.0\.1:(\d+)"), 60, "the live URL")
        live_port = int(url.group(1))
        rec = subprocess.Popen(
            [PY, "-m", "patternrl.cli", "record", "--swarm", swarm, "--out", str(outside_log),
             "--zenoh-port", str(port), *tls],
            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        procs.append(rec)
        rec_err = Lines(rec.stderr)  # type: ignore[arg-type]
        wait_for(lambda: rec_err.find("recording swarm") or rec.poll() is not None, 60,
                 "the recorder to subscribe")
        assert rec.poll() is None, rec_err.text()
        client = FoxgloveClient("127.0.0.1", live_port)
        procs += [subprocess.Popen(
            [PY, "-m", "patternrl.cli", "robot", "--swarm", swarm, "--id", str(i), "--brain",
             "rule:assign", "--zenoh-port", str(port), "--exit-after-silence-s",
             ROBOT_SILENCE_EXIT_S, *tls],
            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)
            for i in range(3)]
        with client, _telling(sim_err):
            chans = client.wait_channels(["/world/scene", "/robot/0/pose"], 60)
            client.subscribe([chans["/world/scene"]["id"], chans["/robot/0/pose"]["id"]])
            got: dict[str, list[Any]] = {"/world/scene": [], "/robot/0/pose": []}
            pose_ch = chans["/robot/0/pose"]
            assert (pose_ch["encoding"], pose_ch["schemaName"]) == (
                "protobuf", "foxglove.PoseInFrame")
            decode = DecoderFactory().decoder_for("protobuf", Schema(
                id=1, name=pose_ch["schemaName"], encoding="protobuf",
                data=base64.b64decode(pose_ch["schema"])))
            assert decode is not None
            refused = 0
            for _attempt in range(2000):  # the world steps every few ms: messages come fast
                if min(len(v) for v in got.values()) >= 3:
                    break
                try:
                    topic, _t, data = client.next_message(1.0)
                except TimeoutError:
                    topic, data = "", b""
                # a subscription the server refused ("Unknown channel ID", seen while the
                # other topic flowed): subscribe again to what has not come, by its id now
                if len(client.statuses) > refused or not topic:
                    refused = len(client.statuses)
                    chans = client.by_topic()
                    again = [chans[t]["id"] for t in got if not got[t] and t in chans]
                    if again:
                        client.subscribe(again)
                if topic in got:
                    got[topic].append(json.loads(data) if topic == "/world/scene"
                                      else decode(data))
            assert min(len(v) for v in got.values()) >= 3, (got.keys(), client.statuses)
        scene = got["/world/scene"][-1]
        assert {"0", "1", "2"} <= {e["id"] for e in scene["entities"]}
        assert all(p.frame_id == "world" for p in got["/robot/0/pose"])
        assert sim.stdout is not None  # its stderr is Lines' to read: not communicate()'s
        out = sim.stdout.read()
        sim.wait(timeout=120)
        assert sim.returncode == 0, sim_err.text()[-2000:]
        _stop(rec)
        assert rec.returncode == 0, rec_err.text()
    finally:
        for p in procs[1:]:
            _stop(p)
        _stop(sim, signal.SIGKILL)
    result = json.loads(out.strip().splitlines()[-1])
    # lockstep: the world's log runs on simulated time, start + step x dt
    offsets = {lt - pb.parse(pb.ROBOT_POSE, data).step * 100_000_000
               for ch, lt, _pt, _seq, data in iter_messages(world_log)
               if ch.schema_name == pb.ROBOT_POSE}
    assert len(offsets) == 1
    ours, theirs = report_log(world_log), report_log(outside_log)
    assert theirs.finished and ours.finished
    assert theirs.robots == ours.robots == [0, 1, 2]
    assert [(p.pattern, p.formed) for p in theirs.phases] == [
        (p.pattern, p.formed) for p in ours.phases] == [("line", True)]
    assert theirs.phases[0].steps == ours.phases[0].steps == result["phases"][0]["steps"]
    assert theirs.last_step == ours.last_step
    # the output exists now: refused without --force, one line, exit 2
    r = subprocess.run([PY, "-m", "patternrl.cli", "record", "--swarm", swarm, "--out",
                        str(outside_log), "--zenoh-port", str(port), *tls],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "exists; pass --force" in r.stderr


@pytest.mark.parametrize("case", ["exists", "directory"])
def test_sim_record_refuses_an_existing_file_or_a_directory(
        tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "run.mcap"
    if case == "exists":
        target.write_bytes(b"keep me")
    else:
        target = tmp_path
    assert cli(["sim", "--record", str(target), "--swarm", "x", "--zenoh-port",
                str(free_port()), "--insecure"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("exists; pass --force" in err[0] or "is a directory" in err[0])
    if case == "exists":
        assert target.read_bytes() == b"keep me"


@pytest.mark.parametrize("address", ["nope:xx", "127.0.0.1:70000"])
def test_a_bad_foxglove_address_is_one_line_and_exit_2(
        address: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["sim", "--foxglove", address, "--swarm", "x", "--zenoh-port",
                str(free_port()), "--insecure"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--foxglove" in err[0]
