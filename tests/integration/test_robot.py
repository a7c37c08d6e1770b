"""Robot processes over real Zenoh on loopback, driven by a stub world in the test.

Every test starts real ``patternrl robot`` processes (``python -m patternrl.cli``),
connected to a :class:`StubWorld` listening on a free loopback port with multicast
scouting off, and waits on conditions with timeouts.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from support import ROOT, wait_for
from support.brains import write_test_brain
from support.stub_world import TEAM_DEADLINE, RobotProc, StubWorld

from runtime.brain.brain import RULE_ASSIGN, RuleBrain
from runtime.brain.signing import generate_key
from runtime.brain.swap import swap_brain
from runtime.decision.controller import Controller
from runtime.decision.formation import (
    assign_slots,
    collision_pairs,
    formation_error,
    slot_positions,
)
from runtime.decision.patterns import make_pattern
from runtime.decision.safety import clamp_speed
from runtime.wire import keys
from runtime.wire.messages import (
    BrainMsg,
    PatternMsg,
    Pose,
    Tag,
    encode_brain,
    encode_pattern,
    encode_pose,
)
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD


def start_team(world: StubWorld, robots: list[RobotProc], n: int, brain: str, *extra: str) -> None:
    robots.extend(RobotProc(world, i, brain, *TEAM_DEADLINE, *extra) for i in range(n))
    world.wait_alive(set(range(n)), timeout=30.0)
    for i in range(n):  # a status proves the robot's link to this world is up
        world.wait_status(i, lambda s: True, 10.0, f"first status of robot {i}")


def spread(n: int, seed: int, side: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = rng.uniform(0, side, 2)
        if all(np.linalg.norm(p - q) >= 0.3 for q in pts):
            pts.append(p)
    return np.array(pts)


def torch_mapped(pid: int) -> bool:
    maps = Path(f"/proc/{pid}/maps")
    return maps.is_file() and "torch" in maps.read_text()


# ------------------------------------------------------------------- malformed data


def malformed_payloads(rid: int, seed: int = 0) -> list[tuple[str, bytes]]:
    """(key suffix, payload) pairs that no decoder accepts, for every subscribed key."""
    rng = np.random.default_rng(seed)
    good_pose = encode_pose(Pose(rid, 5, 0.0, 1.0, 1.0, 0.0, 0.0, 4))
    nan_pose = struct.pack("<BBIQdddddI", Tag.POSE, 1, rid, 5, 0.0, float("nan"), 1.0, 0, 0, 4)
    pattern = encode_pattern(PatternMsg(1, "circle", make_pattern("circle", 4), 0.025))
    nan_pattern = bytearray(pattern)
    nan_pattern[-8:] = struct.pack("<d", float("nan"))
    dense = encode_pattern(PatternMsg(2, "dense", np.zeros((4, 2)), 0.025))  # spacing 0 < 2R
    brain = encode_brain(BrainMsg("fuzz", "{}", b"x", ()))
    out: list[tuple[str, bytes]] = [
        ("pose", b""),
        ("pose", b"\x01"),
        ("pose", good_pose[:-1]),
        ("pose", good_pose + b"\x00"),
        ("pose", bytes([Tag.COMMAND]) + good_pose[1:]),
        ("pose", bytes([Tag.POSE, 99]) + good_pose[2:]),
        ("pose", nan_pose),
        ("pose_other_id", good_pose),  # robot_id in the payload disagrees with the key
        ("pose", encode_pose(Pose(rid, 5, 0.0, 1e300, 1.0, 0.0, 0.0, 4))),  # finite, absurd
        ("pattern", pattern[:10]),
        ("pattern", bytes(nan_pattern)),
        ("pattern", dense),
        ("pattern", pattern[:2] + b"\xff" * 22),
        ("brain", brain[:7]),
        ("brain", brain[:2] + b"\xff\xff\xff\xff" + brain[6:]),
        ("brain", bytes([Tag.BRAIN, 1]) + b"\x00" * 3),
    ]
    for _ in range(15):
        key = ("pose", "pattern", "brain")[int(rng.integers(0, 3))]
        out.append((key, rng.bytes(int(rng.integers(0, 120)))))
    return out


def send_malformed(world: StubWorld, rid: int, seed: int) -> int:
    sent = 0
    for what, payload in malformed_payloads(rid, seed):
        if what == "pose":
            key = keys.pose_key(world.swarm, rid)
        elif what == "pose_other_id":
            key = keys.pose_key(world.swarm, rid + 1)
        elif what == "pattern":
            key = keys.pattern_key(world.swarm)
        else:
            key = keys.brain_key(world.swarm)
        world.put_raw(key, payload)
        sent += 1
    return sent


# ------------------------------------------------------------------------- tests


def test_robots_form_pattern_survive_fuzz_and_stop_on_sigint(
    world: StubWorld, robots: list[RobotProc]
) -> None:
    n = 4
    start_team(world, robots, n, RULE_ASSIGN)
    for r in robots:
        assert not torch_mapped(r.proc.pid), "torch loaded in a robot process"
    C = world.publish_pattern("circle", n)
    pos = spread(n, seed=3, side=2.0)
    # The pattern travels apart from the poses and may reach a robot after them: a robot
    # without a pattern holds still. Step in place until every robot acts on it.
    first = 0
    while True:
        new, cmds = world.lockstep(pos, first)
        if all((c.vx, c.vy) != (0.0, 0.0) for c in cmds.values()):
            break
        first += 1
        assert first < 20, "the pattern never reached every robot"
    # the first commands point every robot at its slot of the shared assignment
    slots = assign_slots(pos, C)
    to_slot = slot_positions(pos, C, slots) - pos
    v = np.array([[cmds[i].vx, cmds[i].vy] for i in range(n)])
    assert np.all(np.einsum("ij,ij->i", v, to_slot) > 0)
    assert collision_pairs(pos, new) == []
    err0 = formation_error(pos, C)
    pos = new
    for step in range(first + 1, first + 60):
        if step % 10 == 0:
            world.publish_pattern("circle", n)  # as a world republishes it
        new, cmds = world.lockstep(pos, step)
        v = np.array([[cmds[i].vx, cmds[i].vy] for i in range(n)])
        assert np.linalg.norm(v, axis=1).max() <= W.v_max_mps + 1e-12
        assert all(c.brain_id == RULE_ASSIGN and c.step == step for c in cmds.values())
        for c in cmds.values():  # the brain's own velocity: the command, unless filtered
            assert np.isfinite([c.brain_vx, c.brain_vy]).all()
            if not c.safety_changed:
                assert clamp_speed(c.brain_vx, c.brain_vy, W.v_max_mps) == pytest.approx(
                    (c.vx, c.vy), abs=1e-12)
        assert collision_pairs(pos, new) == []
        pos = new
    assert formation_error(pos, C) < W.formed_tol_m < err0

    # fuzz every subscribed key while the loop runs: no crash, drops counted
    before = {i: world.status[i][-1].messages_dropped for i in range(n)}
    sent = 0
    for k, step in enumerate(range(first + 60, first + 80)):
        if k < 6:
            sent += send_malformed(world, rid=k % n, seed=k)
        pos, cmds = world.lockstep(pos, step)
        assert set(cmds) == set(range(n))
    for i in range(n):
        st = world.wait_status(
            i,
            lambda s, i=i: s.messages_dropped - before[i] >= sent,
            5.0,
            f"robot {i} counting {sent} dropped messages",
        )
        assert st.errors == 0, st.last_error
        assert st.decision_latency_us_p99 > 0
        assert st.brain_id == RULE_ASSIGN
    assert formation_error(pos, C) < W.formed_tol_m  # the pattern survived the fuzz

    for r in robots:
        r.interrupt()
    for r in robots:
        rc, _, err = r.finish(timeout=10.0)
        assert rc == 0, err
        assert "Traceback" not in err
        assert "heavy_modules=none" in err
    world.wait(lambda: not world.alive, 10.0, "liveliness tokens gone")


class Stepper(threading.Thread):
    """Runs the lockstep world continuously; records every step's brains."""

    def __init__(self, world: StubWorld, pos: np.ndarray, first_step: int = 0) -> None:
        super().__init__(daemon=True)
        self.world = world
        self.pos = pos
        self.step = first_step
        self.stop = threading.Event()
        self.brains: list[dict[int, str]] = []
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            while not self.stop.is_set():
                # a generous guard against a hang, not a bound on how long a step takes
                self.pos, cmds = self.world.lockstep(self.pos, self.step, timeout=30.0)
                self.brains.append({i: c.brain_id for i, c in cmds.items()})
                self.step += 1
        except BaseException as e:  # reported by the test
            self.error = e

    def wait_steps(self, k: int, timeout: float = 120.0) -> None:  # a step may take 30 s
        target = self.step + k
        wait_for(lambda: self.step >= target or self.error, timeout, f"{k} more steps")
        assert self.error is None, self.error

    def finish(self) -> None:
        self.stop.set()
        self.join(timeout=10.0)
        assert self.error is None, self.error




