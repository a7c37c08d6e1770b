"""The world and the robots on separate hosts (network namespaces), TLS and access control on.

* peer to peer across a veth link with 5 % packet loss each way (nftables);
* the same link cut for 2 s mid-run and restored;
* through a Zenoh router on a third host, world and robots on different
  subnets with no route between them (so every message goes through it).

Each run must still form with 0 collisions. Every wait is bounded; the
namespaces and processes are removed whatever happens (``net`` fixture).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import pytest
from netns_hosts import PY, ROOT, Net, cut_for, wait_for
from support import ROBOT_SILENCE_EXIT_S

from runtime.net.identity import load_identity
from runtime.net.session import make_config, open_config
from runtime.wire import keys
from runtime.wire.messages import MessageError, decode_pose
from sim_bridge.launch.swarm_keys import create_swarm_keys
from sim_bridge.log.reader import read_log
from sim_bridge.world.sim_world import WARM_UP_STEPS

ROBOTS = 3
PORT = 7447
RUN_TIMEOUT_S = 240


@pytest.fixture
def swarm(tmp_path: Path) -> tuple[str, Path]:
    name = f"netns{abs(hash(tmp_path.name)) % 100000}"
    create_swarm_keys(tmp_path / "keys", name, ROBOTS)
    return name, tmp_path / "keys"


def start_world(net: Net, ns: str, swarm: str, keys_dir: Path, log: Path,
                *zenoh: str) -> subprocess.Popen[bytes]:
    return net.patternrl(ns, "world", "sim", "--swarm", swarm, "--robots", str(ROBOTS),
                         "--patterns", "circle", "--seed", "5", "--record", str(log), "--json",
                         "--wait-robots-s", "90", "--step-deadline-ms", "400",
                         "--identity", str(keys_dir / "world"), *zenoh)


def start_robots(net: Net, ns: str, swarm: str, keys_dir: Path, *zenoh: str) -> None:
    for i in range(ROBOTS):
        net.patternrl(ns, f"robot{i}", "robot", "--swarm", swarm, "--id", str(i),
                      "--brain", "rule:assign", "--exit-after-silence-s", ROBOT_SILENCE_EXIT_S,
                      "--identity", str(keys_dir / f"robot-{i}"), *zenoh)


def finish(net: Net, world: subprocess.Popen[bytes], log: Path) -> dict[str, Any]:
    """Wait for the world's end; its JSON result, checked: formed, 0 collisions."""
    try:
        world.wait(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the world did not finish in {RUN_TIMEOUT_S} s:\n"
                             + net.log("world")[-3000:]) from None
    out = net.log("world")
    assert world.returncode == 0, out[-3000:]
    result: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    (phase,) = result["phases"]
    assert phase["formed"] and phase["collisions"] == 0, result
    run = read_log(log)
    assert run.recovery.finished
    assert sorted({e["robot"] for e in run.events_of("join")}) == list(range(ROBOTS))
    return result


def test_peer_to_peer_across_hosts_with_5_percent_loss(net: Net, swarm: tuple[str, Path],
                                                       tmp_path: Path) -> None:
    name, keys_dir = swarm
    w, r = net.host("world"), net.host("robots")
    net.link(w, "10.231.1.1", r, "10.231.1.2")
    net.loss(r, 5)  # both ways: every pose and every command crosses it
    log = tmp_path / "loss.mcap"
    world = start_world(net, w, name, keys_dir, log, "-l", f"tls/10.231.1.1:{PORT}")
    start_robots(net, r, name, keys_dir, "-e", f"tls/10.231.1.1:{PORT}")
    finish(net, world, log)
    assert net.dropped(r) > 0  # the loss was real


class StepWatcher:
    """An operator's session in this (root) namespace: the highest step of the world's poses,
    and whether the world's liveliness token has been seen (the session is connected)."""

    def __init__(self, keys_dir: Path, swarm: str, endpoint: str) -> None:
        conf = make_config("peer", [endpoint], [], identity=load_identity(keys_dir / "operator"))
        self.session = open_config(conf)
        self.step = -1
        self.world_seen = False
        self.sub = self.session.declare_subscriber(keys.all_poses(swarm), self._on)
        self.alive = self.session.liveliness().declare_subscriber(
            keys.alive_key(swarm, keys.WORLD_ID), self._on_alive, history=True)

    def _on(self, sample: Any) -> None:
        try:
            self.step = max(self.step, decode_pose(sample.payload.to_bytes()).step)
        except MessageError:
            pass

    def _on_alive(self, sample: Any) -> None:
        self.world_seen = True

    def close(self) -> None:
        self.alive.undeclare()
        self.sub.undeclare()
        self.session.close()


