"""Mutual TLS and access control on loopback, with real Zenoh sessions and real processes.

A peer without a certificate (or with one from another authority) never joins;
a peer holding robot 1's certificate can publish robot 1's keys and nothing
else: the world never sees its forged commands for robot 2, its brain, its
pattern or a phantom robot's liveliness. The same forgeries on open TCP do
arrive, so the tests would notice rules that let them through.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from support import (
    ROBOT_SILENCE_EXIT_S,
    Seen,
    forge_and_fence,
    forged_command,
    forged_keys,
    free_port,
    wait_for,
)

from runtime.net.identity import load_identity
from runtime.net.session import make_config, open_config
from runtime.wire import keys
from sim_bridge.launch.swarm_keys import create_swarm_keys
from sim_bridge.log.reader import read_log

SWARM = "sec"
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def swarm_keys(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("keys") / "sec"
    create_swarm_keys(out, SWARM, 3)
    return out


def session(keys_dir: Path | None, name: str | None, connect: list[str],
            listen: list[str]) -> zenoh.Session:
    ident = load_identity(keys_dir / name) if keys_dir is not None and name else None
    return open_config(make_config("peer", connect, listen, identity=ident))


cmd = forged_command
FORGED_KEYS = forged_keys(SWARM)


def attack_and_fence(attacker: zenoh.Session, seen: Seen) -> list[object]:
    """Robot 1 forges what it has no right to, the world's liveliness token among them."""
    return forge_and_fence(attacker, seen, SWARM, (77, keys.WORLD_ID))


def join(attacker: zenoh.Session, seen: Seen) -> None:
    """Wait until the world hears the attacker at all (its own key, step 0)."""
    hello = cmd(1, 0, "hello")

    def heard() -> bool:
        attacker.put(keys.cmd_key(SWARM, 1), hello)
        return seen.has(keys.cmd_key(SWARM, 1), hello)

    wait_for(heard, 30, "the world to hear robot 1", poll=0.05)


@pytest.fixture
def tls_world(swarm_keys: Path) -> Iterator[tuple[zenoh.Session, Seen, str]]:
    ep = f"tls/127.0.0.1:{free_port()}"
    s = session(swarm_keys, "world", [], [ep])
    seen = Seen(s, SWARM)
    try:
        yield s, seen, ep
    finally:
        seen.close()
        s.close()  # type: ignore[no-untyped-call]


def test_robot_1s_certificate_publishes_robot_1s_keys_only(
        tls_world: tuple[zenoh.Session, Seen, str], swarm_keys: Path) -> None:
    _, seen, ep = tls_world
    with session(swarm_keys, "robot-1", [ep], ["tls/127.0.0.1:0"]) as attacker:
        join(attacker, seen)
        tokens = attack_and_fence(attacker, seen)
        assert not set(FORGED_KEYS) & seen.keys(), seen.keys()
        assert seen.alive == {"1"}  # no phantom robot 77, no second world
        for t in tokens:
            t.undeclare()  # type: ignore[attr-defined]


def test_the_operator_puts_its_patterns_on_its_own_key_never_on_the_worlds(
        tls_world: tuple[zenoh.Session, Seen, str], swarm_keys: Path) -> None:
    """Only the world speaks on the pattern key: that is what keeps an operator's pattern
    from locking out the world's next phase (runtime/decision/team_pattern.py)."""
    _, seen, ep = tls_world
    with session(swarm_keys, "operator", [ep], ["tls/127.0.0.1:0"]) as op:
        mine = keys.operator_pattern_key(SWARM)

        def heard(payload: bytes) -> bool:
            op.put(keys.pattern_key(SWARM), payload)  # refused, whenever it is put
            op.put(mine, payload)
            return seen.has(mine, payload)

        wait_for(lambda: heard(b"operator-pattern"), 30, "the operator's pattern", poll=0.05)
        assert keys.pattern_key(SWARM) not in seen.keys(), seen.keys()


def test_a_robot_that_agrees_hears_robot_1s_own_slots_never_its_forged_ones(
        swarm_keys: Path) -> None:
    """``robot --agree`` takes its peers' slots: its session enforces every robot's rules
    (:func:`runtime.net.identity.apply_identity`), so robot 1's certificate reaches it on
    robot 1's slots key and never on robot 2's. With the robot's own file's rules (the roles
    only) it would hear no robot at all."""
    from runtime.wire.messages import Slots, encode_slots

    ep = f"tls/127.0.0.1:{free_port()}"
    ident = load_identity(swarm_keys / "robot-0")
    with open_config(make_config("peer", [], [ep], identity=ident, hears_robots=True)) as r0:
        seen = Seen(r0, SWARM)
        try:
            with session(swarm_keys, "robot-1", [ep], ["tls/127.0.0.1:0"]) as attacker:
                own = encode_slots(Slots(1, 5, 1, 0))
                forged = encode_slots(Slots(2, 5, 1, 1))

                def heard() -> bool:
                    attacker.put(keys.slots_key(SWARM, 2), forged)  # refused each time
                    attacker.put(keys.slots_key(SWARM, 1), own)  # after it: the fence
                    return seen.has(keys.slots_key(SWARM, 1), own)

                wait_for(heard, 30, "robot 0 to hear robot 1's slots", poll=0.05)
                assert keys.slots_key(SWARM, 2) not in seen.keys(), seen.keys()
        finally:
            seen.close()