def run_swap_cli(world: StubWorld, brain: str, *extra: str) -> subprocess.CompletedProcess[str]:
    cmd = [
        sys.executable,
        "-m",
        "patternrl.cli",
        "swap",
        "--swarm",
        world.swarm,
        "--brain",
        brain,
        "--connect",
        world.endpoint,
        "--insecure",
        *extra,
    ]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("batches", [False, True], ids=["per-robot poses", "all-poses message"])
def test_hot_swap_valid_and_invalid_brains_without_missing_a_step(
    world: StubWorld, robots: list[RobotProc], tmp_path: Path, batches: bool
) -> None:
    """With all poses in one message a robot decides on Zenoh's thread and hands a step
    to its loop only while a swap waits: the swaps still fall between two steps."""
    n = 3
    world.batches = batches
    start_team(world, robots, n, RULE_ASSIGN, "--pattern", "line")
    good = write_test_brain(tmp_path, "good", seed=1)
    good_id = json.loads(good.with_suffix(".json").read_text())["brain_id"]
    bad = {
        "wrong shape": (write_test_brain(tmp_path, "wide", in_dim=40), "obs_dim 40"),
        "corrupt": (write_test_brain(tmp_path, "corrupt", corrupt=True), "cannot load"),
        "nan": (write_test_brain(tmp_path, "nan", nan=True), "non-finite"),
        "digest": (write_test_brain(tmp_path, "digest", wrong_digest=True), "digest mismatch"),
        "unsigned": (write_test_brain(tmp_path, "unsigned", sign=False), "not signed"),
        "untrusted": (
            write_test_brain(tmp_path, "untrusted", sign=generate_key(tmp_path / "other")),
            "untrusted key",
        ),
    }
    stepper = Stepper(world, spread(n, seed=5, side=1.5))
    stepper.start()
    try:
        stepper.wait_steps(5)
        # a valid brain through the CLI: every robot accepts, exit 0
        r = run_swap_cli(world, str(good), "--robots", "0-2", "--timeout-s", "15")
        assert r.returncode == 0, r.stdout + r.stderr
        lines = r.stdout.strip().splitlines()
        assert lines[0].split()[:2] == ["robot", "old"] and len(lines) == 1 + n
        assert all("accepted" in line and good_id[:12] in line for line in lines[1:])
        stepper.wait_steps(3)
        assert set(stepper.brains[-1].values()) == {good_id}
        # an invalid brain through the CLI: refused, exit 1, the good brain keeps running
        wide, why = bad["wrong shape"]
        r = run_swap_cli(world, str(wide), "--timeout-s", "15", "--json")
        assert r.returncode == 1, r.stdout + r.stderr
        out = json.loads(r.stdout)
        assert not out["ok"] and len(out["robots"]) == n
        for row in out["robots"]:
            assert row["answered"] and not row["accepted"] and why in row["reason"]
            assert row["old_brain"] == row["new_brain"] == good_id
        # the other invalid brains straight from the test's session
        from runtime.brain.swap import read_brain

        for name, (path, why) in bad.items():
            manifest, data, _ = read_brain(str(path))
            ans = swap_brain(world.session, world.swarm, manifest, data, set(range(n)), 15.0)
            for a in ans.values():
                assert a.answered and not a.accepted, (name, a)
                assert why in a.reason, (name, a.reason)
                assert a.new_brain == good_id
        # and back to the rule brain
        manifest, data, _ = read_brain(RULE_ASSIGN)
        ans = swap_brain(world.session, world.swarm, manifest, data, {1}, 15.0)
        assert ans[1].accepted and ans[1].old_brain == good_id and ans[1].new_brain == RULE_ASSIGN
        stepper.wait_steps(3)
        assert stepper.brains[-1] == {0: good_id, 1: RULE_ASSIGN, 2: good_id}
        for i in range(n):  # no swap left an error (a busy machine may starve a robot of
            # poses for a second while a peer loads its brain: the watchdog's note is no error)
            st = world.wait_status(i, lambda s: s.errors == 0, 30.0, "a clean status")
            assert st.last_error == "" or st.last_error.startswith("watchdog: no pose"), (
                st.last_error)
    finally:
        stepper.finish()
    # every step got every robot's command (lockstep waited for all of them), and each
    # robot switched brain between two steps: no step without a command
    assert len(stepper.brains) == stepper.step
    assert all(set(b) == set(range(n)) for b in stepper.brains)
    for i in range(n):
        seq = [b[i] for b in stepper.brains]
        changes = [k for k in range(1, len(seq)) if seq[k] != seq[k - 1]]
        assert len(changes) == (2 if i == 1 else 1)


