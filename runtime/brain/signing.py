"""Signed brains: ed25519 keys, a brain's signature, and the keys a robot trusts.

A brain's manifest carries ``signature``::

    {"alg": "ed25519", "public_key": "<64 hex>", "value": "<128 hex>"}

``value`` signs :func:`signed_bytes`: a fixed domain line, the sha256 of the ONNX
bytes and the canonical manifest (sorted keys, no spaces, without the
``signature`` field, with ``brain_id`` set to that sha256). Changing one byte of
the ONNX file or one field of the manifest breaks the signature. Rule brains
(``rule:assign``) are code, not files, and need none.

Keys are OpenSSH ed25519 files, as ``ssh-keygen -t ed25519`` writes them: a
private key ``NAME`` (mode 0600) and its public half ``NAME.pub``. The user's
own key is ``$PATTERNRL_HOME/brain-key`` (default ``~/.config/patternrl``),
made on first use by ``patternrl train`` or ``patternrl brain keygen``.

A robot trusts (:func:`default_trust`): the project's release key (its public
half ships as ``exports/release-key.pub``), the user's own key when it exists,
and every ``--trust`` key or directory of ``*.pub`` files (``launch`` passes its
per-run operator key this way).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

# Only ed25519 at import (~15 ms): cryptography's key-file serialisation costs ~80 ms and
# ~8 MB more, so it is imported where a private key is written or read, never by a robot.
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from runtime.errors import InputError

__all__ = [
    "ALG",
    "RELEASE_PUBLIC_KEY",
    "SignatureError",
    "TrustedKeys",
    "default_trust",
    "generate_key",
    "home_dir",
    "key_id",
    "load_private_key",
    "load_public_key",
    "run_operator_key",
    "sign_manifest",
    "signed_bytes",
    "user_key",
    "verify_manifest",
]

ALG: Final = "ed25519"
DOMAIN: Final = b"patternrl brain signature v1\n"
SIGNATURE_KEY: Final = "signature"
USER_KEY_NAME: Final = "brain-key"
RELEASE_PUBLIC_KEY: Final = "88ee5fc53398a470b60dbf596beac1e264539ace7b4cb05d66e8ab319c07d685"
"""The project's release key (raw ed25519 public key, hex): ``exports/release-key.pub``."""


class SignatureError(InputError):
    """A signature missing, malformed or by an untrusted key; the message is one line."""


def home_dir() -> Path:
    """Where the user's key lives: ``$PATTERNRL_HOME``, else ``~/.config/patternrl``."""
    env = os.environ.get("PATTERNRL_HOME")
    return Path(env) if env else Path.home() / ".config" / "patternrl"


def key_id(public_hex: str) -> str:
    """A short name for a key: the first 16 hex digits of the sha256 of its raw bytes."""
    return hashlib.sha256(bytes.fromhex(public_hex)).hexdigest()[:16]


def _raw_hex(pub: Ed25519PublicKey) -> str:
    return pub.public_bytes_raw().hex()


# ------------------------------------------------------------------ key files


def generate_key(path: Path, comment: str = "patternrl brain key") -> Path:
    """Write a new private key ``path`` (0600) and ``path.pub``; refuses to overwrite."""
    pub_path = path.with_name(path.name + ".pub")
    if path.exists() or pub_path.exists():
        raise InputError(f"key {path} already exists: not overwritten")
    from cryptography.hazmat.primitives import serialization

    key = Ed25519PrivateKey.generate()
    private = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.OpenSSH,
        serialization.NoEncryption(),
    )
    public = key.public_key().public_bytes(
        serialization.Encoding.OpenSSH, serialization.PublicFormat.OpenSSH
    )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(private)
        pub_path.write_bytes(public + b" " + comment.encode() + b"\n")
    except OSError as e:
        raise InputError(f"cannot write key {path}: {e.strerror or e}") from None
    return path


def user_key(create: bool = True) -> Path | None:
    """The user's own private key, made on first use when ``create`` (else None if absent)."""
    path = home_dir() / USER_KEY_NAME
    if not path.exists() and create:
        generate_key(path, f"patternrl key of {os.environ.get('USER', 'user')}")
    return path if path.exists() else None


def run_operator_key(folder: str | Path) -> Path:
    """A fresh key pair ``folder/operator-key`` (and ``.pub``) for one run; replaces an old one.

    ``patternrl launch`` makes it and its robots trust it, so the operator of a
    run can sign a brain to hot-swap into that run and no other.
    """
    path = Path(folder) / "operator-key"
    for old in (path, path.with_name(path.name + ".pub")):
        try:
            old.unlink()
        except FileNotFoundError:
            pass
        except OSError as e:
            raise InputError(f"cannot replace key {old}: {e.strerror or e}") from None
    return generate_key(path, "patternrl launch operator key")


def load_private_key(path: str | Path) -> Ed25519PrivateKey:
    """An OpenSSH (or PEM PKCS8) ed25519 private key; :class:`InputError` if unusable."""
    from cryptography.hazmat.primitives import serialization

    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read key {p}: {e.strerror or e}") from None
    try:
        if b"OPENSSH PRIVATE KEY" in data:
            key: Any = serialization.load_ssh_private_key(data, password=None)
        else:
            key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as e:
        raise InputError(f"key {p} is not an unencrypted private key: {e}") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise InputError(f"key {p} is not an ed25519 key")
    return key


