"""benchmarks/paper_experiments.py and what it needs from ``patternrl eval``.

The script's pieces (paired comparison, methods, the document) on a tiny run
without the world; the evaluation's min separation, per-episode numbers and
ORCA time horizon, which the baselines' comparison rests on.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import pytest
from support import load_benchmark
from support.brains import trainer_sized_mlp, write_brain

from runtime.brain.brain import RULE_ASSIGN, load_brain
from runtime.decision.observation import ObservationSpec
from runtime.decision.safety import OrcaParams
from runtime.world_config import DEFAULT_WORLD
from trainer.evaluate import evaluate_brain


@pytest.fixture(scope="module")
def pe() -> ModuleType:
    return load_benchmark("paper_experiments")


def _stats(formed: list[bool], travel: list[float], steps: list[float]) -> Any:
    return SimpleNamespace(episode_stats={"formed": [float(f) for f in formed],
                                          "travel_m": travel, "steps": steps})


def test_paired_reduction_uses_only_episodes_both_formed(pe: ModuleType) -> None:
    a = _stats([True, True, False, True], [6.0, 6.0, 1.0, 100.0], [5, 5, 1, 5])
    b = _stats([True, True, True, False], [10.0, 10.0, 10.0, 1.0], [10, 10, 10, 10])
    r = pe.paired_reduction(a, b, "travel_m")
    assert r["episodes"] == 2 and r["reduction"] == pytest.approx(0.4)
    assert r["lo"] == pytest.approx(0.4) and r["hi"] == pytest.approx(0.4)  # no spread
    none = pe.paired_reduction(_stats([False], [1.0], [1]), b, "steps")
    assert none["episodes"] == 0 and np.isnan(none["reduction"])


def test_methods_cover_baselines_and_each_brain(pe: ModuleType) -> None:
    ms = pe.methods_for(["x/a.onnx"], [0.5, 1.0])
    assert [m.key for m in ms] == ["rule-off", "rule-orca-0.5", "rule-orca-1", "a-raw",
                                   "a-orca-0.5", "a-orca-1"]
    assert [m.tau for m in ms] == [None, 0.5, 1.0, None, 0.5, 1.0]
    assert [m.learned for m in ms] == [False, False, False, True, True, True]


def test_eval_reports_min_separation_and_per_episode_numbers() -> None:
    brain = load_brain(RULE_ASSIGN)
    two_r = DEFAULT_WORLD.min_separation_m
    res = {tau: evaluate_brain(brain, "circle", 6, 4, seed=3, progress=False,
                               safety=None if tau is None else OrcaParams(time_horizon_s=tau))
           for tau in (None, 0.5, 2.0)}
    for r in res.values():
        st = r.episode_stats
        assert {len(v) for v in st.values()} == {4}
        assert r.min_separation_m == pytest.approx(min(st["min_separation_m"]))
        formed = np.asarray(st["formed"], bool)
        ratio = np.asarray(st["travel_m"]) / np.asarray(st["lower_bound_travel_m"])
        assert r.travel_ratio == pytest.approx(ratio[formed].mean())
        assert "episode_stats" not in r.to_dict() and "min_separation_m" in r.to_dict()
    orca = res[2.0]
    assert orca.collisions == 0 and orca.min_separation_m >= two_r - 1e-6
    # same starts, whatever the filter: the lower bounds agree episode by episode
    assert res[None].episode_stats["lower_bound_travel_m"] == orca.episode_stats[
        "lower_bound_travel_m"]
    # a longer horizon is a more cautious filter: it never travels less here
    assert sum(orca.episode_stats["travel_m"]) > sum(res[0.5].episode_stats["travel_m"])


def test_eval_cli_takes_the_orca_time_horizon(capsys: pytest.CaptureFixture[str]) -> None:
    from patternrl.cli import main

    base = ["eval", "--brain", RULE_ASSIGN, "--pattern", "circle", "--robots", "5",
            "--episodes", "2", "--json", "--no-progress"]
    outs = []
    for tau in ("0.5", "2"):
        assert main([*base, "--orca-time-horizon-s", tau]) == 0
        outs.append(json.loads(capsys.readouterr().out))
    assert outs[0]["mean_steps"] != outs[1]["mean_steps"]
    assert main([*base, "--orca-time-horizon-s", "0"]) == 2


def test_tiny_run_writes_the_document(pe: ModuleType, tmp_path: Path) -> None:
    spec = ObservationSpec("general")
    brain = write_brain(tmp_path, "mlp", spec, trainer_sized_mlp(spec.dim), sidecar=False)
    out = tmp_path / "docs"
    rc = pe.main(["--ns", "4", "--episodes", "2", "--taus", "1", "--brains", str(brain),
                  "--out", str(out), "--fig5-dir", str(tmp_path / "none"), "--skip-world",
                  "--latency-samples", "20"])
    assert rc == 0
    doc = (out / "results.md").read_text()
    for part in ("## Headline", "## How this was run", "(a) n-regular polygons",
                 "Against rule + ORCA, tau = 1 s", "Not available in this run",
                 "(d) Per-decision latency", "mlp raw", "rule, no filter"):
        assert part in doc, part
    assert (out / "figures" / "polygons.png").stat().st_size > 0
    raw = json.loads((out / "results.json").read_text())
    taus = {f"{OrcaParams().time_horizon_s:g}", "1"}  # the default horizon and the paper's 1 s
    assert {p["method"] for p in raw["polygons"]} == {
        "rule-off", "mlp-raw", *(f"{m}-orca-{t}" for m in ("rule", "mlp") for t in taus)}
