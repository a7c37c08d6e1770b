"""The star topology: a ``patternrl router`` process, every member its Zenoh client.

Real processes and real sessions on loopback, mutual TLS and access control on:

* the router enforces the swarm's rules on what it relays: a client holding robot
  1's certificate reaches the world with robot 1's command and token, never with
  robot 2's command, a brain, a pattern or a phantom robot (the same forgeries on
  open TCP through an open router do arrive, so the rules are what stops them);
* a client without a certificate of the swarm's authority cannot connect at all;
* an operator's brain swap (``patternrl swap``, a client) reaches robot processes
  (clients) through the router, and their answers come back to it.
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
    stop_processes,
    wait_for,
)

from runtime.net.identity import load_identity
from runtime.net.session import ZenohSetupError, make_config, open_config
from runtime.wire import keys
from sim_bridge.launch.router import RouterProcess
from sim_bridge.launch.swarm_keys import create_swarm_keys

SWARM = "star"
ROOT = Path(__file__).resolve().parents[2]
FORGED_KEYS = forged_keys(SWARM)
pytestmark = pytest.mark.timeout(180)


@pytest.fixture(scope="module")
def swarm_keys(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("keys") / SWARM
    create_swarm_keys(out, SWARM, 3)
    return out


@pytest.fixture
def router(swarm_keys: Path, tmp_path: Path) -> Iterator[RouterProcess]:
    r = RouterProcess(SWARM, free_port(), swarm_keys, tmp_path / "router.log")
    r.start()
    try:
        yield r
    finally:
        r.stop()


def client(keys_dir: Path | None, name: str | None, endpoint: str) -> zenoh.Session:
    ident = load_identity(keys_dir / name) if keys_dir is not None and name else None
    return open_config(make_config("client", [endpoint], [], identity=ident))


cmd = forged_command


def forge_then_fence(attacker: zenoh.Session, seen: Seen) -> list[object]:
    """Robot 1 forges what it has no right to, then sends its own command and token.

    One link each way through the router keeps order, so once the fence is in, every
    forgery that was going to arrive has.
    """
    hello = cmd(1, 0, "hello")

    def heard() -> bool:
        attacker.put(keys.cmd_key(SWARM, 1), hello)
        return seen.has(keys.cmd_key(SWARM, 1), hello)

    wait_for(heard, 30, "the world to hear robot 1 through the router", poll=0.05)
    return forge_and_fence(attacker, seen, SWARM, (77,))


def test_the_router_relays_robot_1s_keys_only(router: RouterProcess, swarm_keys: Path) -> None:
    with client(swarm_keys, "world", router.endpoint) as world, \
            client(swarm_keys, "robot-1", router.endpoint) as attacker:
        seen = Seen(world, SWARM)
        try:
            tokens = forge_then_fence(attacker, seen)
            assert not set(FORGED_KEYS) & seen.keys(), seen.keys()
            assert seen.alive == {"1"}  # no phantom robot 77
            for t in tokens:
                t.undeclare()  # type: ignore[attr-defined]
        finally:
            seen.close()
        # both are clients: one link each, to the router, none between them
        assert list(world.info.peers_zid()) == []
        assert [str(z) for z in world.info.routers_zid()] == \
            [str(z) for z in attacker.info.routers_zid()]


def test_an_open_router_relays_the_same_forgeries(tmp_path: Path) -> None:
    r = RouterProcess(SWARM, free_port(), None, tmp_path / "router.log")
    r.start()
    try:
        with client(None, None, r.endpoint) as world, client(None, None, r.endpoint) as attacker:
            seen = Seen(world, SWARM)
            try:
                tokens = forge_then_fence(attacker, seen)
                assert set(FORGED_KEYS) <= seen.keys()
                assert {"77", "1"} <= seen.alive
                for t in tokens:
                    t.undeclare()  # type: ignore[attr-defined]
            finally:
                seen.close()
    finally:
        r.stop()


def test_a_client_without_the_swarms_certificate_cannot_connect(
        router: RouterProcess, swarm_keys: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    create_swarm_keys(other, SWARM, 3)  # the same swarm name, another authority
    plain_tcp = router.endpoint.replace("tls/", "tcp/")
    for make in (lambda: client(other, "robot-1", router.endpoint),
                 lambda: client(None, None, plain_tcp)):
        with pytest.raises(ZenohSetupError):
            make().close()  # type: ignore[no-untyped-call]
    with client(swarm_keys, "robot-0", router.endpoint) as member:  # the router is up
        assert len(list(member.info.routers_zid())) == 1


def test_an_operators_swap_reaches_robot_clients_through_the_router(
        router: RouterProcess, swarm_keys: Path, tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.pop("PATTERNRL_ZENOH_PORT", None)
    base = [sys.executable, "-m", "patternrl.cli"]
    star = ["--tls-dir", str(swarm_keys), "--zenoh-port", str(router.port),
            "--zenoh-mode", "client"]
    procs: list[subprocess.Popen[bytes]] = []
    logs = []
    try:
        for i in range(3):
            log = open(tmp_path / f"robot{i}.log", "wb")
            logs.append(log)
            procs.append(subprocess.Popen(
                [*base, "robot", "--swarm", SWARM, "--id", str(i), "--brain",
                 str(ROOT / "exports" / "general.onnx"), "--exit-after-silence-s",
                 ROBOT_SILENCE_EXIT_S, *star],
                cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=log,
                stderr=subprocess.STDOUT, start_new_session=True))
        with client(swarm_keys, "world", router.endpoint) as world:
            seen = Seen(world, SWARM)
            try:
                wait_for(lambda: {"0", "1", "2"} <= seen.alive, 60, "three robots alive")
            finally:
                seen.close()
        swap = subprocess.run(
            [*base, "swap", "--swarm", SWARM, "--brain", "rule:assign", "--timeout-s", "30",
             "--json", *star],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=90, check=False)
        assert swap.returncode == 0, swap.stdout + swap.stderr
        out = json.loads(swap.stdout)
        assert out["ok"] and sorted(r["robot"] for r in out["robots"]) == [0, 1, 2], out
        assert all(r["accepted"] and r["new_brain"] == "rule:assign" for r in out["robots"])
    finally:
        stop_processes(procs)
        for log in logs:
            log.close()


@pytest.mark.parametrize("listen", [None, ["-l", "tls/127.0.0.1:{port}", "-l",
                                           "tls/127.0.0.1:{port2}"]])
def test_the_ready_line_names_the_endpoints(swarm_keys: Path, listen: list[str] | None) -> None:
    port, port2 = free_port(), free_port()
    extra = [x.format(port=port, port2=port2) for x in listen or []]
    proc = subprocess.Popen(
        [sys.executable, "-m", "patternrl.cli", "router", "--swarm", SWARM, "--zenoh-port",
         str(port), "--tls-dir", str(swarm_keys), *extra],
        cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.append(proc.stdout.readline()),  # type: ignore[union-attr]
                              daemon=True)
    reader.start()
    try:
        wait_for(lambda: lines or proc.poll() is not None, 60, "the router's ready line")
    finally:
        stop_processes([proc])
    want = ", ".join(f"tls/127.0.0.1:{p}" for p in ((port, port2) if listen else (port,)))
    assert lines and lines[0].rstrip("\n") == f"router ready: {want}", (lines, proc.stderr.read())  # type: ignore[union-attr]
