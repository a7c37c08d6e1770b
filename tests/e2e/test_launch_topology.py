"""``patternrl launch --topology router|peer``: both wirings form a pattern, as a user runs them.

The router topology (the default) starts ``patternrl router`` and makes the world and
every robot its Zenoh clients; the peer topology makes every process a peer of the
world's listener. Each run must form with 0 collisions and stop every process it
started (the router included: nothing listens on its port afterwards).
"""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.timeout(300)


def launch(tmp_path: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("PATTERNRL_ZENOH_PORT", None)
    return subprocess.run(
        [sys.executable, "-m", "patternrl.cli", "launch", "--patterns", "circle", "--no-plot",
         "--json", "--record", str(tmp_path / "run.mcap"), *argv],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=280, check=False)


def port_in_use(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.parametrize(("topology", "security"), [("router", ()), ("router", ("--insecure",)),
                                                    ("peer", ("--insecure",))])
def test_launch_forms_with_either_topology(tmp_path: Path, topology: str,
                                           security: tuple[str, ...]) -> None:
    proc = launch(tmp_path, "--robots", "5", "--mode", "realtime", "--topology", topology,
                  "--swarm", f"topo{os.getpid()}", *security)
    assert proc.returncode == 0, proc.stderr[-3000:]
    hub = "router" if topology == "router" else "world, peers"
    found = re.search(rf"zenoh {hub} (tcp|tls)/127\.0\.0\.1:(\d+)", proc.stderr)
    assert found, proc.stderr[-2000:]
    assert found.group(1) == ("tcp" if security else "tls")
    port = int(found.group(2))
    (phase,) = json.loads(proc.stdout.strip().splitlines()[-1])["phases"]
    assert phase["formed"] and phase["collisions"] == 0, phase
    assert not port_in_use(port)  # the router (or the world) is gone with the run


def test_router_topology_refuses_the_worlds_own_endpoints(tmp_path: Path) -> None:
    proc = launch(tmp_path, "--robots", "2", "--insecure", "--topology", "router",
                  "-e", "tcp/127.0.0.1:7447")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("patternrl launch: error: ")
    assert "--topology peer" in proc.stderr and "Traceback" not in proc.stderr
