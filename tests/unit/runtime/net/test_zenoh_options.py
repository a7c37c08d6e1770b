"""Zenoh's own option names, --cfg, multicast scouting, and the identity checks at the edge."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import pytest

from runtime.net.session import (
    ZenohSetupError,
    add_zenoh_arguments,
    config_from_args,
    identity_from_args,
    world_port,
)
from sim_bridge.launch.swarm_keys import create_swarm_keys


def parser(with_exec_mode: bool = False) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    p.add_argument("--id", type=int, default=0)
    if with_exec_mode:  # robot and sim: --mode is lockstep/realtime
        p.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    add_zenoh_arguments(p)
    return p


@pytest.fixture(scope="module")
def keys_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("keys") / "swarm"
    create_swarm_keys(out, "s1", 3)
    return out


def test_zenoh_names_and_the_old_spellings_parse_alike() -> None:
    short = parser().parse_args(["-m", "client", "-e", "tcp/10.0.0.1:7447", "-l",
                                 "tcp/0.0.0.0:7447", "-c", "z.json5", "--insecure"])
    long = parser().parse_args(["--mode", "client", "--connect", "tcp/10.0.0.1:7447",
                                "--listen", "tcp/0.0.0.0:7447", "--config", "z.json5",
                                "--insecure"])
    old = parser().parse_args(["--zenoh-mode", "client", "--connect", "tcp/10.0.0.1:7447",
                               "--listen", "tcp/0.0.0.0:7447", "--zenoh-config", "z.json5",
                               "--insecure"])
    assert vars(short) == vars(long) == vars(old)
    assert short.zenoh_mode == "client" and short.zenoh_config == "z.json5"


def test_a_command_with_its_own_mode_keeps_it_and_takes_m() -> None:
    a = parser(with_exec_mode=True).parse_args(["--mode", "realtime", "-m", "client"])
    assert a.mode == "realtime" and a.zenoh_mode == "client"
    a = parser(with_exec_mode=True).parse_args(["--zenoh-mode", "peer"])
    assert a.mode == "lockstep" and a.zenoh_mode == "peer"


def test_cfg_and_multicast_reach_the_config() -> None:
    a = parser().parse_args(["--insecure", "--cfg", "transport/unicast/max_links:3",
                             "--cfg", 'id:"aabbccdd"', "--multicast-scouting"])
    conf = config_from_args(a, "robot", "s1")
    assert json.loads(conf.get_json("transport/unicast/max_links")) == 3
    assert json.loads(conf.get_json("id")) == "aabbccdd"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is True
    off = config_from_args(parser().parse_args(["--insecure"]), "robot", "s1")
    assert json.loads(off.get_json("scouting/multicast/enabled")) is False
    assert json.loads(off.get_json("connect/endpoints")) == [f"tcp/127.0.0.1:{world_port('s1')}"]


@pytest.mark.parametrize("item", ["nocolon", ":1", "transport/unicast/max_links:", "no/such/key:1",
                                  "transport/unicast/max_links:{bad json"])
def test_a_bad_cfg_is_one_line(item: str) -> None:
    with pytest.raises(ZenohSetupError) as e:
        config_from_args(parser().parse_args(["--insecure", "--cfg", item]), "robot", "s1")
    assert "--cfg" in str(e.value) and "\n" not in str(e.value)


def test_secure_by_default_refuses_to_run_without_an_identity() -> None:
    with pytest.raises(ZenohSetupError, match=r"no identity.*--insecure"):
        identity_from_args(parser().parse_args([]), "robot", "s1")


def test_identity_gives_tls_endpoints_and_access_rules(keys_dir: Path) -> None:
    a = parser().parse_args(["--id", "2", "--tls-dir", str(keys_dir)])
    ident = identity_from_args(a, "robot", "s1")
    assert ident is not None and ident.name == "robot-2"
    conf = config_from_args(a, "robot", "s1")
    port = world_port("s1")
    assert json.loads(conf.get_json("connect/endpoints")) == [f"tls/127.0.0.1:{port}"]
    assert json.loads(conf.get_json("listen/endpoints")) == ["tls/127.0.0.1:0"]
    tls = json.loads(conf.get_json("transport/link/tls"))
    assert tls["enable_mtls"] is True
    assert tls["connect_certificate"] == str(keys_dir.resolve() / "robot-2" / "cert.pem")
    acl = json.loads(conf.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    world = identity_from_args(parser().parse_args(["--tls-dir", str(keys_dir)]), "world", "s1")
    tool = identity_from_args(parser().parse_args(["--tls-dir", str(keys_dir)]), "tool", "s1")
    assert (world.name, tool.name) == ("world", "operator")  # type: ignore[union-attr]


@pytest.mark.parametrize("argv, role, swarm, match", [
    (["--id", "1", "--identity", "{k}/robot-2"], "robot", "s1", "cannot speak for robot 1"),
    (["--identity", "{k}/world"], "world", "other", "belongs to swarm 's1'"),
    (["--identity", "{k}/world", "--insecure"], "world", "s1", "--insecure runs without"),
    (["--identity", "{k}/world", "--tls-dir", "{k}"], "world", "s1", "not both"),
    (["--tls-dir", "{k}", "--as", "robot-99"], "tool", "s1", "not found"),
    (["--identity", "{k}/world", "-l", "tcp/0.0.0.0:7447"], "world", "s1", "not TLS"),
])
def test_identity_mistakes_are_one_line(keys_dir: Path, argv: list[str], role: str, swarm: str,
                                        match: str) -> None:
    a = parser().parse_args([x.format(k=keys_dir) for x in argv])
    with pytest.raises(ZenohSetupError, match=match) as e:
        config_from_args(a, role, swarm)  # type: ignore[arg-type]
    assert "\n" not in str(e.value)


def test_a_private_key_others_can_read_is_refused(tmp_path: Path) -> None:
    create_swarm_keys(tmp_path / "k", "s2", 1)
    key = tmp_path / "k" / "robot-0" / "key.pem"
    assert os.stat(key).st_mode & 0o777 == 0o600
    assert os.stat(tmp_path / "k" / "ca" / "ca.key").st_mode & 0o777 == 0o600
    key.chmod(0o644)
    a = parser().parse_args(["--identity", str(tmp_path / "k" / "robot-0")])
    with pytest.raises(ZenohSetupError, match="readable by others"):
        identity_from_args(a, "robot", "s2")
