"""A swarm identity: the certificate a process speaks with and the access rules it enforces.

A swarm is a set of identities, each holding a certificate from the swarm's own
certificate authority (``patternrl keys create``, :mod:`sim_bridge.launch.swarm_keys`):

==============  ===================================================================
identity        may publish (Zenoh ``put`` / liveliness token / reply)
==============  ===================================================================
``world``       every robot's ``pose``, all poses of a step (``poses``), the
                ``pattern`` (and replies to pattern queries), the ``brain`` of
                each pattern between phases, liveliness ``alive/world``
``robot-<i>``   its own ``robot/<i>/cmd``, ``robot/<i>/status`` and ``robot/<i>/view``
                (the team as it perceived it), liveliness ``alive/<i>``, and its own
                ``robot/<i>/pose`` (a robot that knows where it is: ``robot --ros2``,
                a real swarm without a world)
``operator``    ``brain`` and ``operator/pattern`` (a pattern between the world's phases:
                only the world puts on ``pattern``, which keeps its phases from
                being locked out, :mod:`runtime.decision.team_pattern`)
``router``      anything of the swarm: a Zenoh router relays what it already
                checked when it received it
==============  ===================================================================

Every identity may subscribe to, and query, any key of its swarm. A robot takes
what the world, the operator and the router publish, never what another robot
does (it needs none of it), so a robot's rules do not name the other robots: a
robot's ``zenoh.json5`` is the same size for any team, and only the world's, the
operator's and the router's grow with it (:func:`access_control`). Zenoh enforces
this itself: mutual TLS (each side of every link proves its certificate to the
other; the certificate's common name is the identity) and Zenoh access control
(``access_control`` in the config) on every *ingress* message, by the common
name of the link it came in on. So every node filters what it receives: a
robot holding ``robot-1``'s certificate that puts on ``robot/2/cmd`` is dropped
by the world (or by the router in between) before any subscriber sees it.

Host names are not checked (``verify_name_on_connect: false``): a certificate
names an identity, not a machine, and robots move between addresses. The
authority's signature and the access rules are what count.

One identity directory (what a robot's host needs, nothing else)::

    identity.json   {"format": 1, "swarm": ..., "name": "robot-3", "robots": N}
    ca.pem          the swarm's authority (public certificate)
    cert.pem        this identity's certificate, CN = name (the role the access
                    rules go by)
    key.pem         its private key (mode 0600)
    zenoh.json5     a Zenoh config of this identity: TLS and access control, for any
                    Zenoh tool (paths absolute where it was created)

:func:`apply_identity` reads the access rules from ``zenoh.json5`` and points
the TLS paths at the directory where it is now, so a copied directory works.

Each command speaks as one role and refuses any other identity at start
(:func:`check_role`, called by :func:`find_identity`): ``sim`` and ``replay
--play`` the ``world``, ``router`` the ``router``, ``robot --id i``
``robot-<i>``, the operator's tools (``swap``, ``record``) the ``operator``.
The role is read from the certificate's common name, which is what the other
nodes' access rules see, and must agree with ``identity.json``.
"""

from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal

import zenoh
from cryptography import x509
from cryptography.x509.oid import NameOID

from runtime.errors import InputError
from runtime.wire import keys

__all__ = [
    "IDENTITY_FILES",
    "OPERATOR",
    "ROUTER",
    "Identity",
    "IdentityError",
    "access_control",
    "apply_identity",
    "certificate_name",
    "check_role",
    "default_identity_name",
    "find_identity",
    "identity_zenoh_config",
    "is_robot",
    "load_identity",
    "robot_identity",
    "tls_section",
]

FORMAT: Final = 1
WORLD: Final = "world"
OPERATOR: Final = "operator"
ROUTER: Final = "router"
CA_FILE: Final = "ca.pem"
CERT_FILE: Final = "cert.pem"
KEY_FILE: Final = "key.pem"
META_FILE: Final = "identity.json"
ZENOH_FILE: Final = "zenoh.json5"
IDENTITY_FILES: Final = (META_FILE, CA_FILE, CERT_FILE, KEY_FILE, ZENOH_FILE)

