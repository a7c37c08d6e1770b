"""``patternrl router``: the swarm's Zenoh router, the hub every member connects to.

    patternrl router --swarm S --tls-dir KEYS          # identity KEYS/router, mutual TLS
    patternrl router --swarm S --insecure               # open TCP on loopback

A Zenoh session in **router** mode listening on the swarm's port
(:func:`runtime.net.session.world_endpoint`: ``--zenoh-port``, else
``$PATTERNRL_ZENOH_PORT``, else derived from the swarm name), or on ``-l``
endpoints. The world, the robots and the tools then run as Zenoh **clients**
of it (``-m client``; their default endpoint is that same port), so the swarm
is a star: one link per member, however large the team, instead of the peer
mesh's link per pair (n (n - 1) / 2: 4,950 at 100 robots, each with its own
keep-alives and declarations to carry).

Security is the swarm's, unchanged: the router speaks as the ``router``
identity (mutual TLS: a member without a certificate of the swarm's authority
cannot connect) and enforces the swarm's access rules on every message it
receives, by the certificate of the link it came in on (robot i may publish
only its own ``cmd``, ``status``, ``view`` and ``alive/i``; see :mod:`runtime.net.identity`).
What it relays, its receivers accept as the router's (``router-relay`` rule).

The process holds no Python callbacks: all the routing is zenoh's own threads.
It prints one line ``router ready: <endpoints>`` on stdout once listening and
runs until SIGTERM or SIGINT (exit 0); bad options: one line on stderr, exit 2.
:class:`RouterProcess` starts one as a child process and waits for that line
(``patternrl launch --topology router``, ``benchmarks/swarm_scale.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

import zenoh

from runtime.errors import InputError
from runtime.net.session import (
    ZenohSetupError,
    add_zenoh_arguments,
    config_from_args,
    open_config,
)
from runtime.wire import keys

READY = "router ready:"
"""The first word of the line a router prints once it listens."""
ROUTER_CFG = (
    # The world's link carries every robot's command of a step at once (n messages within a
    # few ms): zenoh's default (4 batches, drop after 1 ms) lost up to half of them at 50
    # robots on a busy 2-core machine. Wait up to half a step, with room for more batches.
    "transport/link/tx/queue/congestion_control/drop/wait_before_drop:50000",
    "transport/link/tx/queue/size/data:16",
)
"""Zenoh settings of the router (``--cfg`` form, applied before the user's ``--cfg``)."""
START_TIMEOUT_S = 30.0
STOP_GRACE_S = 3.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--swarm", required=True, help="swarm name ([A-Za-z0-9_-]+)")
    add_zenoh_arguments(p)  # -m defaults to router here; --tls-dir: identity DIR/router
    p.epilog = ("Here -m defaults to router, listening on the swarm's port (--zenoh-port); "
                "with --tls-dir DIR it speaks as DIR/router. Members connect as clients: "
                "patternrl sim/robot/swap ... --zenoh-mode client (same --swarm and port).")


def listen_endpoints(conf: zenoh.Config) -> str:
    """The endpoints a config listens on, comma-separated, for the ready line."""
    try:
        # get_json answers JSON text: a list, or an object of lists per mode
        value = json.loads(conf.get_json("listen/endpoints"))
    except Exception:  # a config file without listen endpoints: zenoh's default
        value = None
    if isinstance(value, dict):
        value = value.get("router")
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        return "zenoh's default endpoints"
    return ", ".join(str(x) for x in value)


def run(args: argparse.Namespace) -> int:
    try:
        keys.validate_swarm(args.swarm)
    except ValueError as e:
        print(f"patternrl router: error: {e}", file=sys.stderr)
        return 2
    if args.zenoh_config is None:
        if args.zenoh_mode is None:
            args.zenoh_mode = "router"
        args.zenoh_cfg = [*ROUTER_CFG, *(args.zenoh_cfg or [])]
    stop = threading.Event()

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            conf = config_from_args(args, "router", args.swarm)
            session = open_config(conf)
        except ZenohSetupError as e:
            print(f"patternrl router: error: {e}", file=sys.stderr)
            return 2
        with session:
            print(f"{READY} {listen_endpoints(conf)}", flush=True)
            while not stop.wait(1.0):
                pass
        return 0
    finally:
        for s, h in old.items():
            signal.signal(s, h)


class RouterProcess:
    """A ``patternrl router`` child process: started, waited for, stopped by its PID.

    ``keys_dir`` None: open TCP (``--insecure``); else the swarm's keys directory
    (the router speaks as ``keys_dir/router``). ``group``: the process group to start
    it in (the launcher's lifeline, :mod:`sim_bridge.launch.lifeline`); None: a
    session of its own.
    """

    def __init__(self, swarm: str, port: int, keys_dir: Path | None,
                 log_path: Path | None = None, group: int | None = None) -> None:
        self.swarm, self.port, self.keys_dir = swarm, port, keys_dir
        self.log_path = log_path
        self.group = group
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def endpoint(self) -> str:
        scheme = "tcp" if self.keys_dir is None else "tls"
        return f"{scheme}/127.0.0.1:{self.port}"

    def start(self, timeout_s: float = START_TIMEOUT_S) -> None:
        """Start the router and return once it listens; InputError (one line) if it does not."""
        cmd = [sys.executable, "-m", "patternrl.cli", "router", "--swarm", self.swarm,
               "--zenoh-port", str(self.port)]
        cmd += ["--insecure"] if self.keys_dir is None else ["--tls-dir", str(self.keys_dir)]
        err = open(self.log_path, "ab") if self.log_path else subprocess.DEVNULL
        try:
            # not the caller's process group: a Ctrl-C reaches the launcher only, which
            # stops the router last
            group_kw: dict[str, Any] = ({"start_new_session": True} if self.group is None
                                        else {"process_group": self.group})
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                         stderr=err, cwd=os.getcwd(), **group_kw)
        finally:
            if self.log_path:
                err.close()  # type: ignore[union-attr]
        assert self.proc.stdout is not None
        deadline = time.monotonic() + timeout_s
        line = b""
        while time.monotonic() < deadline and self.proc.poll() is None:
            ready, _, _ = select.select([self.proc.stdout], [], [], 0.2)
            if ready:
                line = self.proc.stdout.readline()
                if line.decode(errors="replace").startswith(READY) or not line:
                    break
        if not line.decode(errors="replace").startswith(READY):
            code = self.proc.poll()
            self.stop()
            where = f"; see {self.log_path}" if self.log_path else ""
            raise InputError(f"the zenoh router did not start on {self.endpoint} "
                             f"({'exit ' + str(code) if code is not None else 'no answer'}"
                             f"{where})")

    def stop(self, grace_s: float = STOP_GRACE_S) -> None:
        """SIGTERM, then SIGKILL after ``grace_s``; a second call does nothing."""
        p, self.proc = self.proc, None
        if p is None:
            return
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        if p.stdout is not None:
            p.stdout.close()

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid
