"""Opening Zenoh sessions the same way in every Pattern-RL process.

Default discovery on one machine (nothing to start by hand, no multicast)
-----------------------------------------------------------------------
Every process runs in Zenoh **peer** mode with multicast scouting **off** and
explicit loopback endpoints:

* the **world** (the sim bridge) *listens* on ``tls/127.0.0.1:<world port>``;
* every **robot**, and every tool (``patternrl swap``, recorders), *connects*
  to that endpoint and *listens* on ``tls/127.0.0.1:0`` (an ephemeral port).

The world port is derived from the swarm name, :func:`world_port`:
``base + crc32(swarm) % 1000`` with ``base`` = :data:`DEFAULT_BASE_PORT`
(7460), overridable with the environment variable ``PATTERNRL_ZENOH_PORT``
(an explicit port for the world endpoint) or the ``--zenoh-port`` option.
So ``patternrl sim --swarm demo`` and ``patternrl robot --swarm demo --id 3``
meet without any endpoint on their command lines, and two swarms on one
machine do not share a port.

Security (on by default)
------------------------
Every process speaks as one identity of its swarm (``--identity DIR``, or
``--tls-dir DIR`` with ``--as NAME`` defaulting to the process's own: ``world``,
``robot-<id>``, ``operator``): mutual TLS with the swarm's certificate
authority and Zenoh access control, see :mod:`runtime.net.identity`. Endpoints are
then ``tls/...``. ``--insecure`` runs on open TCP instead (``tcp/...``): for
experiments on loopback, where anyone on the machine can join the swarm. A
process given neither refuses to start; one given a config file (``-c``) uses
it as written (the file is then the user's security choice).

With a router (``patternrl router``; what ``patternrl launch`` starts for
more than 20 robots) the router listens on that port instead, and the world,
the robots and the tools run as Zenoh **clients** (``-m client``): each
connects to the port and listens nowhere, so the swarm is a star of one link
per process rather than a mesh of one link per pair.

Robots do not need the world to be up first: a peer retries its ``connect``
endpoint in the background. Once connected, Zenoh's gossip scouting (on by
default) tells every peer about the others' listening endpoints, so peers
then connect to each other directly (a full mesh on loopback): a robot hears
``patternrl swap`` even though both only named the world's endpoint.

Options (zenoh's own names, as in zenoh-python's ``examples/common/common.py``)
-----------------------------------------------------------------------------
``-m/--mode`` (``--zenoh-mode``; commands with an execution ``--mode`` of their
own take ``-m``/``--zenoh-mode`` only), ``-e/--connect``, ``-l/--listen``,
``-c/--config`` (``--zenoh-config``), ``--cfg KEY:VALUE`` (repeatable, a JSON5
value at a config path, applied last), ``--multicast-scouting`` /
``--no-multicast-scouting`` (off unless a config file says otherwise).
Across machines nothing changes but the endpoints: ``-e tls/10.0.0.2:7447``
(a world's or a router's), ``-l tls/0.0.0.0:7447``, or a whole config file.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final, Literal

import zenoh

from runtime.errors import InputError
from runtime.net.identity import Identity, IdentityError, apply_identity, find_identity
from runtime.wire.keys import validate_swarm

__all__ = [
    "DEFAULT_BASE_PORT",
    "PORT_ENV",
    "Role",
    "ZenohSetupError",
    "add_zenoh_arguments",
    "identity_from_args",
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
SCHEMES: Final = ("tcp", "tls")

Role = Literal["world", "robot", "tool", "router"]


class ZenohSetupError(InputError):
    """A Zenoh configuration that cannot be used; the message is one line."""


def world_port(swarm: str, base: int = DEFAULT_BASE_PORT) -> int:
    """The world's default TCP port for ``swarm``: base + crc32(swarm) % 1000."""
    validate_swarm(swarm)
    return base + zlib.crc32(swarm.encode("utf-8")) % PORT_SPREAD


def world_endpoint(swarm: str, port: int | None = None, scheme: str = "tcp") -> str:
    """``<scheme>/127.0.0.1:<port>``: where the world listens and everyone else connects.

    ``port`` None: the ``PATTERNRL_ZENOH_PORT`` environment variable if set,
    else :func:`world_port` of the swarm. ``scheme``: ``tcp`` or ``tls``.
    """
    if scheme not in SCHEMES:
        raise ZenohSetupError(f"unknown link scheme {scheme!r} (known: {', '.join(SCHEMES)})")
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
    return f"{scheme}/{LOOPBACK}:{port}"