def test_realtime_stale_peers_watchdog_and_exit_after_silence(
    world: StubWorld, robots: list[RobotProc]
) -> None:
    robots.append(
        RobotProc(
            world,
            0,
            RULE_ASSIGN,
            "--mode",
            "realtime",
            "--rate-hz",
            "20",
            "--stale-s",
            "0.4",
            "--watchdog-s",
            "0.6",
            "--exit-after-silence-s",
            "1.5",
            "--safety",
            "off",
            "--pattern",
            "line",
        )
    )
    world.wait_alive({0}, 30.0)
    world.wait_status(0, lambda s: True, 10.0, "first status")
    pos = np.array([[0.0, 0.0], [2.0, 0.5], [1.0, 2.0]])

    def expected(team: list[int]) -> tuple[float, float]:
        c = Controller(RuleBrain(), W, None)
        p = pos[team]
        return c.decide(team.index(0), p, make_pattern("line", len(team)), 0).velocity

    def latest_cmd() -> tuple[int, tuple[float, float]] | None:
        with world.cond:
            steps = [s for s, c in world.cmds.items() if 0 in c]
            if not steps:
                return None
            c = world.cmds[max(steps)][0]
            return c.step, (c.vx, c.vy)

    def publish_until(ids: list[int], want: tuple[float, float], timeout: float) -> None:
        deadline = time.monotonic() + timeout
        step = 0
        while True:
            step += 1
            world.publish_poses(1000 + step, pos[ids], ids)
            got = latest_cmd()
            if got is not None and np.allclose(got[1], want, atol=1e-9):
                return
            assert time.monotonic() < deadline, f"no command {want} from team {ids}: {got}"
            time.sleep(0.05)  # the world's own realtime period

    three, two = expected([0, 1, 2]), expected([0, 1])
    assert not np.allclose(three, two)
    publish_until([0, 1, 2], three, 30.0)
    publish_until([0, 1], two, 30.0)  # robot 2 goes silent: stale after 0.4 s, absent
    # the world goes silent: one zero command, then the robot exits on its own
    last = latest_cmd()
    assert last is not None
    world.wait(
        lambda: any(
            c.get(0) is not None and (c[0].vx, c[0].vy) == (0.0, 0.0) for c in world.cmds.values()
        ),
        5.0,
        "the watchdog's zero command",
    )
    world.wait_status(0, lambda s: "watchdog" in s.last_error, 30.0, "watchdog in status")
    rc, _, err = robots[0].finish(timeout=10.0)
    assert rc == 0, err
    assert "world silent" in err and "Traceback" not in err


