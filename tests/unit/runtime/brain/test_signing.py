"""Signed brains: keys, signatures over bytes + manifest, trust, and ``patternrl brain``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support import ROOT
from support.brains import copy_shipped_brain

from runtime.brain.brain import BrainError, load_brain, load_sent_brain, read_brain_file
from runtime.brain.cli import sign_brain_file, verify_brain_file
from runtime.brain.signing import (
    RELEASE_PUBLIC_KEY,
    SignatureError,
    default_trust,
    generate_key,
    load_public_key,
)

EXPORTS = ROOT / "exports"


def test_the_release_key_ships_and_signs_every_shipped_brain() -> None:
    assert load_public_key(EXPORTS / "release-key.pub") == RELEASE_PUBLIC_KEY
    release_only = default_trust(user=False)
    for onnx in sorted(EXPORTS.glob("*.onnx")):
        assert verify_brain_file(str(onnx), release_only) == "release", onnx
    assert not list(EXPORTS.glob("release-key")), "the private half never ships"


def test_sign_verify_and_every_way_to_break_it(tmp_path: Path) -> None:
    brain = copy_shipped_brain(tmp_path)
    key = generate_key(tmp_path / "op")
    with pytest.raises(SignatureError, match="untrusted key"):  # still the release signature
        verify_brain_file(str(brain), default_trust(release=False, user=False))
    sign_brain_file(str(brain), key)
    trust = default_trust([tmp_path / "op.pub"], release=False, user=False)
    assert verify_brain_file(str(brain), trust) == "op.pub"
    assert load_brain(str(brain), trust=trust).brain_id == read_brain_file(str(brain)).brain_id
    # a trusted directory works the same
    assert verify_brain_file(str(brain), default_trust([tmp_path], user=False)) == "op.pub"
    with pytest.raises(BrainError, match="untrusted key"):
        load_brain(str(brain), trust=default_trust(user=False))
    side = brain.with_suffix(".json")
    signed = json.loads(side.read_text())
    # one field of the manifest changed: the signature no longer holds
    forged = dict(signed, evaluation={"success_rate": 1.0})
    side.write_text(json.dumps(forged))
    with pytest.raises(BrainError, match="does not match"):
        load_brain(str(brain), trust=trust)
    # no signature at all
    side.write_text(json.dumps({k: v for k, v in signed.items() if k != "signature"}))
    with pytest.raises(BrainError, match="not signed"):
        load_brain(str(brain), trust=trust)
    # a swap carrying the signed manifest with other bytes: refused before onnxruntime reads them
    data = brain.read_bytes()
    other = (EXPORTS / "circle-10-general.onnx").read_bytes()
    forged_id = dict(signed, brain_id=__import__("hashlib").sha256(other).hexdigest())
    with pytest.raises(BrainError, match="does not match"):
        load_sent_brain(json.dumps(forged_id), other, trust=trust)
    assert load_sent_brain(json.dumps(signed), data, trust=trust).brain_id == signed["brain_id"]
    # rule brains are code: no signature asked
    assert load_sent_brain('{"rule": "rule:assign"}', b"", trust=trust).brain_id == "rule:assign"