def session_endpoints(
    role: Role, swarm: str, port: int | None = None, scheme: str = "tcp",
    mode: str | None = None,
) -> tuple[list[str], list[str]]:
    """Default (connect, listen) endpoints of a process of ``role`` in ``swarm``.

    ``mode`` ``client``: connect to the swarm's port (a router's, ``patternrl
    router``), listen nowhere, whatever the role.
    """
    ep = world_endpoint(swarm, port, scheme)
    if mode == "client":
        return [ep], []
    if role in ("world", "router"):
        return [], [ep]
    return [ep], [f"{scheme}/{LOOPBACK}:0"]


def _check_endpoints(what: str, eps: Sequence[str], tls_only: bool = False) -> list[str]:
    out = []
    for ep in eps:
        if not isinstance(ep, str) or "/" not in ep or ep.startswith("/"):
            raise ZenohSetupError(f"bad {what} endpoint {ep!r}: expected e.g. tls/127.0.0.1:7447")
        if tls_only and not ep.startswith("tls/"):
            raise ZenohSetupError(
                f"{what} endpoint {ep!r} is not TLS: with an identity every link is tls/... "
                "(or run open with --insecure)")
        out.append(ep)
    return out


_RUST_SOURCE = re.compile(r"\s+at\s+\S+\.rs:\d+\.?$")
_ZENOH_STR = re.compile(r'^Str\("(.*)"\)$')
_ZENOH_JSON5 = re.compile(r'^Json5Err\(Message \{ msg: "((?:[^"\\]|\\.)*)"')


def _reason(e: BaseException) -> str:
    """Zenoh's error in words: without the Rust source path it names, nor its wrappers."""
    text = _RUST_SOURCE.sub("", str(e).strip())
    if m := _ZENOH_STR.match(text):
        text = m.group(1)
    elif m := _ZENOH_JSON5.match(text):
        msg = m.group(1).replace('\\"', '"')
        text = "bad value: " + msg.rpartition("\\n  = ")[2]  # a parser's caret drawing: its verdict
    return " ".join(text.split()) or type(e).__name__


def _first_line(e: BaseException) -> str:
    text = _reason(e)
    return text.splitlines()[0] if text else type(e).__name__


def _insert(conf: zenoh.Config, key: str, value: Any, what: str) -> None:
    try:
        conf.insert_json5(key, json.dumps(value))
    except Exception as e:  # zenoh.ZError: a value zenoh refuses
        raise ZenohSetupError(f"bad {what}: {_first_line(e)[:200]}") from None


def _apply_cfg(conf: zenoh.Config, items: Sequence[str]) -> None:
    """``--cfg KEY:VALUE`` items: VALUE is JSON5 put at config path KEY (zenoh's convention)."""
    for item in items:
        key, sep, value = item.partition(":")
        if not sep or not key.strip() or not value.strip():
            raise ZenohSetupError(f"bad --cfg {item!r}: expected KEY:VALUE, e.g. "
                                  "'transport/unicast/max_links:2'")
        try:
            conf.insert_json5(key.strip(), value)
        except Exception as e:
            reason = _first_line(e)
            if reason == "unknown key":
                reason = f"unknown zenoh config key {key.strip()!r}"
            else:
                reason = f"key {key.strip()!r}: {reason}"
            raise ZenohSetupError(f"bad --cfg {item!r}: {reason[:200]}") from None