def test_link_cut_for_2_s_and_restored(net: Net, swarm: tuple[str, Path],
                                       tmp_path: Path) -> None:
    name, keys_dir = swarm
    w, r = net.host("world"), net.host("robots")
    _, robots_end = net.link(w, "10.231.1.1", r, "10.231.1.2")
    # a second link from this namespace to the world's, to watch the run's steps
    root_end, w_end = f"{net.tag}o"[-15:], f"{net.tag}p"[-15:]
    subprocess.run(["ip", "link", "add", root_end, "type", "veth", "peer", "name", w_end],
                   check=True, timeout=30)
    subprocess.run(["ip", "link", "set", w_end, "netns", w], check=True, timeout=30)
    subprocess.run(["ip", "addr", "add", "10.231.9.1/24", "dev", root_end], check=True,
                   timeout=30)
    subprocess.run(["ip", "link", "set", root_end, "up"], check=True, timeout=30)
    subprocess.run(["ip", "-n", w, "addr", "add", "10.231.9.2/24", "dev", w_end], check=True,
                   timeout=30)
    subprocess.run(["ip", "-n", w, "link", "set", w_end, "up"], check=True, timeout=30)
    log = tmp_path / "cut.mcap"
    # the world steps on 300 steps after the circle forms (in about 40): the cut falls within
    # the run even when a busy machine delays the watcher by tens of steps
    world = start_world(net, w, name, keys_dir, log, "-l", f"tls/10.231.1.1:{PORT}",
                        "-l", f"tls/10.231.9.2:{PORT}", "--hold-steps", "300")
    # the watcher is connected before any robot starts, so the world (waiting for its robots)
    # cannot run ahead of it however busy the machine is
    watcher = StepWatcher(keys_dir, name, f"tls/10.231.9.2:{PORT}")
    try:
        wait_for(lambda: watcher.world_seen or world.poll() is not None, 120,
                 "the watcher to see the world", poll=0.05)
        assert world.poll() is None, net.log("world")[-3000:]
        start_robots(net, r, name, keys_dir, "-e", f"tls/10.231.1.1:{PORT}")
        # cut as soon as the run's first steps (which wait for every robot) are done: a
        # 3-robot circle needs tens of steps, a few at most have gone by
        wait_for(lambda: watcher.step >= WARM_UP_STEPS or world.poll() is not None, 120,
                 "the world to start stepping", poll=0.01)
        assert world.poll() is None, net.log("world")[-3000:]
        cut_at = watcher.step
        cut_for(net, r, robots_end, 2.0).join(timeout=30)
        wait_for(lambda: watcher.step >= cut_at + 5 or world.poll() is not None, 60,
                 "steps after the link came back", poll=0.05)
    finally:
        watcher.close()
    result = finish(net, world, log)
    # the cut bit: steps went by without the robots' commands
    assert result["phases"][0]["deadline_misses"] >= 1, result


def test_through_a_router_on_a_third_host(net: Net, swarm: tuple[str, Path],
                                          tmp_path: Path) -> None:
    name, keys_dir = swarm
    w, rt, r = net.host("world"), net.host("router"), net.host("robots")
    net.link(w, "10.231.1.1", rt, "10.231.1.2")
    net.link(r, "10.231.2.1", rt, "10.231.2.2")  # no route from robots to world but rt
    router = net.run(rt, "router", PY, str(ROOT / "tests" / "netns" / "zenoh_router.py"),
                     str(keys_dir / "router"), f"tls/0.0.0.0:{PORT}")
    wait_for(lambda: "ready" in net.log("router") or router.poll() is not None, 60,
             "the router to listen")
    assert router.poll() is None, net.log("router")
    log = tmp_path / "router.mcap"
    world = start_world(net, w, name, keys_dir, log, "-m", "client",
                        "-e", f"tls/10.231.1.2:{PORT}", "-l", "tls/10.231.1.1:0")
    start_robots(net, r, name, keys_dir, "-m", "client", "-e", f"tls/10.231.2.2:{PORT}",
                 "-l", "tls/10.231.2.1:0")
    finish(net, world, log)
    assert router.poll() is None  # it carried the whole run
