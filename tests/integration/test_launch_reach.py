"""``patternrl launch`` on a machine where its swarm's own port is taken: it says where its
swarm is, as flags ready to paste, and ``patternrl record`` with them records the run."""

from __future__ import annotations

import os
import shlex
import socket
import subprocess
import sys
from pathlib import Path

from support import ROOT

from runtime.net.session import world_port
from sim_bridge.log.report import report_log


def test_launch_prints_the_flags_that_reach_its_swarm_on_a_fallback_port(tmp_path: Path) -> None:
    swarm = f"reach{os.getpid()}"
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    env.pop("PATTERNRL_ZENOH_PORT", None)
    with socket.socket() as taken:  # the swarm's own port is busy: launch falls back
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        taken.bind(("127.0.0.1", world_port(swarm)))
        taken.listen()
        p = subprocess.Popen(
            [sys.executable, "-m", "patternrl.cli", "launch", "--robots", "3", "--swarm", swarm,
             "--brains", "rule:assign", "--patterns", "line,circle,cross", "--mode", "realtime",
             "--insecure", "--no-plot", "--record", str(tmp_path / "run.mcap")],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        try:
            assert p.stderr is not None
            lines = [p.stderr.readline(), p.stderr.readline()]
            reach = lines[1]
            assert "reach this swarm" in reach, lines
            flags = shlex.split(reach.split("with:", 1)[1])
            assert flags[:2] == ["--swarm", swarm] and "--zenoh-port" in flags
            assert int(flags[flags.index("--zenoh-port") + 1]) != world_port(swarm)
            out = tmp_path / "outside.mcap"
            r = subprocess.run(
                [sys.executable, "-m", "patternrl.cli", "record", *flags, "--out", str(out),
                 "--duration-s", "2"], capture_output=True, text=True, timeout=60, env=env,
                cwd=ROOT)
            assert r.returncode == 0, r.stderr
            assert report_log(out).robots == [0, 1, 2]
        finally:
            p.terminate()
            p.communicate(timeout=60)