def make_config(
    mode: str | None = "peer",
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    config_file: str | Path | None = None,
    multicast: bool | None = None,
    cfg: Sequence[str] = (),
    identity: Identity | None = None,
    hears_robots: bool = False,
) -> zenoh.Config:
    """A Zenoh config: the file if given (else defaults), then the explicit overrides.

    ``hears_robots``: a robot identity enforces every robot's access rules
    (:func:`runtime.net.identity.apply_identity`).

    In order: the file (or an empty config with multicast scouting off), the
    ``identity``'s mutual TLS and access rules, ``mode`` (None: the file's, else
    peer), ``connect``/``listen`` (None: keep the file's), ``multicast`` (None:
    keep), then every ``--cfg KEY:VALUE`` in ``cfg``. With an identity every
    given endpoint must be ``tls/``.
    """
    if mode is not None and mode not in MODES:
        raise ZenohSetupError(f"unknown zenoh mode {mode!r} (known: {', '.join(MODES)})")
    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise ZenohSetupError(f"zenoh config file not found: {path}")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as e:  # zenoh.ZError and friends
            raise ZenohSetupError(f"bad zenoh config {path}: {_first_line(e)}") from None
        try:
            file_mode = conf.get_json("mode")
        except Exception:
            file_mode = None
        if mode is None and not file_mode:
            mode = "peer"
    else:
        conf = zenoh.Config()
        mode = mode or "peer"
        if multicast is None:
            multicast = False
        # Zenoh's shared memory (on by default) runs a watchdog thread in every process
        # that wakes 20 times a second (0.7 ms of CPU a second each, 5 % of a robot's in a
        # 100-robot swarm); Pattern-RL's messages are small and cross TLS links, which
        # never carry shared memory. A config file can turn it back on.
        _insert(conf, "transport/shared_memory/enabled", False, "shared memory")
    if identity is not None:
        apply_identity(conf, identity, hears_robots)
    if mode is not None:
        _insert(conf, "mode", mode, "zenoh mode")
    if multicast is not None:
        _insert(conf, "scouting/multicast/enabled", bool(multicast), "multicast scouting")
    tls_only = identity is not None
    if connect is not None:
        _insert(conf, "connect/endpoints", _check_endpoints("connect", connect, tls_only),
                "connect endpoints")
    if listen is not None:
        _insert(conf, "listen/endpoints", _check_endpoints("listen", listen, tls_only),
                "listen endpoints")
    _apply_cfg(conf, cfg)
    return conf


def open_config(conf: zenoh.Config) -> zenoh.Session:
    """Open a session from a config; ZenohSetupError (one line) on failure."""
    try:
        return zenoh.open(conf)
    except Exception as e:
        raise ZenohSetupError(f"cannot open zenoh session: {_first_line(e)[:300]}") from None


def direct(callback: Callable[[Any], Any]) -> zenoh.handlers.Callback[Any]:
    """``callback`` run on the Zenoh thread that received the sample.

    zenoh-python's default (``indirect``) hands every sample to a Python thread
    of its own that then calls the callback: one more thread wake-up and GIL
    hand-over per sample. For the hot keys (the world's poses at the robots,
    the robots' commands at the world) whose callbacks only decode, store and
    notify, running them on the receiving thread saves that hop. Such a
    callback must never block on the caller's thread (no Zenoh calls that wait
    for a reply, no long work): it would stall every key of the session.
    """
    return zenoh.handlers.Callback(callback, indirect=False)


def open_session(
    mode: str = "peer",
    connect: Sequence[str] | None = None,
    listen: Sequence[str] | None = None,
    config_file: str | Path | None = None,
    identity: Identity | None = None,
) -> zenoh.Session:
    """Open a Zenoh session (see :func:`make_config`); ZenohSetupError on failure."""
    return open_config(make_config(mode, connect, listen, config_file, identity=identity))


# ------------------------------------------------------------------ command line


