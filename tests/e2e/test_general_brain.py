"""The shipped general brain: the launcher's default, and forming a shape it never saw.

``test_general_brain_forms_an_unseen_shape_over_zenoh`` runs the shipped brain
``exports/general.onnx`` (trained on random shapes only) in the world over Zenoh:
``patternrl sim`` and 13 ``patternrl robot`` processes on loopback, lockstep, on
a pattern file written here (a block arrow: a closed polygon with corners, which
the training shapes, smooth closed curves, open polylines and scattered points,
are not). The verdict comes from the MCAP log alone
(:func:`sim_bridge.log.report.report_log` recomputes every figure from the poses):
formed, no collision, every command from the general brain.

The brain is a shipped file: when it is missing the test fails (it does not
skip). ``PATTERNRL_GENERAL_BRAIN=path.onnx`` points it at another general brain.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

from runtime.brain.brain import RULE_ASSIGN, load_brain
from runtime.world_config import DEFAULT_WORLD

ROOT = Path(__file__).resolve().parents[2]
GENERAL_ENV = "PATTERNRL_GENERAL_BRAIN"
ROBOTS = 13
ARROW = [(-1.5, -0.25), (0.3, -0.25), (0.3, -0.7), (1.2, 0.0), (0.3, 0.7), (0.3, 0.25),
         (-1.5, 0.25)]
"""A block arrow pointing along +x, metres: shaft 1.8 x 0.5, head 0.9 long and 1.4 wide."""


def shipped_general_brain() -> Path:
    """``exports/general.onnx`` (or ``$PATTERNRL_GENERAL_BRAIN``); fails when it is missing."""
    path = Path(os.environ.get(GENERAL_ENV) or ROOT / "exports" / "general.onnx")
    if not path.is_file():
        pytest.fail(f"the shipped general brain {path} is missing "
                    "(scripts/train_shipped.sh any trains it)")
    return path


@pytest.mark.timeout(120)
def test_general_brain_forms_an_unseen_shape_over_zenoh(procs: Any, tmp_path: Path,
                                                        kit: Any) -> None:
    from runtime.decision.patterns import make_pattern
    from sim_bridge.log.report import report_log

    brain_path = shipped_general_brain()
    brain = load_brain(str(brain_path))
    assert brain.spec.needs_slots and brain.spec.accepts_team(ROBOTS)  # general or plan
    arrow = tmp_path / "arrow.json"
    arrow.write_text(json.dumps({"points": ARROW, "closed": True}))
    make_pattern(arrow, ROBOTS)  # a valid pattern for 13 (and fewer) robots

    swarm, port, log = f"e2e-general-{os.getpid()}", kit.free_port(), tmp_path / "general.mcap"
    world = procs.world(swarm, port, "--robots", str(ROBOTS), "--patterns", str(arrow),
                        "--seed", "11", "--record", str(log), "--wait-robots-s", "60", "--json")
    for i in range(ROBOTS):  # started together: each one's start-up overlaps the others'
        procs.start(f"robot{i}", "robot", "--swarm", swarm, "--id", str(i), "--zenoh-port",
                    str(port), "--brain", str(brain_path))
    assert world.wait(timeout=100) == 0, procs.log("world")[-3000:]
    result = json.loads(procs.log("world").strip().splitlines()[-1])
    assert result["all_formed"], result

    rep = report_log(log)
    assert rep.finished and rep.outcome == "done" and rep.malformed == 0
    (phase,) = rep.phases
    assert phase.pattern == "arrow" and phase.n_robots == ROBOTS and not phase.lost
    assert phase.formed and phase.final_error_m is not None
    assert phase.final_error_m <= DEFAULT_WORLD.formed_tol_m
    assert phase.collisions == 0
    assert phase.min_separation_m is not None
    assert phase.min_separation_m >= DEFAULT_WORLD.min_separation_m
    assert set(phase.brains) == {brain.brain_id}  # every command came from the general brain
    assert phase.swaps_accepted == 0
    # the world's own verdict agrees with the log (the lower bound on steps may not: it is
    # an estimate that the rounding of the logged poses can move by a step)
    assert not {"formed", "steps", "collisions", "min_separation_m"} & set(phase.mismatches)


def test_launcher_runs_the_general_brain_by_default(tmp_path: Path, kit: Any,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from runtime.errors import InputError
    from sim_bridge.world.brain_choice import GENERAL_BRAIN, pick_brains

    ex = tmp_path / "exports"
    ex.mkdir()
    for name, obs, pattern, n in [("circle-10-paper", "paper", "circle", 10),
                                  ("line-10-paper", "paper", "line", 10),
                                  ("circle-10-general", "general", "circle", None),
                                  ("line-10-general", "general", "line", None)]:
        kit.write_test_brain(ex, name, obs, pattern, n)
    pats = ["circle", "line"]
    # no general brain yet: the per-pattern brains, else the rule
    chosen, _ = pick_brains("auto", pats, 10, "general", search=(ex,))
    assert {p: Path(c.ref).stem for p, c in chosen.items()} == {
        "circle": "circle-10-general", "line": "line-10-general"}
    chosen, line = pick_brains("auto", [*pats, "heart"], 10, "general", search=(ex,))
    assert {c.ref for c in chosen.values()} == {RULE_ASSIGN} and "heart" in line

    general = kit.write_test_brain(ex, "general", seed=1)
    assert general.name == GENERAL_BRAIN
    for patterns, n in [(pats, 10), ([*pats, "heart", "cross", "triangle"], 13)]:
        chosen, line = pick_brains("auto", patterns, n, "general", search=(ex,))
        assert set(chosen) == set(patterns)
        assert {c.ref for c in chosen.values()} == {str(general)}  # one brain: no swaps
        assert {c.kind for c in chosen.values()} == {"general"}
        assert "general.onnx" in line and "general.onnx" in chosen["circle"].label
    # the default search starts in ./exports
    monkeypatch.chdir(tmp_path)
    chosen, _ = pick_brains("auto", pats, 10, "general")
    assert {c.ref for c in chosen.values()} == {str(Path("exports") / GENERAL_BRAIN)}

    # the paper brains stay selectable, and so do the rule and any brain file
    for value, search in [("exports", None), ("auto", (ex,))]:
        chosen, _ = pick_brains(value, pats, 10, "paper", search=search)
        assert {p: Path(c.ref).stem for p, c in chosen.items()} == {
            "circle": "circle-10-paper", "line": "line-10-paper"}
        assert {c.kind for c in chosen.values()} == {"paper"}
    chosen, _ = pick_brains(RULE_ASSIGN, pats, 10, "general")
    assert {c.ref for c in chosen.values()} == {RULE_ASSIGN}
    chosen, _ = pick_brains(str(ex / "circle-10-general.onnx"), [*pats, "heart"], 7, "general")
    assert {Path(c.ref).stem for c in chosen.values()} == {"circle-10-general"}
    with pytest.raises(InputError, match="10 robots, not 7"):
        pick_brains(str(ex / "circle-10-paper.onnx"), pats, 7, "general")

    # an unreadable general brain is passed over, and the line says why
    (ex / "general.json").write_text("{not json")
    chosen, line = pick_brains("auto", pats, 10, "general", search=(ex,))
    assert Path(chosen["circle"].ref).stem == "circle-10-general" and "general" in line