RoleName = Literal["world", "robot", "tool", "router"]


class IdentityError(InputError):
    """An identity directory that cannot be used; the message is one line."""


def robot_identity(robot_id: int) -> str:
    """The identity name of robot ``robot_id``: ``robot-<id>``."""
    return f"robot-{int(robot_id)}"


def is_robot(name: str) -> bool:
    """Whether ``name`` is a robot's identity (``robot-<id>``)."""
    return name.startswith("robot-") and name[len("robot-"):].isdigit()


def default_identity_name(role: RoleName, robot_id: int | None = None) -> str:
    """The identity a process of ``role`` speaks as unless told otherwise."""
    if role == "robot":
        if robot_id is None:
            raise IdentityError("a robot's identity needs its id")
        return robot_identity(robot_id)
    return {"world": WORLD, "tool": OPERATOR, "router": ROUTER}[role]


# ------------------------------------------------------------------ the rules


def _rule(rid: str, messages: list[str], key_exprs: list[str], flows: list[str]) -> dict[str, Any]:
    return {"id": rid, "messages": messages, "flows": flows, "permission": "allow",
            "key_exprs": key_exprs}


def access_control(swarm: str, n_robots: int, hears_robots: bool = True) -> dict[str, Any]:
    """Zenoh ``access_control`` of a swarm of ``n_robots`` robots (the table above).

    Default deny; every rule is an *ingress* allow rule keyed by the certificate
    common name of the link a message arrives on; egress is open (the receiver
    decides). The roles' rules are written once; a robot's own keys need a rule per
    robot (Zenoh's rules name fixed key expressions, with no per-subject template),
    and only ``hears_robots`` identities carry them: the world, the operator's tools
    and the router, which take what robots publish. A robot takes nothing from
    another robot (it decides from the world's poses) unless it drives a ROS 2 base or
    agrees on slots (:func:`apply_identity` then builds every robot's rules), so its rules
    name the roles only: its ``zenoh.json5`` has the same size whatever the team, and a swarm's
    rules grow linearly with the team (three identities of O(n), n of O(1)).
    """
    keys.validate_swarm(swarm)
    root = f"{keys.PREFIX}/{swarm}"
    ingress = ["ingress"]
    rules = [
        _rule("egress", ["put", "delete", "declare_subscriber", "query", "declare_queryable",
                         "reply", "liveliness_token", "declare_liveliness_subscriber",
                         "liveliness_query"], ["**"], ["egress"]),
        _rule("listen", ["declare_subscriber", "declare_liveliness_subscriber",
                         "liveliness_query", "query"], [f"{root}/**"], ingress),
        # the world also swaps in each pattern's chosen brain between phases (signed brains only)
        _rule("world-put", ["put"], [keys.all_poses(swarm), keys.poses_key(swarm),
                                     keys.pattern_key(swarm), keys.brain_key(swarm)], ingress),
        _rule("world-pattern-queries", ["declare_queryable", "reply"], [keys.pattern_key(swarm)],
              ingress),
        _rule("world-alive", ["liveliness_token"], [keys.alive_key(swarm, keys.WORLD_ID)],
              ingress),
        _rule("operator-put", ["put"], [keys.brain_key(swarm), keys.operator_pattern_key(swarm)],
              ingress),
        _rule("router-relay", ["put", "delete", "declare_queryable", "reply", "liveliness_token"],
              [f"{root}/**"], ingress),
    ]
    subjects: list[dict[str, Any]] = [
        {"id": "anyone"},
        {"id": WORLD, "cert_common_names": [WORLD]},
        {"id": OPERATOR, "cert_common_names": [OPERATOR]},
        {"id": ROUTER, "cert_common_names": [ROUTER]},
    ]
    policies: list[dict[str, Any]] = [
        {"id": "everyone-listens", "rules": ["egress", "listen"], "subjects": ["anyone"]},
        {"id": "world", "rules": ["world-put", "world-pattern-queries", "world-alive"],
         "subjects": [WORLD]},
        {"id": "operator", "rules": ["operator-put"], "subjects": [OPERATOR]},
        {"id": "router", "rules": ["router-relay"], "subjects": [ROUTER]},
    ]
    for i in range(n_robots if hears_robots else 0):
        name = robot_identity(i)
        rules.append(_rule(f"{name}-put", ["put"], [keys.cmd_key(swarm, i),
                                                   keys.status_key(swarm, i),
                                                   keys.view_key(swarm, i),
                                                   keys.slots_key(swarm, i),
                                                   keys.pose_key(swarm, i)], ingress))
        rules.append(_rule(f"{name}-alive", ["liveliness_token"], [keys.alive_key(swarm, i)],
                           ingress))
        subjects.append({"id": name, "cert_common_names": [name]})
        policies.append({"id": name, "rules": [f"{name}-put", f"{name}-alive"],
                         "subjects": [name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def tls_section(directory: Path) -> dict[str, Any]:
    """Zenoh ``transport/link/tls`` of the identity in ``directory`` (absolute paths)."""
    d = directory.resolve()
    cert, key = str(d / CERT_FILE), str(d / KEY_FILE)
    return {
        "root_ca_certificate": str(d / CA_FILE),
        "listen_certificate": cert, "listen_private_key": key,
        "connect_certificate": cert, "connect_private_key": key,
        "enable_mtls": True,
        "verify_name_on_connect": False,
    }


def identity_zenoh_config(directory: Path, name: str, swarm: str,
                          n_robots: int) -> dict[str, Any]:
    """The ``zenoh.json5`` written beside an identity: mutual TLS and access control.

    Peer mode, except the router's (router mode: ``zenohd -c router/zenoh.json5``).
    """
    return {
        "mode": "router" if name == ROUTER else "peer",
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tls": tls_section(directory)}},
        "access_control": access_control(swarm, n_robots, hears_robots=not is_robot(name)),
    }


# ------------------------------------------------------------------ loading


@dataclass(frozen=True)
class Identity:
    """One identity directory, checked: who it is, of which swarm, where its files lie."""

    directory: Path
    swarm: str
    name: str
    robots: int

    @property
    def acl(self) -> dict[str, Any]:
        """The access rules this identity enforces (from its ``zenoh.json5``)."""
        try:
            conf = json.loads((self.directory / ZENOH_FILE).read_text())
            acl = conf["access_control"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise IdentityError(f"{self.directory / ZENOH_FILE}: no access rules ({e})") from None
        if not isinstance(acl, dict):
            raise IdentityError(f"{self.directory / ZENOH_FILE}: access_control is not an object")
        return acl


def load_identity(directory: str | Path) -> Identity:
    """Check an identity directory; IdentityError (one line) if anything is missing or open."""
    d = Path(directory)
    if not d.is_dir():
        raise IdentityError(f"identity directory not found: {d} (made by 'patternrl keys create')")
    for f in IDENTITY_FILES:
        if not (d / f).is_file():
            raise IdentityError(f"identity {d}: {f} is missing")
    mode = stat.S_IMODE(os.stat(d / KEY_FILE).st_mode)
    if mode & 0o077:
        raise IdentityError(f"identity {d}: {KEY_FILE} is readable by others (mode {mode:o}); "
                            f"chmod 600 {d / KEY_FILE}")
    try:
        meta = json.loads((d / META_FILE).read_text())
        fmt, swarm, name, robots = meta["format"], meta["swarm"], meta["name"], meta["robots"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise IdentityError(f"identity {d}: bad {META_FILE} ({e})") from None
    if fmt != FORMAT:
        raise IdentityError(f"identity {d}: format {fmt!r} unknown (expected {FORMAT})")
    if not isinstance(name, str) or not isinstance(robots, int) or not isinstance(swarm, str):
        raise IdentityError(f"identity {d}: bad {META_FILE}")
    try:
        keys.validate_swarm(swarm)
    except ValueError as e:
        raise IdentityError(f"identity {d}: {e}") from None
    return Identity(d.resolve(), swarm, name, robots)


def find_identity(identity_dir: str | None, tls_dir: str | None, as_name: str | None,
                  role: RoleName, robot_id: int | None, swarm: str) -> Identity:
    """The identity of a process from ``--identity DIR`` or ``--tls-dir DIR [--as NAME]``.

    Checks that it belongs to ``swarm`` and, for a robot, that it is this robot's.
    """
    if identity_dir is not None and tls_dir is not None:
        raise IdentityError("give --identity DIR or --tls-dir DIR, not both")
    if identity_dir is not None:
        if as_name is not None:
            raise IdentityError("--as goes with --tls-dir, not --identity")
        ident = load_identity(identity_dir)
    elif tls_dir is not None:
        name = as_name or default_identity_name(role, robot_id)
        ident = load_identity(Path(tls_dir) / name)
    else:
        raise IdentityError("no identity given")
    if ident.swarm != swarm:
        raise IdentityError(f"identity {ident.name} belongs to swarm '{ident.swarm}', "
                            f"not '{swarm}'")
    check_role(ident, role, robot_id)
    return ident


def certificate_name(directory: Path) -> str:
    """The common name of ``directory/cert.pem``: the name the access rules know it by."""
    path = directory / CERT_FILE
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
        names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    except (OSError, ValueError) as e:
        raise IdentityError(f"identity {directory}: {CERT_FILE} is not a certificate "
                            f"({' '.join(str(e).split())[:120]})") from None
    if len(names) != 1 or not isinstance(names[0].value, str):
        raise IdentityError(f"identity {directory}: {CERT_FILE} has no single common name")
    return names[0].value


_ROLE_WORDS: Final = {"world": "the world", "router": "the router",
                      "tool": "an operator's tool"}


def check_role(ident: Identity, role: RoleName, robot_id: int | None = None) -> None:
    """IdentityError (one line) unless ``ident`` is the identity a process of ``role`` needs.

    ``world`` needs ``world``, ``router`` ``router``, ``tool`` (swap, record)
    ``operator``, ``robot`` ``robot-<robot_id>`` (any robot's when the id is not
    known). The name is the certificate's common name, the one the access rules
    match, and ``identity.json`` must say the same.
    """
    cn = certificate_name(ident.directory)
    if cn != ident.name:
        raise IdentityError(f"identity {ident.directory}: {CERT_FILE} is {cn!r} but "
                            f"{META_FILE} says {ident.name!r}")
    if role == "robot":
        if robot_id is None:
            if is_robot(cn):
                return
            raise IdentityError(f"identity {cn} is not a robot's (robot-<id>)")
        if cn != robot_identity(robot_id):
            raise IdentityError(f"identity {cn} cannot speak for robot {robot_id} "
                                f"(its identity is {robot_identity(robot_id)})")
        return
    need = default_identity_name(role)
    if cn != need:
        raise IdentityError(f"identity {cn} cannot act as {_ROLE_WORDS[role]} "
                            f"(that needs identity {need})")


def apply_identity(conf: zenoh.Config, ident: Identity, hears_robots: bool = False) -> None:
    """Put the identity's mutual TLS and access rules into a Zenoh config.

    ``hears_robots``: a robot that takes its peers' own poses (``robot --ros2``: no world
    relays them) or their slots (``robot --agree``) enforces every robot's rules, as the
    world does, built here from the swarm's size rather than read from its file (which names
    the roles only): each robot may put on its own keys only."""
    acl = (access_control(ident.swarm, ident.robots, hears_robots=True)
           if hears_robots and is_robot(ident.name) else ident.acl)
    try:
        conf.insert_json5("transport/link/tls", json.dumps(tls_section(ident.directory)))
        conf.insert_json5("access_control", json.dumps(acl))
    except IdentityError:
        raise
    except Exception as e:  # zenoh.ZError: a config zenoh refuses
        raise IdentityError(f"identity {ident.directory}: zenoh refused it: "
                            f"{str(e).strip()[:200]}") from None
