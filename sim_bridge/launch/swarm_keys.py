"""``patternrl keys create``: a swarm's certificate authority and one identity per member.

    patternrl keys create --swarm S --robots N --out DIR

writes (private keys mode 0600, directories 0700)::

    DIR/ca/ca.pem, ca.key           the swarm's authority: keep ca.key off the robots
    DIR/world/                      the world (``patternrl sim --identity DIR/world``)
    DIR/robot-0/ .. robot-<N-1>/    one per robot (``patternrl robot --identity ...``)
    DIR/operator/                   brains and patterns (``patternrl swap``)
    DIR/router/                     a Zenoh router between hosts, if one is used

Each identity directory is self-contained (see :mod:`runtime.net.identity`): copy
``DIR/robot-3`` to robot 3's host and nothing else. Certificates are ECDSA
P-256, valid ``--days`` days; the common name is the identity's name. The world's,
operator's and router's access rules name every robot (so a swarm that grows needs
new keys); a robot's name the roles only, so time and size grow linearly with the
team, up to :data:`MAX_ROBOTS` robots (more is refused at once).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from runtime.errors import InputError
from runtime.net import identity as idn
from runtime.wire import keys
from runtime.wire.fields import MAX_PATTERN_POINTS

DEFAULT_DAYS = 3650
MAX_ROBOTS = MAX_PATTERN_POINTS
"""The largest team: the most robots a pattern message carries points for (4096). Keys for
it take ~13 s; the world's, operator's and router's rules grow linearly (2.8 MB at 4096),
a robot's stay ~3 KB (the rules: :func:`runtime.net.identity.access_control`)."""


@dataclass(frozen=True)
class SwarmKeys:
    """What :func:`create_swarm_keys` wrote."""

    out: Path
    swarm: str
    robots: int
    names: tuple[str, ...]

    def identity_dir(self, name: str) -> Path:
        return self.out / name


def _name(cn: str, swarm: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, f"patternrl swarm {swarm}")])


def _write_private(path: Path, data: bytes) -> None:
    """Write a secret readable by its owner only, from the first byte on."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert_pem(cert: x509.Certificate) -> bytes:
    return cert.public_bytes(serialization.Encoding.PEM)


def _make_ca(swarm: str, days: int) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    name = _name(f"patternrl-{swarm}-ca", swarm)
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, key_cert_sign=True, crl_sign=True,
                                         encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
                           critical=False)
            .sign(key, hashes.SHA256()))
    return key, cert


def _make_leaf(cn: str, swarm: str, ca_key: ec.EllipticCurvePrivateKey,
               ca_cert: x509.Certificate, days: int
               ) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    key = ec.generate_private_key(ec.SECP256R1())
    now = dt.datetime.now(dt.UTC)
    # every identity both listens and connects (peers mesh), so server and client use;
    # the DNS name is the identity (host names are not checked: runtime/net/identity.py)
    cert = (x509.CertificateBuilder().subject_name(_name(cn, swarm))
            .issuer_name(ca_cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False,
                                         key_encipherment=False, data_encipherment=False,
                                         key_agreement=True, key_cert_sign=False, crl_sign=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                  ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.SubjectAlternativeName([x509.DNSName(cn)]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    return key, cert


def create_swarm_keys(out: Path, swarm: str, robots: int, days: int = DEFAULT_DAYS,
                      force: bool = False) -> SwarmKeys:
    """Make the authority and every identity of a swarm under ``out`` (see module doc)."""
    try:
        keys.validate_swarm(swarm)
    except ValueError as e:
        raise InputError(str(e)) from None
    if not 1 <= robots <= MAX_ROBOTS:
        raise InputError(f"--robots must be in 1..{MAX_ROBOTS} (the largest team a pattern "
                         f"message carries), got {robots}")
    if not 1 <= days <= 100 * 366:
        raise InputError(f"--days must be in 1..36600, got {days}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out} exists and is not a directory")
    if (out / "ca").exists():
        if not force:
            raise InputError(f"{out} already holds a swarm's keys; replacing them locks out every "
                             "identity made from them (use --force to do it anyway)")
        shutil.rmtree(out / "ca")
    out.mkdir(parents=True, exist_ok=True, mode=0o700)
    names = (idn.WORLD, *(idn.robot_identity(i) for i in range(robots)), idn.OPERATOR,
             idn.ROUTER)
    ca_key, ca_cert = _make_ca(swarm, days)
    ca_dir = out / "ca"
    ca_dir.mkdir(mode=0o700)
    (ca_dir / idn.CA_FILE).write_bytes(_cert_pem(ca_cert))
    _write_private(ca_dir / "ca.key", _key_pem(ca_key))
    for name in names:
        d = out / name
        if d.exists():
            shutil.rmtree(d)
        d.mkdir(mode=0o700)
        key, cert = _make_leaf(name, swarm, ca_key, ca_cert, days)
        (d / idn.CA_FILE).write_bytes(_cert_pem(ca_cert))
        (d / idn.CERT_FILE).write_bytes(_cert_pem(cert))
        _write_private(d / idn.KEY_FILE, _key_pem(key))
        meta = {"format": idn.FORMAT, "swarm": swarm, "name": name, "robots": robots}
        (d / idn.META_FILE).write_text(json.dumps(meta, indent=1) + "\n")
        conf = idn.identity_zenoh_config(d, name, swarm, robots)
        (d / idn.ZENOH_FILE).write_text(json.dumps(conf, indent=1) + "\n")
    return SwarmKeys(out.resolve(), swarm, robots, names)


# ------------------------------------------------------------------ command line


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    c = sub.add_parser("create", help="make a swarm's authority and one identity per member",
                       description=__doc__.split("\n\n")[0] if __doc__ else None)
    c.add_argument("--swarm", required=True, help="swarm name ([A-Za-z0-9_-]+)")
    c.add_argument("--robots", type=int, required=True,
                   help="robots 0..N-1, one identity each (the access rules name each)")
    c.add_argument("--out", type=Path, required=True, help="directory to write (made if needed)")
    c.add_argument("--days", type=int, default=DEFAULT_DAYS,
                   help=f"certificate validity in days (default {DEFAULT_DAYS})")
    c.add_argument("--force", action="store_true",
                   help="replace the keys already in --out (every old identity stops working)")
    c.add_argument("--json", action="store_true", help="print one JSON line")


def run(args: argparse.Namespace) -> int:
    try:
        made = create_swarm_keys(args.out, args.swarm, args.robots, args.days, args.force)
    except InputError as e:
        print(f"patternrl keys: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"patternrl keys: error: {e.strerror or e}: {e.filename or args.out}",
              file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"out": str(made.out), "swarm": made.swarm, "robots": made.robots,
                          "identities": list(made.names)}))
        return 0
    print(f"swarm {made.swarm}: authority {made.out / 'ca'} (keep ca.key private), "
          f"{len(made.names)} identities in {made.out}: world, robot-0..robot-{made.robots - 1}, "
          f"operator, router")
    print(f"copy {made.out / 'robot-<i>'} to robot i's host; run it with --identity DIR")
    return 0
