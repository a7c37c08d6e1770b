"""``patternrl brain``: make a signing key, sign a brain, verify a brain's signature.

::

    patternrl brain keygen [--out PATH]          a new ed25519 key pair (PATH, PATH.pub)
    patternrl brain sign FILE.onnx [--key K]     sign FILE's manifest (the sidecar FILE.json)
    patternrl brain verify FILE.onnx [--trust K.pub ...] [--json]

``sign`` validates the brain as a robot would, then writes its sidecar with a
``signature`` (:mod:`runtime.brain.signing`); the ONNX bytes are never changed. The
key defaults to the user's own (``$PATTERNRL_HOME/brain-key``, made on first
use). ``verify`` checks the signature against the keys a robot trusts by default
(the release key and the user's own) plus every ``--trust`` key or directory.

Exit codes: 0 done (verify: the signature holds); 1 verify: unsigned, untrusted
or broken signature; 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from runtime.brain.brain import BrainError, BrainManifest, brain_digest, open_brain, read_brain_file
from runtime.brain.brain import sidecar_path as _sidecar
from runtime.brain.signing import (
    SignatureError,
    TrustedKeys,
    default_trust,
    generate_key,
    home_dir,
    key_id,
    load_private_key,
    load_public_key,
    sign_manifest,
    user_key,
    verify_manifest,
)
from runtime.errors import InputError
from runtime.log import one_line

__all__ = ["add_arguments", "run", "sign_brain_file", "verify_brain_file"]


def _onnx_file(ref: str) -> tuple[BrainManifest, bytes]:
    brain = read_brain_file(ref)
    if brain.manifest is None:
        raise InputError(f"{ref} is a rule brain: code, not a file, it needs no signature")
    return brain.manifest, brain.data


def sign_brain_file(ref: str, key: str | Path | None = None) -> BrainManifest:
    """Sign the brain ``ref`` (.onnx) with ``key`` (default: the user's); its sidecar is rewritten.

    The brain is validated first: a signer vouches for what it signs.
    """
    brain = read_brain_file(ref)
    if brain.manifest is None:
        raise InputError(f"{ref} is a rule brain: code, not a file, it needs no signature")
    open_brain(brain)
    private = load_private_key(key if key is not None else user_key(create=True) or "")
    manifest = brain.manifest
    manifest.signature = None
    manifest.brain_id = brain_digest(brain.data)
    manifest.signature = sign_manifest(manifest.to_dict(), manifest.brain_id, private)
    side = _sidecar(ref)
    try:
        side.write_text(manifest.to_json(with_id=True) + "\n", encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot write manifest {side}: {e.strerror or e}") from None
    return manifest


def verify_brain_file(ref: str, trust: TrustedKeys) -> str:
    """The origin of the trusted key that signed ``ref``; :class:`SignatureError` if none."""
    manifest, data = _onnx_file(ref)
    return verify_manifest(manifest.to_dict(), brain_digest(data), trust)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    kg = sub.add_parser("keygen", help="make a new ed25519 key pair (private, and .pub)")
    kg.add_argument("--out", type=Path, default=None,
                    help="private key path (default: the user's own, $PATTERNRL_HOME/brain-key)")
    sg = sub.add_parser("sign", help="sign a brain's manifest (writes its sidecar .json)")
    sg.add_argument("file", help="the brain (.onnx; its manifest is the sidecar or metadata)")
    sg.add_argument("--key", default=None,
                    help="private key (default: the user's own, made on first use)")
    vf = sub.add_parser("verify", help="check a brain's signature against trusted keys")
    vf.add_argument("file", help="the brain (.onnx)")
    vf.add_argument("--trust", action="append", default=[], metavar="KEY.pub",
                    help="also trust this public key or directory of *.pub (repeatable)")
    vf.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    err = f"patternrl brain {args.action}: error:"
    try:
        if args.action == "keygen":
            path = args.out if args.out is not None else home_dir() / "brain-key"
            generate_key(path)
            pub = load_public_key(str(path) + ".pub")
            print(f"{path} and {path}.pub (key {key_id(pub)})")
            return 0
        if args.action == "sign":
            sig = sign_brain_file(args.file, args.key).signature or {}
            print(f"{args.file}: signed by key {key_id(sig['public_key'])} "
                  f"(manifest {_sidecar(args.file)})")
            return 0
        trust = default_trust(args.trust)
        try:
            origin = verify_brain_file(args.file, trust)
            ok, reason = True, f"signed by {origin}"
        except SignatureError as e:
            ok, reason = False, one_line(str(e))
        if args.json:
            print(json.dumps({"file": args.file, "ok": ok, "reason": reason}))
        else:
            print(f"{args.file}: {'OK' if ok else 'REFUSED'}: {reason}")
        return 0 if ok else 1
    except (InputError, BrainError) as e:
        print(f"{err} {one_line(str(e))}", file=sys.stderr)
        return 2
