"""Opening Zenoh sessions the same way in every Pattern-RL process.

Default discovery on one machine (nothing to start by hand, no multicast)
-----------------------------------------------------------------------
Every process runs in Zenoh **peer** mode with multicast scouting **off** and
explicit loopback endpoints:

* the **world** (the sim bridge) *listens* on ``tcp/127.0.0.1:<world port>``;
* every **robot**, and every tool (``patternrl swap``, recorders), *connects*
  to that endpoint and *listens* on ``tcp/127.0.0.1:0`` (an ephemeral port).

The world port is derived from the swarm name, :func:`world_port`:
``base + crc32(swarm) % 1000`` with ``base`` = :data:`DEFAULT_BASE_PORT`
(7460), overridable with the environment variable ``PATTERNRL_ZENOH_PORT``
(an explicit port for the world endpoint) or the ``--zenoh-port`` option.
So ``patternrl sim --swarm demo`` and ``patternrl robot --swarm demo --id 3``
meet without any endpoint on their command lines, and two swarms on one
machine do not share a port.

Robots do not need the world to be up first: a peer retries its ``connect``
endpoint in the background. Once connected, Zenoh's gossip scouting (on by
default) tells every peer about the others' listening endpoints, so peers
then connect to each other directly (a full mesh on loopback): a robot hears
``patternrl swap`` even though both only named the world's endpoint.

Across machines nothing changes but the endpoints: pass ``--connect`` /
``--listen`` (e.g. a router's ``tcp/10.0.0.2:7447``), or a full Zenoh config
file with ``--zenoh-config FILE``. A config file is used as written, except
that ``--mode``, ``--connect`` and ``--listen`` given on the command line
override the file's values; without a file, the defaults above apply.
"""

from __future__ import annotations

import argparse
import json
import os
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Final, Literal

import zenoh

from runtime.errors import InputError
from runtime.keys import validate_swarm

__all__ = [
    "DEFAULT_BASE_PORT",
    "PORT_ENV",
    "Role",
    "ZenohSetupError",
    "add_zenoh_arguments",
    "make_config",
    "open_session",
    "open_session_from_args",
    "session_endpoints",
    "world_endpoint",
    "world_port",
]

DEFAULT_BASE_PORT: Final = 7460
PORT_SPREAD: Final = 1000
PORT_ENV: Final = "PATTERNRL_ZENOH_PORT"
LOOPBACK: Final = "127.0.0.1"
MODES: Final = ("peer", "client", "router")

Role = Literal["world", "robot", "tool"]


class ZenohSetupError(InputError):
    """A Zenoh configuration that cannot be used; the message is one line."""


def world_port(swarm: str, base: int = DEFAULT_BASE_PORT) -> int:
    """The world's default TCP port for ``swarm``: base + crc32(swarm) % 1000."""
    validate_swarm(swarm)
    return base + zlib.crc32(swarm.encode("utf-8")) % PORT_SPREAD


def world_endpoint(swarm: str, port: int | None = None) -> str:
    """``tcp/127.0.0.1:<port>``: where the world listens and everyone else connects.

    ``port`` None: the ``PATTERNRL_ZENOH_PORT`` environment variable if set,
    else :func:`world_port` of the swarm.
    """
    if port is None:
        env = os.environ.get(PORT_ENV, "").strip()
        if env:
            try:
                port = int(env)
            except ValueError:
                raise ZenohSetupError(f"{PORT_ENV}={env!r} is not a port number") from None
        else:
            port = world_port(swarm)
    if not 0 < port < 65536:
        raise ZenohSetupError(f"port {port} out of range 1..65535")
    return f"tcp/{LOOPBACK}:{port}"


def session_endpoints(
    role: Role, swarm: str, port: int | None = None
) -> tuple[list[str], list[str]]:
    """Default (connect, listen) endpoints of a process of ``role`` in ``swarm``."""
    ep = world_endpoint(swarm, port)
    if role == "world":
        return [], [ep]
    return [ep], [f"tcp/{LOOPBACK}:0"]


