"""Brains: manifest, ONNX loading and validation, the rule brain."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from support.brains import GENERAL, mlp_model, write_brain

from runtime.brain.brain import (
    RULE_ASSIGN,
    Brain,
    BrainError,
    BrainManifest,
    OnnxBrain,
    RuleBrain,
    load_brain,
    load_sent_brain,
    probe_observations,
    read_brain_file,
    short_id,
    validate_brain_bytes,
)
from runtime.decision.observation import ObservationSpec
from runtime.world_config import DEFAULT_WORLD

# ----------------------------------------------------------------------------- manifest


def test_manifest_round_trip() -> None:
    m = BrainManifest(
        observation=ObservationSpec("paper", n_robots=10),
        brain_id="ab" * 32,
        file="x.onnx",
        pattern="heart",
        n_robots=10,
        world={"radius_m": 0.1},
        training={"episodes": 3},
        evaluation={"success": 1.0},
    )
    back = BrainManifest.from_json(m.to_json())
    assert back == m
    assert BrainManifest.from_dict(m.to_dict()) == m
    assert "brain_id" not in json.loads(m.to_json(with_id=False))


@pytest.mark.parametrize(
    "change, why",
    [
        ({"format": "other"}, "format"),
        ({"format_version": 2}, "format_version"),
        ({"observation": {"name": "nope"}}, "observation"),
        ({"action": {"kind": "polar", "v_max_mps": 1, "dt_s": 0.1}}, "kind"),
        ({"action": {"kind": "cartesian", "v_max_mps": -1, "dt_s": 0.1}}, "v_max_mps"),
        ({"n_robots": "ten"}, "n_robots"),
    ],
)
def test_manifest_refuses_bad_fields(change: dict[str, object], why: str) -> None:
    d = BrainManifest(observation=GENERAL).to_dict()
    d.update(change)
    with pytest.raises(BrainError, match=why):
        BrainManifest.from_dict(d)


def test_manifest_refuses_bad_json() -> None:
    with pytest.raises(BrainError, match="not valid JSON"):
        BrainManifest.from_json("{nope")
    with pytest.raises(BrainError, match="object"):
        BrainManifest.from_json("[1, 2]")


# ------------------------------------------------------------------------------ loading


def test_load_good_brain_with_sidecar(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "good")
    brain = load_brain(str(path))
    assert isinstance(brain, OnnxBrain) and isinstance(brain, Brain)
    assert brain.brain_id == hashlib.sha256(path.read_bytes()).hexdigest()
    assert brain.spec == GENERAL
    assert brain.manifest is not None and brain.manifest.brain_id == brain.brain_id
    obs = probe_observations(GENERAL)
    a = brain.act(obs)
    assert a.shape == (len(obs), 2) and a.dtype == np.float64
    np.testing.assert_array_equal(a, brain.act(obs))  # deterministic
    one = brain.act(obs[3:4])
    np.testing.assert_allclose(one[0], a[3], rtol=1e-5, atol=1e-6)


def test_load_from_metadata_without_sidecar(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "meta", sidecar=False)
    brain = load_brain(str(path))
    assert brain.brain_id == hashlib.sha256(path.read_bytes()).hexdigest()
    assert brain.manifest is not None and brain.manifest.file == "meta.onnx"


def test_load_refuses_brain_without_manifest(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "bare", sidecar=False, metadata=False)
    with pytest.raises(BrainError, match="no manifest"):
        load_brain(str(path))


def test_load_missing_file_and_unknown_rule(tmp_path: Path) -> None:
    with pytest.raises(BrainError, match="not found"):
        load_brain(str(tmp_path / "absent.onnx"))
    with pytest.raises(BrainError, match="unknown rule"):
        load_brain("rule:teleport")


def test_refuses_wrong_input_dim(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "wide", model=mlp_model(GENERAL.dim + 3))
    with pytest.raises(BrainError, match="obs_dim 39"):
        load_brain(str(path))


def test_refuses_nan_output(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "nan", model=mlp_model(GENERAL.dim, nan=True))
    with pytest.raises(BrainError, match="non-finite"):
        load_brain(str(path))


def test_refuses_corrupt_bytes(tmp_path: Path) -> None:
    data = write_brain(tmp_path, "corrupt").read_bytes()
    for bad in (data[: len(data) // 2], b"not an onnx model"):
        digest = hashlib.sha256(bad).hexdigest()
        with pytest.raises(BrainError, match="onnxruntime cannot load"):
            validate_brain_bytes(bad, BrainManifest(observation=GENERAL), digest)
    # bytes that still parse but whose weights are garbage are refused all the same
    mangled = bytearray(data)
    mangled[len(data) // 3 : len(data) // 3 + 64] = b"\xff" * 64
    digest = hashlib.sha256(bytes(mangled)).hexdigest()
    with pytest.raises(BrainError):
        validate_brain_bytes(bytes(mangled), BrainManifest(observation=GENERAL), digest)


def test_refuses_digest_mismatch(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "digest")
    data = path.read_bytes()
    manifest = BrainManifest(observation=GENERAL)
    with pytest.raises(BrainError, match="digest mismatch"):
        validate_brain_bytes(data, manifest, "0" * 64)
    # a sidecar that names other bytes
    side = json.loads(path.with_suffix(".json").read_text())
    side["brain_id"] = "f" * 64
    path.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(BrainError, match="digest mismatch"):
        load_brain(str(path))


def test_refuses_wrong_names_and_shapes() -> None:
    for model, why in [
        (mlp_model(GENERAL.dim, input_name="x"), "inputs"),
        (mlp_model(GENERAL.dim, out_dim=3), "action"),
        (mlp_model(GENERAL.dim, fixed_batch=True), "dynamic"),
    ]:
        data = model.SerializeToString()
        digest = hashlib.sha256(data).hexdigest()
        with pytest.raises(BrainError, match=why):
            validate_brain_bytes(data, BrainManifest(observation=GENERAL), digest)


def test_validated_brain_error_messages_are_one_line(tmp_path: Path) -> None:
    data = b"\x08\x07garbage"
    with pytest.raises(BrainError) as e:
        validate_brain_bytes(
            data, BrainManifest(observation=GENERAL), hashlib.sha256(data).hexdigest()
        )
    assert "\n" not in str(e.value)


def test_paper_brain_probes_and_loads(tmp_path: Path) -> None:
    spec = ObservationSpec("paper", n_robots=5)
    path = write_brain(tmp_path, "paper", spec=spec, model=mlp_model(spec.dim), pattern="circle")
    brain = load_brain(str(path))
    assert brain.spec == spec and brain.manifest is not None and brain.manifest.pattern == "circle"
    assert probe_observations(spec).shape[1] == spec.dim


# ------------------------------------------------------------------- reading brain files


def test_read_brain_file_of_a_rule() -> None:
    f = read_brain_file(RULE_ASSIGN)
    assert (f.ref, f.data, f.manifest, f.brain_id, f.rule) == (
        RULE_ASSIGN,
        b"",
        None,
        RULE_ASSIGN,
        RULE_ASSIGN,
    )
    assert json.loads(f.wire_manifest()) == {"rule": RULE_ASSIGN}
    assert isinstance(load_sent_brain(f.wire_manifest(), f.data), RuleBrain)
    with pytest.raises(BrainError, match="unknown rule"):
        read_brain_file("rule:teleport")


def test_read_brain_file_sidecar_then_metadata(tmp_path: Path) -> None:
    path = write_brain(tmp_path, "b")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    f = read_brain_file(str(path))
    assert f.rule is None and f.data == path.read_bytes() and f.brain_id == digest
    assert f.manifest is not None and f.manifest.file == "b.onnx" and f.session is None
    # the sidecar names other bytes: read as it says (the robots refuse it)
    side = json.loads(path.with_suffix(".json").read_text())
    side["brain_id"] = "f" * 64
    path.with_suffix(".json").write_text(json.dumps(side))
    assert read_brain_file(str(path)).brain_id == "f" * 64
    # sidecar=False reads the manifest inside the ONNX file: no id there, so the digest
    embedded = read_brain_file(str(path), sidecar=False)
    assert embedded.brain_id == digest and embedded.session is not None
    assert embedded.manifest is not None and embedded.manifest.observation == GENERAL
    bare = write_brain(tmp_path, "bare", sidecar=False, metadata=False)
    with pytest.raises(BrainError, match="no manifest"):
        read_brain_file(str(bare))
    with pytest.raises(BrainError, match="not found"):
        read_brain_file(str(tmp_path / "absent.onnx"))


def test_a_sent_brain_is_validated_like_a_file(tmp_path: Path) -> None:
    f = read_brain_file(str(write_brain(tmp_path, "sent")))
    brain = load_sent_brain(f.wire_manifest(), f.data)
    assert isinstance(brain, OnnxBrain) and brain.brain_id == f.brain_id
    with pytest.raises(BrainError, match="digest mismatch"):
        load_sent_brain(f.wire_manifest(), f.data + b"x")
    assert f.manifest is not None
    no_id = f.manifest.to_json(with_id=False)
    with pytest.raises(BrainError, match="no brain_id"):
        load_sent_brain(no_id, f.data)
    with pytest.raises(BrainError, match="not valid JSON"):
        load_sent_brain("{", f.data)


def test_short_id() -> None:
    assert short_id(RULE_ASSIGN) == RULE_ASSIGN
    assert short_id("0123456789abcdef" * 4) == "0123456789ab"


# ---------------------------------------------------------------------------- rule brain


def test_rule_brain_drives_to_slot_at_most_v_max() -> None:
    b = load_brain(RULE_ASSIGN)
    assert isinstance(b, RuleBrain) and b.brain_id == RULE_ASSIGN and b.manifest is None
    obs = np.zeros((3, b.spec.dim))
    obs[0, 0:2] = [3.0, 4.0]  # far: full speed toward it
    obs[1, 0:2] = [0.03, -0.04]  # within one step: land on it exactly
    a = b.act(obs)
    np.testing.assert_allclose(a[0], [0.6, 0.8])
    np.testing.assert_allclose(a[1], [0.3, -0.4])
    np.testing.assert_array_equal(a[2], [0.0, 0.0])
    for i in range(3):  # the single-row fast path gives the same numbers
        np.testing.assert_allclose(b.act(obs[i : i + 1])[0], a[i], rtol=0, atol=1e-15)
    assert np.linalg.norm(a, axis=1).max() <= DEFAULT_WORLD.v_max_mps