def test_bad_input_exits_2_with_one_line(tmp_path: Path) -> None:
    corrupt = write_test_brain(tmp_path, "corrupt", corrupt=True)
    cases = [
        ["robot", "--swarm", "s", "--id", "0", "--brain", str(tmp_path / "absent.onnx")],
        ["robot", "--swarm", "s", "--id", "0", "--brain", str(corrupt)],
        ["robot", "--swarm", "s", "--id", "0", "--brain", RULE_ASSIGN, "--pattern", "blob"],
        ["robot", "--swarm", "bad/name", "--id", "0", "--brain", RULE_ASSIGN],
        ["swap", "--swarm", "s", "--brain", str(tmp_path / "absent.onnx")],
        ["swap", "--swarm", "s", "--brain", RULE_ASSIGN, "--robots", "3-1"],
    ]
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "patternrl.cli", *c],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for c in cases
    ]
    for c, p in zip(cases, procs, strict=True):
        _, err = p.communicate(timeout=60)
        assert p.returncode == 2, (c, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and "error" in lines[0], (c, err)
        assert "Traceback" not in err


@pytest.mark.parametrize("spec", ["0-3,7", "1,3,5", "2"])
def test_parse_robots(spec: str) -> None:
    from runtime.brain.swap import parse_robots

    assert parse_robots(spec) == {"0-3,7": {0, 1, 2, 3, 7}, "1,3,5": {1, 3, 5}, "2": {2}}[spec]


def test_default_loopback_discovery_and_sigterm(world: StubWorld, robots: list[RobotProc]) -> None:
    """No endpoint on the command line: the robot finds the world by the swarm's port."""
    robots.append(
        RobotProc(world, 0, RULE_ASSIGN, "--pattern", "line", "--json-logs", default_endpoints=True)
    )
    world.wait_alive({0}, 30.0)
    pos = np.array([[0.0, 0.0], [1.0, 1.0]])
    world.publish_poses(0, pos)
    world.wait(lambda: 0 in world.cmds[0], 10.0, "a command over default endpoints")
    robots[0].proc.terminate()  # SIGTERM: a clean stop as well
    rc, _, err = robots[0].finish(timeout=10.0)
    assert rc == 0, err
    events = [json.loads(line)["event"] for line in err.strip().splitlines()]
    assert events[0] == "start" and events[-1] == "stop"


def test_world_port_is_derived_from_the_swarm(monkeypatch: pytest.MonkeyPatch) -> None:
    from runtime.net.session import (
        DEFAULT_BASE_PORT,
        PORT_ENV,
        session_endpoints,
        world_endpoint,
        world_port,
    )

    monkeypatch.delenv(PORT_ENV, raising=False)
    p = world_port("demo")
    assert DEFAULT_BASE_PORT <= p < DEFAULT_BASE_PORT + 1000 and p == world_port("demo")
    assert world_endpoint("demo") == f"tcp/127.0.0.1:{p}"
    assert session_endpoints("world", "demo") == ([], [f"tcp/127.0.0.1:{p}"])
    assert session_endpoints("robot", "demo") == ([f"tcp/127.0.0.1:{p}"], ["tcp/127.0.0.1:0"])
    monkeypatch.setenv(PORT_ENV, "12345")
    assert world_endpoint("demo") == "tcp/127.0.0.1:12345"


def test_a_robot_started_by_hand_leaves_when_its_world_is_gone(
    world: StubWorld, robots: list[RobotProc]
) -> None:
    robots.append(RobotProc(world, 0, RULE_ASSIGN, "--pattern", "line", "--world-timeout-s", "1"))
    world.wait_alive({0}, 30.0)
    world.publish_poses(0, np.array([[0.0, 0.0], [1.0, 0.0]]), [0, 1])
    world.wait_cmds(0, [0], 10.0)
    # the world says no more: the robot holds still, then exits with one line
    code, _, err = robots[0].finish(timeout=30.0)
    assert code == 1, err
    lines = [ln for ln in err.splitlines() if "world is gone" in ln]
    assert len(lines) == 1 and "--world-timeout-s 1" in lines[0]
    assert "Traceback" not in err


def test_a_realtime_robot_listens_to_its_own_pose_key_until_all_poses_come(
    world: StubWorld, robots: list[RobotProc]
) -> None:
    """A hundred robots each listening to every robot's pose key until their first all-poses
    message cost the swarm ten thousand messages a step: a realtime robot listens to its own
    key only (a world of per-robot poses shows itself there), and to none once all-poses
    messages come."""
    world.batches = True
    matched = {0: threading.Event(), 5: threading.Event()}
    dropped = threading.Event()
    listeners = []
    for rid in matched:
        pub = world.session.declare_publisher(keys.pose_key(world.swarm, rid))

        def on_match(status: object, rid: int = rid) -> None:
            if getattr(status, "matching", False):
                matched[rid].set()
            elif rid == 0 and matched[0].is_set():
                dropped.set()

        listeners.append((pub, pub.declare_matching_listener(on_match)))
    try:
        robots.append(RobotProc(world, 0, RULE_ASSIGN, "--mode", "realtime", "--pattern",
                                "line", "--safety", "off"))
        world.wait_alive({0}, 30.0)
        world.wait_status(0, lambda s: True, 10.0, "first status")
        assert matched[0].wait(30.0), "the robot never listened to its own pose key"
        pos = np.array([[0.0, 0.0], [2.0, 0.5]])
        for step in range(100):  # bounded: the key is dropped after the first decision
            world.publish_poses(step, pos, [0, 5])
            world.wait_cmds(step, [0])
            if dropped.wait(0.05):
                break
        assert dropped.is_set(), "its own pose key still listened to after all-poses messages"
        assert not matched[5].is_set(), "a peer's pose key was listened to"
    finally:
        for pub, listener in listeners:
            listener.undeclare()
            pub.undeclare()