def load_public_key(path: str | Path) -> str:
    """The raw public key (hex) of a ``.pub`` file (OpenSSH ``ssh-ed25519 ...`` line)."""
    p = Path(path)
    try:
        data = p.read_bytes().strip()
    except OSError as e:
        raise InputError(f"cannot read public key {p}: {e.strerror or e}") from None
    # "ssh-ed25519 <base64 of: u32 len, 'ssh-ed25519', u32 len, 32 key bytes> [comment]"
    parts = data.split()
    if len(parts) < 2 or parts[0] != b"ssh-ed25519":
        raise InputError(f"{p} is not an OpenSSH ed25519 public key ('ssh-ed25519 AAAA...')")
    try:
        blob = base64.b64decode(parts[1], validate=True)
        (n,) = struct.unpack_from(">I", blob, 0)
        name = blob[4 : 4 + n]
        (m,) = struct.unpack_from(">I", blob, 4 + n)
        raw = blob[8 + n : 8 + n + m]
    except (binascii.Error, struct.error, ValueError):
        raw, name, m = b"", b"", 0
    if name != b"ssh-ed25519" or m != 32 or len(raw) != 32 or 8 + n + m != len(blob):
        raise InputError(f"{p} is not an OpenSSH ed25519 public key ('ssh-ed25519 AAAA...')")
    return raw.hex()


# ------------------------------------------------------------------ trust


@dataclass(frozen=True)
class TrustedKeys:
    """The public keys (raw hex) whose brains a robot runs, with where each came from."""

    keys: dict[str, str]
    """raw public key hex -> its origin (a file name, ``release``)."""

    def names(self) -> str:
        return ", ".join(f"{key_id(k)[:8]} ({o})" for k, o in self.keys.items()) or "none"


def _pub_files(ref: str | Path) -> list[Path]:
    p = Path(ref)
    if p.is_dir():
        return sorted(p.glob("*.pub"))
    if not p.exists():
        raise InputError(f"trusted key {p}: no such file or directory")
    return [p]


def default_trust(extra: Iterable[str | Path] = (), *, release: bool = True,
                  user: bool = True) -> TrustedKeys:
    """The release key, the user's own key (if it exists) and every ``extra`` key or dir."""
    keys: dict[str, str] = {}
    if release:
        keys[RELEASE_PUBLIC_KEY] = "release"
    if user:
        own = home_dir() / (USER_KEY_NAME + ".pub")
        if own.is_file():
            try:
                keys.setdefault(load_public_key(own), "own key")
            except InputError:
                pass  # a broken own key trusts nothing; signing with it says why
    for ref in extra:
        for f in _pub_files(ref):
            keys.setdefault(load_public_key(f), f.name)
    return TrustedKeys(keys)


# ------------------------------------------------------------------ signatures


def _canonical(manifest: dict[str, Any], digest: str) -> bytes:
    body = {k: v for k, v in manifest.items() if k != SIGNATURE_KEY}
    body["brain_id"] = digest
    return json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True,
                      allow_nan=False).encode("ascii")


def signed_bytes(manifest: dict[str, Any], digest: str) -> bytes:
    """What a brain's signature signs: domain, sha256 of the ONNX bytes, canonical manifest."""
    return DOMAIN + digest.encode("ascii") + b"\n" + _canonical(manifest, digest)


def sign_manifest(manifest: dict[str, Any], digest: str, key: Ed25519PrivateKey) -> dict[str, str]:
    """The ``signature`` field for ``manifest`` (a dict) of the brain whose sha256 is ``digest``."""
    value = key.sign(signed_bytes(manifest, digest))
    return {"alg": ALG, "public_key": _raw_hex(key.public_key()), "value": value.hex()}


def verify_manifest(manifest: dict[str, Any], digest: str, trust: TrustedKeys) -> str:
    """Check the signature of a manifest (a dict); the signer's origin, or SignatureError."""
    sig = manifest.get(SIGNATURE_KEY)
    if sig is None:
        raise SignatureError("brain is not signed (patternrl brain sign FILE --key KEY)")
    if not isinstance(sig, dict) or sig.get("alg") != ALG:
        raise SignatureError(f"brain signature must be an {ALG} object")
    pub, value = sig.get("public_key"), sig.get("value")
    try:
        raw_pub = bytes.fromhex(pub) if isinstance(pub, str) else b""
        raw_sig = bytes.fromhex(value) if isinstance(value, str) else b""
    except ValueError:
        raw_pub = raw_sig = b""
    if len(raw_pub) != 32 or len(raw_sig) != 64:
        raise SignatureError("brain signature is malformed (public_key or value)")
    origin = trust.keys.get(raw_pub.hex())
    if origin is None:
        raise SignatureError(f"brain is signed by untrusted key {key_id(raw_pub.hex())}")
    try:
        Ed25519PublicKey.from_public_bytes(raw_pub).verify(raw_sig, signed_bytes(manifest, digest))
    except InvalidSignature:
        raise SignatureError(
            f"brain signature by key {key_id(raw_pub.hex())} does not match its bytes and manifest"
        ) from None
    return origin