def _check_endpoints(what: str, eps: Sequence[str]) -> list[str]:
    out = []
    for ep in eps:
        if not isinstance(ep, str) or "/" not in ep or ep.startswith("/"):
            raise ZenohSetupError(f"bad {what} endpoint {ep!r}: expected e.g. tcp/127.0.0.1:7447")
        out.append(ep)
    return out


def make_config(
    mode: str = "peer",
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    config_file: str | Path | None = None,
    multicast: bool = False,
) -> zenoh.Config:
    """A Zenoh config: the file if given (else defaults), with explicit overrides.

    Without ``config_file``: ``mode``, multicast scouting as ``multicast`` (off
    by default), and the given endpoints. With a file: the file as written,
    then ``connect``/``listen`` replace the file's endpoints when not None, and
    ``mode`` replaces the file's mode when the file has none.
    """
    if mode not in MODES:
        raise ZenohSetupError(f"unknown zenoh mode {mode!r} (known: {', '.join(MODES)})")
    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise ZenohSetupError(f"zenoh config file not found: {path}")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as e:  # zenoh.ZError and friends
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise ZenohSetupError(f"bad zenoh config {path}: {first}") from None
        try:
            file_mode = conf.get_json("mode")
        except Exception:
            file_mode = None
        if not file_mode:
            conf.insert_json5("mode", json.dumps(mode))
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
    try:
        if connect is not None:
            conf.insert_json5("connect/endpoints", json.dumps(_check_endpoints("connect", connect)))
        if listen is not None:
            conf.insert_json5("listen/endpoints", json.dumps(_check_endpoints("listen", listen)))
    except ZenohSetupError:
        raise
    except Exception as e:
        raise ZenohSetupError(f"bad zenoh endpoints: {str(e).strip()[:200]}") from None
    return conf


def open_session(
    mode: str = "peer",
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    config_file: str | Path | None = None,
) -> zenoh.Session:
    """Open a Zenoh session (see :func:`make_config`); ZenohSetupError on failure."""
    conf = make_config(mode, connect, listen, config_file)
    try:
        return zenoh.open(conf)
    except Exception as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ZenohSetupError(f"cannot open zenoh session: {first[:300]}") from None


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The Zenoh options every Pattern-RL process shares."""
    g = parser.add_argument_group("zenoh")
    g.add_argument(
        "--zenoh-config",
        metavar="FILE",
        default=None,
        help="a Zenoh JSON5 config file, used as written (--connect/--listen override it)",
    )
    g.add_argument(
        "--zenoh-mode",
        choices=MODES,
        default="peer",
        help="Zenoh mode when no config file says (default: peer)",
    )
    g.add_argument(
        "--connect",
        metavar="EP",
        action="append",
        default=None,
        help="endpoint to connect to, repeatable (default: the world's tcp/127.0.0.1:<port>)",
    )
    g.add_argument(
        "--listen",
        metavar="EP",
        action="append",
        default=None,
        help="endpoint to listen on, repeatable (default: tcp/127.0.0.1:0 for robots and tools)",
    )
    g.add_argument(
        "--zenoh-port",
        type=int,
        default=None,
        metavar="PORT",
        help=f"the world's loopback port (default: ${PORT_ENV}, else derived from the swarm name)",
    )


def open_session_from_args(args: argparse.Namespace, role: Role, swarm: str) -> zenoh.Session:
    """Open the session of a process from the options of :func:`add_zenoh_arguments`."""
    connect: list[str] | None = args.connect
    listen: list[str] | None = args.listen
    if args.zenoh_config is None:
        d_connect, d_listen = session_endpoints(role, swarm, args.zenoh_port)
        if connect is None:
            connect = d_connect
        if listen is None:
            listen = d_listen
    return open_session(args.zenoh_mode, connect, listen, args.zenoh_config)
