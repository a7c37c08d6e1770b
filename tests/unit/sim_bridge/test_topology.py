"""Which Zenoh wiring a run gets: the endpoints of a router's clients, launch's ``auto`` rule."""

from __future__ import annotations

import argparse

import pytest

from runtime.net.session import Role, session_endpoints, world_port
from sim_bridge.launch.launch import PEER_MAX_ROBOTS, topology_of


@pytest.mark.parametrize("role", ["world", "robot", "tool"])
def test_a_client_connects_to_the_swarms_port_and_listens_nowhere(role: Role) -> None:
    ep = f"tls/127.0.0.1:{world_port('demo')}"
    assert session_endpoints(role, "demo", None, "tls", "client") == ([ep], [])


def test_peers_keep_the_world_listening_and_robots_connecting() -> None:
    ep = "tcp/127.0.0.1:7500"
    assert session_endpoints("world", "demo", 7500, "tcp", "peer") == ([], [ep])
    assert session_endpoints("robot", "demo", 7500, "tcp", None) == ([ep], ["tcp/127.0.0.1:0"])
    assert session_endpoints("router", "demo", 7500, "tcp", "router") == ([], [ep])


@pytest.mark.parametrize(("topology", "robots", "expected"), [
    ("auto", 1, "peer"), ("auto", PEER_MAX_ROBOTS, "peer"), ("auto", PEER_MAX_ROBOTS + 1, "router"),
    ("auto", 100, "router"), ("peer", 100, "peer"), ("router", 2, "router")])
def test_launch_auto_takes_the_mesh_for_small_teams_only(topology: str, robots: int,
                                                          expected: str) -> None:
    assert topology_of(argparse.Namespace(topology=topology, robots=robots)) == expected