def _add(group: Any, parser: argparse.ArgumentParser, *names: str, **kw: Any) -> None:
    """Add an option under the names the command has not taken already (e.g. robot's --mode)."""
    # argparse keeps its option table private; it has been stable since Python 2.7
    taken = parser._option_string_actions
    free = [n for n in names if n not in taken]
    if free:
        group.add_argument(*free, **kw)


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The Zenoh and security options every Pattern-RL process that opens a session shares."""
    g = parser.add_argument_group("zenoh (zenoh's own option names)")
    _add(g, parser, "-m", "--mode", "--zenoh-mode", dest="zenoh_mode", choices=MODES,
         default=None,
         help="zenoh session mode (default: the config file's, else peer); -m/--zenoh-mode "
              "where the command's --mode is its execution mode")
    _add(g, parser, "-e", "--connect", dest="connect", metavar="ENDPOINT", action="append",
         default=None,
         help="endpoint to connect to, repeatable, e.g. tls/10.0.0.1:7447 (default: the "
              "world's tls/127.0.0.1:<port>)")
    _add(g, parser, "-l", "--listen", dest="listen", metavar="ENDPOINT", action="append",
         default=None,
         help="endpoint to listen on, repeatable, e.g. tls/0.0.0.0:7447 (default: the world "
              "tls/127.0.0.1:<port>, others tls/127.0.0.1:0)")
    _add(g, parser, "-c", "--config", "--zenoh-config", dest="zenoh_config", metavar="FILE",
         default=None,
         help="a Zenoh JSON5 config file, used as written under the options given here")
    _add(g, parser, "--cfg", dest="zenoh_cfg", metavar="KEY:VALUE", action="append",
         default=[],
         help="set a config path to a JSON5 value, repeatable, applied last, e.g. "
              "--cfg 'transport/unicast/max_links:2'")
    _add(g, parser, "--multicast-scouting", dest="multicast", action="store_const", const=True,
         default=None, help="find peers by UDP multicast too (off by default)")
    _add(g, parser, "--no-multicast-scouting", dest="multicast", action="store_const",
         const=False, help="no multicast scouting (the default unless a config file enables it)")
    _add(g, parser, "--zenoh-port", dest="zenoh_port", type=int, default=None, metavar="PORT",
         help=f"the world's loopback port (default: ${PORT_ENV}, else derived from the swarm "
              "name)")
    s = parser.add_argument_group(
        "security (mutual TLS and access control; see 'patternrl keys create')")
    _add(s, parser, "--identity", dest="identity", metavar="DIR", default=None,
         help="this process's identity directory (e.g. keys/robot-3)")
    _add(s, parser, "--tls-dir", dest="tls_dir", metavar="DIR", default=None,
         help="a swarm's keys directory; the identity is DIR/<--as>")
    _add(s, parser, "--as", dest="identity_as", metavar="NAME", default=None,
         help="identity name under --tls-dir (default: world, robot-<id> or operator, by "
              "command)")
    _add(s, parser, "--insecure", dest="insecure", action="store_true",
         help="open TCP, no certificates and no access control: for experiments on loopback "
              "(anyone who reaches the port can steer the swarm)")


def identity_from_args(args: argparse.Namespace, role: Role, swarm: str) -> Identity | None:
    """The identity the options name; None when running open (``--insecure`` or ``-c FILE``).

    ZenohSetupError when none is given and no config file either: secure by default.
    """
    identity_dir = getattr(args, "identity", None)
    tls_dir = getattr(args, "tls_dir", None)
    as_name = getattr(args, "identity_as", None)
    insecure = bool(getattr(args, "insecure", False))
    if insecure:
        if identity_dir is not None or tls_dir is not None:
            raise ZenohSetupError("--insecure runs without an identity: drop --identity/--tls-dir")
        return None
    if identity_dir is None and tls_dir is None:
        if getattr(args, "zenoh_config", None) is not None:
            return None
        raise ZenohSetupError(
            "no identity: give --identity DIR or --tls-dir DIR (made by 'patternrl keys "
            "create'), or --insecure to run open on loopback")
    robot_id = getattr(args, "id", None) if role == "robot" else None
    try:
        return find_identity(identity_dir, tls_dir, as_name, role, robot_id, swarm)
    except IdentityError as e:
        raise ZenohSetupError(str(e)) from None


def tells_each_other(args: argparse.Namespace) -> bool:
    """Whether a robot of these options tells its team what it agrees on and hears theirs
    (``--agree`` under its ``--conditions``, :func:`runtime.decision.agreement.hears`): it
    then enforces every robot's access rules, so that each may tell its own only."""
    from runtime.conditions import parse_conditions
    from runtime.decision.agreement import hears

    agree = getattr(args, "agree", None)
    if agree is None:
        return False
    try:
        return hears(agree, parse_conditions(getattr(args, "conditions", None) or "perfect"))
    except (InputError, ValueError):
        return True  # refused before it runs; the stricter rules meanwhile


def config_from_args(args: argparse.Namespace, role: Role, swarm: str) -> zenoh.Config:
    """The Zenoh config of a process from the options of :func:`add_zenoh_arguments`."""
    ident = identity_from_args(args, role, swarm)
    connect: list[str] | None = args.connect
    listen: list[str] | None = args.listen
    if args.zenoh_config is None:
        scheme = "tcp" if ident is None else "tls"
        d_connect, d_listen = session_endpoints(role, swarm, args.zenoh_port, scheme,
                                                args.zenoh_mode)
        if connect is None:
            connect = d_connect
        if listen is None:
            listen = d_listen
    return make_config(args.zenoh_mode, connect, listen, args.zenoh_config,
                       getattr(args, "multicast", None), getattr(args, "zenoh_cfg", None) or (),
                       ident, hears_robots=bool(getattr(args, "ros2", None))
                       or tells_each_other(args))


def open_session_from_args(args: argparse.Namespace, role: Role, swarm: str) -> zenoh.Session:
    """Open the session of a process from the options of :func:`add_zenoh_arguments`."""
    return open_config(config_from_args(args, role, swarm))
