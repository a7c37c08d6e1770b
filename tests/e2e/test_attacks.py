"""An outsider on the swarm's port: a plain Zenoh peer tries to steer a running swarm.

A real world (``patternrl sim``) and real robot processes form patterns in
lockstep on loopback while a peer of the test, with no credentials, sends what
an attacker would: a pattern of 65,536 points (1 MB), one with 1e308
coordinates, a 2-point pattern the team cannot form, a pattern version 2^64-1,
an unsigned brain, a liveliness token for a robot that does not exist, a
command on robot 0's key in robot 1's name, and malformed payloads on every
key. The swarm must do what it would have done anyway (every pattern formed, 0
collisions), and the robots' statuses and the world's log must say what was
refused.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from runtime.decision.patterns import make_pattern
from runtime.net.session import open_session
from runtime.wire import keys
from runtime.wire.messages import (
    VERSION,
    BrainMsg,
    Command,
    MessageError,
    PatternMsg,
    Tag,
    decode_pattern,
    decode_status,
    encode_brain,
    encode_command,
    encode_pattern,
)
from sim_bridge.log.reader import read_log

pytestmark = pytest.mark.timeout(180)
N = 4


def _pattern_payload(version: int, points: np.ndarray, n_claimed: int | None = None) -> bytes:
    """A pattern message as an attacker writes it: no check on what goes in."""
    n = len(points) if n_claimed is None else n_claimed
    head = struct.pack("<BBQdHI", Tag.PATTERN, VERSION, version, 0.025, 1, n)
    return head + b"x" + np.asarray(points, "<f8").tobytes()


def test_an_outsider_peer_cannot_steer_the_swarm(procs: Any, tmp_path: Path, kit: Any) -> None:
    import os

    swarm, port, log = f"e2e-attack-{os.getpid()}", kit.free_port(), tmp_path / "attack.mcap"
    # realtime at 10 Hz: the run lasts seconds of wall clock however busy the machine is, so
    # every round of attacks lands on a running swarm
    world = procs.world(swarm, port, "--robots", str(N), "--patterns", "circle,line,cross",
                        "--seed", "4", "--record", str(log), "--json", "--wait-robots-s", "60",
                        "--mode", "realtime")
    unsigned = kit.write_test_brain(tmp_path, "unsigned", sign=False)
    onnx = unsigned.read_bytes()
    manifest = unsigned.with_suffix(".json").read_text()

    peer = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"], listen=["tcp/127.0.0.1:0"])
    statuses: dict[int, dict[str, Any]] = {}
    versions: list[int] = []

    def on_status(s: zenoh.Sample) -> None:
        try:
            st = decode_status(s.payload.to_bytes())
        except MessageError:
            return
        rec = statuses.setdefault(st.robot_id, {"dropped": 0, "swaps": []})
        rec["dropped"] = max(rec["dropped"], st.messages_dropped)
        if st.swap_request_id == "evil":
            rec["swaps"].append((st.swap_accepted, st.swap_reason, st.brain_id))

    def on_pattern(s: zenoh.Sample) -> None:
        try:
            versions.append(decode_pattern(s.payload.to_bytes()).version)
        except MessageError:
            pass

    subs = [peer.declare_subscriber(keys.all_status(swarm), on_status),
            peer.declare_subscriber(keys.pattern_key(swarm), on_pattern)]
    watcher = kit.Watcher(swarm, port)
    token = None
    robots = []
    try:
        robots = [procs.robot(swarm, port, i, "--mode", "realtime")
                  for i in range(N)]
        kit.wait_for(lambda: watcher.step() >= 1 and versions, 60, "the swarm to start")
        v = max(versions)
        huge = _pattern_payload(v + 1, np.zeros((65_536, 2)))
        absurd = _pattern_payload(v + 1, np.array([[1e308, 0], [-1e308, 0], [0, 1e308],
                                                   [0, -1e308]]))
        two = encode_pattern(PatternMsg(v + 1, "two", np.array([[0.0, 0.0], [0.25, 0.0]]),
                                        0.025))
        end = _pattern_payload(2**64 - 1, make_pattern("cross", N))
        lying = _pattern_payload(v + 1, np.zeros((2, 2)), n_claimed=4096)  # claims 4096 points
        forged = encode_command(Command(1, 0, 1.0, 0.0, "evil", False, 0.0, 1.0))
        brain = encode_brain(BrainMsg("evil", manifest, onnx))
        token = peer.liveliness().declare_token(keys.alive_key(swarm, 77))
        junk = [b"", b"\x04", b"\x04\x01" + b"\xff" * 30, bytes(range(256)),
                b"\x01\x01" + bytes(56)]  # a pose of robot 0 at step 0 with no live robot
        sent_to_robots = 0
        running: list[bool] = []
        for _ in range(3):  # a few rounds while the swarm forms
            for payload in (huge, absurd, two, end, lying):
                peer.put(keys.pattern_key(swarm), payload)
                sent_to_robots += 1
            peer.put(keys.brain_key(swarm), brain)
            peer.put(keys.cmd_key(swarm, 0), forged)  # robot 1's command on robot 0's key
            for j in junk:
                for key in (keys.pattern_key(swarm), keys.pose_key(swarm, 0),
                            keys.poses_key(swarm), keys.cmd_key(swarm, 2),
                            keys.status_key(swarm, 3), keys.brain_key(swarm)):
                    peer.put(key, j)
                # the pattern and the all-poses key reach every robot (a robot stops
                # listening to the per-robot pose keys once the world's all-poses come)
                sent_to_robots += 2
            step = watcher.step()
            running.append(world.poll() is None)
            kit.wait_for(lambda s=step: watcher.step() >= s + 3 or world.poll() is not None,
                         60, "three more steps")
        kit.wait_for(lambda: len(statuses) == N and all(
            statuses[r]["dropped"] >= sent_to_robots and statuses[r]["swaps"] for r in range(N)),
            60, "every robot to count the attacks and answer the brain")
        assert running == [True] * 3  # every round reached a running swarm
        assert world.wait(timeout=120) == 0, procs.log("world")
    finally:
        if token is not None:
            token.undeclare()
        for s in subs:
            s.undeclare()
        watcher.close()
        peer.close()
    result = json.loads(procs.log("world").strip().splitlines()[-1])
    # the swarm did what it does without an attacker
    assert result["all_formed"], result
    assert [p["pattern"] for p in result["phases"]] == ["circle", "line", "cross"]
    assert all(p["collisions"] == 0 and p["n_robots"] == N for p in result["phases"])
    # every robot refused the brain (the old one kept running) and counted the rest
    for r in range(N):
        assert all(not ok and "not signed" in why and bid == "rule:assign"
                   for ok, why, bid in statuses[r]["swaps"]), statuses[r]
    run = read_log(log)
    assert all(e["robot"] != 77 for e in run.events_of("join"))
    malformed = [e["reason"] for e in run.events_of("malformed")]
    assert any("robot_id 1 on key" in m for m in malformed)  # the forged command
    patterns = run.events_of("pattern")  # only the world's own versions, 1 per phase
    assert [e["version"] for e in patterns] == [1, 2, 3]
    for r in range(N):
        text = procs.log(f"robot{r}")
        assert "Traceback" not in text, text
    assert "Traceback" not in procs.log("world")
    del robots