def test_on_open_tcp_the_same_forgeries_arrive() -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    with session(None, None, [], [ep]) as w, session(None, None, [ep], []) as attacker:
        seen = Seen(w, SWARM)
        try:
            join(attacker, seen)
            tokens = attack_and_fence(attacker, seen)
            assert set(FORGED_KEYS) <= seen.keys()
            assert {"77", "world", "1"} <= seen.alive
            for t in tokens:
                t.undeclare()  # type: ignore[attr-defined]
        finally:
            seen.close()


def test_a_peer_without_the_swarms_certificate_never_joins(
        tls_world: tuple[zenoh.Session, Seen, str], swarm_keys: Path, tmp_path: Path) -> None:
    w, seen, ep = tls_world
    other = tmp_path / "other"
    create_swarm_keys(other, SWARM, 3)  # the same swarm name, another authority
    no_cert = make_config("peer", [ep], [])  # TLS trusting the right authority, no certificate
    no_cert.insert_json5("transport/link/tls/root_ca_certificate",
                         json.dumps(str(swarm_keys / "ca" / "ca.pem")))
    no_cert.insert_json5("transport/link/tls/verify_name_on_connect", "false")
    outsiders = [session(None, None, [ep.replace("tls/", "tcp/")], []),  # plain TCP
                 open_config(no_cert),
                 session(other, "robot-1", [ep], ["tls/127.0.0.1:0"])]
    try:
        for s in outsiders:
            for step in range(5):
                s.put(keys.cmd_key(SWARM, 1), cmd(1, step))
                s.put(keys.brain_key(SWARM), b"forged")
        # a member that joins after them is heard: the world was listening all along
        with session(swarm_keys, "robot-1", [ep], ["tls/127.0.0.1:0"]) as member:
            join(member, seen)
            for s in outsiders:  # whatever they sent before is in by now (or never comes)
                s.put(keys.cmd_key(SWARM, 1), cmd(1, 5))
            attack_and_fence(member, seen)
            assert [str(z) for z in w.info.peers_zid()] == [str(member.info.zid())]
        assert all(not list(s.info.peers_zid()) for s in outsiders)
        forged = [p for k, p in seen.samples if k == keys.cmd_key(SWARM, 1)
                  and p not in (cmd(1, 0, "hello"), cmd(1, 999, "fence"))]
        assert forged == [] and keys.brain_key(SWARM) not in seen.keys()
    finally:
        for s in outsiders:
            s.close()  # type: ignore[no-untyped-call]


def test_a_swarm_with_certificates_forms_while_robot_1s_key_forges(
        swarm_keys: Path, tmp_path: Path) -> None:
    """Real sim and robot processes with their identities; robot 1's key held by an attacker."""
    port, log = free_port(), tmp_path / "sec.mcap"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("PATTERNRL_ZENOH_PORT", None)
    base = [sys.executable, "-m", "patternrl.cli"]
    tls = ["--tls-dir", str(swarm_keys), "--zenoh-port", str(port)]
    sim = subprocess.Popen(
        [*base, "sim", "--swarm", SWARM, "--robots", "3", "--patterns", "circle", "--seed", "3",
         "--record", str(log), "--json", "--wait-robots-s", "60", *tls],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    robots = [subprocess.Popen(
        [*base, "robot", "--swarm", SWARM, "--id", str(i), "--brain", "rule:assign",
         "--exit-after-silence-s", ROBOT_SILENCE_EXIT_S, *tls],
        cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for i in range(3)]
    stop = threading.Event()
    attacker = session(swarm_keys, "robot-1", [f"tls/127.0.0.1:{port}"], ["tls/127.0.0.1:0"])

    def forge() -> None:  # about 20 forgeries a second for the whole run, bounded
        tokens = [attacker.liveliness().declare_token(keys.alive_key(SWARM, 77))]
        for step in range(3000):
            if stop.wait(0.05):
                break
            attacker.put(keys.cmd_key(SWARM, 2), cmd(2, step))
            attacker.put(keys.brain_key(SWARM), b"forged")
            attacker.put(keys.pattern_key(SWARM), b"forged")
        for t in tokens:
            t.undeclare()  # type: ignore[no-untyped-call]

    forger = threading.Thread(target=forge, daemon=True)
    forger.start()
    try:
        out, err = sim.communicate(timeout=150)
    finally:
        stop.set()
        forger.join(timeout=10)
        attacker.close()  # type: ignore[no-untyped-call]
        for p in (sim, *robots):
            if p.poll() is None:
                p.kill()
            p.wait(timeout=10)
    assert sim.returncode == 0, err[-2000:]
    result = json.loads(out.strip().splitlines()[-1])
    assert result["all_formed"] and result["phases"][0]["collisions"] == 0, result
    run = read_log(log)
    assert "forged" not in run.commands.brain_ids
    assert [e["robot"] for e in run.events_of("join")] == [0, 1, 2]  # no phantom 77
    assert run.topics.get(keys.brain_key(SWARM), 0) == 0
