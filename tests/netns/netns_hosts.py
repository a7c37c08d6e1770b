"""Hosts made of Linux network namespaces: veth links, packet loss, link cuts, processes.

Each test gets a :class:`Net` that creates its namespaces (``ip netns add``), joins
them with veth pairs on private 10.231.x.0/24 subnets, runs processes inside them
(``ip netns exec``) and, whatever happens, stops every process it started by PID
and deletes every namespace it made (which deletes their veth ends too).

Needs root, ``ip`` (iproute2) and ``nft`` (nftables): scripts/test.sh installs the
last two. Without them the tests fail with the reason: they stand for the
cross-host guarantees and are never skipped.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from support import stop_processes  # noqa: E402
from support import wait_for as wait_for  # noqa: E402

PY = sys.executable


def _sh(*argv: str) -> None:
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30, check=False)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: {r.stderr.strip() or r.returncode}")


def _walk(obj: Any) -> Iterator[dict[str, Any]]:
    """Every dict inside a JSON value."""
    if isinstance(obj, dict):
        yield obj
        for v in obj.values():
            yield from _walk(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _walk(v)


def require_network_tools() -> None:
    """Fail (never skip) with what is missing to build namespaces here."""
    if os.geteuid() != 0:
        pytest.fail("network namespace tests need root (CI runs as root)")
    for tool, pkg in (("ip", "iproute2"), ("nft", "nftables")):
        if shutil.which(tool) is None:
            pytest.fail(f"'{tool}' not found: install {pkg} (scripts/test.sh does it as root)")


class Net:
    """Namespaces, links and processes of one test; :meth:`close` undoes all of it."""

    def __init__(self, tmp: Path) -> None:
        self.tag = f"pr{os.getpid() % 100000}{int(time.monotonic() * 1000) % 1000}"
        self.tmp = tmp
        self.namespaces: list[str] = []
        self.procs: list[subprocess.Popen[bytes]] = []
        self._links = 0

    def host(self, name: str) -> str:
        """A new namespace with loopback up; returns its name."""
        ns = f"{self.tag}-{name}"
        _sh("ip", "netns", "add", ns)
        self.namespaces.append(ns)
        _sh("ip", "-n", ns, "link", "set", "lo", "up")
        return ns

    def link(self, a: str, a_addr: str, b: str, b_addr: str) -> tuple[str, str]:
        """A veth pair between namespaces a and b, addresses with their /24; its two ends."""
        self._links += 1
        ea, eb = f"{self.tag}a{self._links}"[-15:], f"{self.tag}b{self._links}"[-15:]
        _sh("ip", "link", "add", ea, "type", "veth", "peer", "name", eb)
        for ns, end, addr in ((a, ea, a_addr), (b, eb, b_addr)):
            _sh("ip", "link", "set", end, "netns", ns)
            _sh("ip", "-n", ns, "addr", "add", f"{addr}/24", "dev", end)
            _sh("ip", "-n", ns, "link", "set", end, "up")
        return ea, eb

    def loss(self, ns: str, percent: int) -> None:
        """Drop ``percent`` % of the packets entering and leaving namespace ``ns`` (nftables)."""
        rules = (f"table inet patternrl_loss {{\n"
                 f" chain in {{ type filter hook input priority 0; "
                 f"numgen random mod 100 < {percent} counter drop; }}\n"
                 f" chain out {{ type filter hook output priority 0; "
                 f"numgen random mod 100 < {percent} counter drop; }}\n}}\n")
        r = subprocess.run(["ip", "netns", "exec", ns, "nft", "-f", "-"], input=rules,
                           capture_output=True, text=True, timeout=30, check=False)
        if r.returncode != 0:
            raise RuntimeError(f"nft in {ns}: {r.stderr.strip()}")

    def dropped(self, ns: str) -> int:
        """Packets the loss rules of namespace ``ns`` dropped so far."""
        r = subprocess.run(["ip", "netns", "exec", ns, "nft", "-j", "list", "table", "inet",
                            "patternrl_loss"], capture_output=True, text=True, timeout=30,
                           check=True)
        return sum(int(x["counter"]["packets"])
                   for x in _walk(json.loads(r.stdout)) if "counter" in x)

    def set_link(self, ns: str, end: str, up: bool) -> None:
        _sh("ip", "-n", ns, "link", "set", end, "up" if up else "down")

    def run(self, ns: str, name: str, *argv: str) -> subprocess.Popen[bytes]:
        """``argv`` inside namespace ``ns``, output to ``<tmp>/<name>.log``."""
        log = open(self.tmp / f"{name}.log", "wb")
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=str(ROOT))
        env.pop("PATTERNRL_ZENOH_PORT", None)
        p = subprocess.Popen(["ip", "netns", "exec", ns, *argv], cwd=ROOT, env=env,
                             stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                             start_new_session=True)
        log.close()
        self.procs.append(p)
        return p

    def patternrl(self, ns: str, name: str, *argv: str) -> subprocess.Popen[bytes]:
        return self.run(ns, name, PY, "-m", "patternrl.cli", *argv)

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text(errors="replace")

    def close(self) -> None:
        stop_processes(self.procs)
        for ns in reversed(self.namespaces):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30,
                           check=False)


def cut_for(net: Net, ns: str, end: str, seconds: float) -> threading.Thread:
    """Take a link down now and back up after ``seconds`` (the fault itself, not a wait)."""
    net.set_link(ns, end, False)
    t = threading.Timer(seconds, net.set_link, (ns, end, True))
    t.start()
    return t
