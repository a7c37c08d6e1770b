"""Every shipped brain loads, passes onnx.checker, and performs as its manifest says."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import onnx
import pytest

from runtime.brain.brain import load_brain
from runtime.decision.safety import OrcaParams
from trainer.evaluate import evaluate_brain

EXPORTS = Path(__file__).resolve().parents[2] / "exports"
BRAINS = sorted(EXPORTS.glob("*.onnx"))
EXPECTED = [f"{p}-10-{o}.onnx" for p in ("circle", "cross", "heart", "line", "triangle")
            for o in ("general", "paper")] + ["general.onnx"]


def test_every_expected_brain_is_shipped() -> None:
    assert sorted(b.name for b in BRAINS) == sorted(EXPECTED)


@pytest.mark.parametrize("path", BRAINS, ids=lambda p: p.stem)
def test_brain_is_valid_and_manifest_is_consistent(path: Path) -> None:
    data = path.read_bytes()
    assert len(data) < 1_000_000  # a few hundred KB
    onnx.checker.check_model(onnx.load_from_string(data), full_check=True)
    manifest = json.loads(path.with_suffix(".json").read_text())
    assert manifest["brain_id"] == hashlib.sha256(data).hexdigest()
    brain = load_brain(str(path))
    assert brain.brain_id == manifest["brain_id"]
    assert brain.spec.to_dict() == manifest["observation"]
    ev = manifest["evaluation"]
    assert ev["episodes"] == 100 and ev["safety"] == "orca"


def _orca(manifest: dict[str, Any]) -> OrcaParams:
    """The safety filter the manifest's figures were measured with."""
    return OrcaParams(**manifest["evaluation"]["orca"])


@pytest.mark.parametrize("path", BRAINS, ids=lambda p: p.stem)
def test_fresh_seeds_agree_with_the_manifest(path: Path) -> None:
    """12 episodes on seeds it was neither trained nor evaluated on, ORCA on, as a robot runs it."""
    manifest = json.loads(path.with_suffix(".json").read_text())
    pattern = manifest["pattern"] or "random"
    res = evaluate_brain(load_brain(str(path)), pattern, manifest["n_robots"], 12, seed=424242,
                         safety=_orca(manifest), progress=False, hold_steps=0)  # as measured
    claimed = manifest["evaluation"]["success_rate"]
    # 12 episodes: a brain claiming 100 % may miss one; a brain claiming 0 % must not form.
    assert abs(res.success_rate - claimed) <= 0.25, (res.success_rate, claimed)
    if manifest["evaluation"]["collisions"] == 0:
        assert res.collisions == 0


def test_manifest_evaluation_is_reproduced_exactly() -> None:
    """`patternrl eval` with the manifest's seed and episodes gives the manifest's figures."""
    path = EXPORTS / "circle-10-general.onnx"
    manifest = json.loads(path.with_suffix(".json").read_text())
    ev = manifest["evaluation"]
    res = evaluate_brain(load_brain(str(path)), "circle", 10, ev["episodes"], seed=ev["seeds"][0],
                         safety=_orca(manifest), progress=False, hold_steps=ev.get("hold_steps", 0))
    assert res.success_rate == ev["success_rate"]
    assert res.collisions == ev["collisions"]
    # The lower-bound estimate gained starts after the brains were evaluated, so a bound can
    # come out a step tighter now: ratios agree to 1 %, outcomes exactly.
    assert res.steps_ratio == pytest.approx(ev["steps_ratio"], rel=0.01)
    assert res.travel_ratio == pytest.approx(ev["travel_ratio"], rel=0.01)
    assert res.formation_error == pytest.approx(ev["formation_error"], rel=1e-9)
