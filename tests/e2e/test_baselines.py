"""End to end: the two rule-based baselines of docs/results.md, in the world over Zenoh.

``rule:assign`` with ``--safety off`` is the CAPT-style rule (shared assignment,
straight lines); with ``--safety orca`` it is the holonomic stand-in for the
paper's NH-ORCA baseline (the same slots, reached through ORCA). Each test runs
a real ``patternrl sim`` and one ``patternrl robot`` process per robot on
loopback, lockstep, and judges the run from the MCAP log alone: the pattern is
formed (recomputed from the recorded poses), collisions are recounted from the
poses (swept discs between consecutive steps) and must match what the world
logged, and the commands on the log show whether the filter was in the loop.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from runtime.decision.formation import assign_slots, collision_pairs, min_separation, slot_distances
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.reader import LogData, read_log

W = DEFAULT_WORLD
ROBOTS = 4
pytestmark = pytest.mark.timeout(90)


def _poses(run: LogData, step: int) -> np.ndarray:
    return run.frames.at(step)[1]


@pytest.mark.parametrize(
    ("safety", "extra"),
    [("off", ()), ("orca", ("--orca-time-horizon-s", "2"))],
    ids=["capt-style", "orca"],
)
def test_rule_baseline_forms_in_the_world(
    procs: Any, tmp_path: Path, kit: Any, safety: str, extra: tuple[str, ...]
) -> None:
    swarm, port = f"e2e-base-{safety}-{os.getpid()}", kit.free_port()
    log = tmp_path / f"{safety}.mcap"
    world = procs.world(swarm, port, "--robots", str(ROBOTS), "--patterns", "circle",
                        "--seed", "11", "--record", str(log), "--json", "--wait-robots-s", "60")
    robots = [procs.robot(swarm, port, i, "--safety", safety, *extra) for i in range(ROBOTS)]
    assert world.wait(timeout=60) == 0, procs.log("world")
    for r in robots:
        assert r.wait(timeout=30) == 0
    result = json.loads(procs.log("world").strip().splitlines()[-1])
    assert result["all_formed"], result

    run = read_log(log)
    assert run.recovery.finished and run.malformed == 0
    (end,) = run.events_of("phase_end")
    assert end["formed"] and end["n_robots"] == ROBOTS and end["deadline_misses"] == 0
    last = end["end_step"]
    assert run.frames.steps.tolist() == list(range(last + 1))  # lockstep: every step
    assert run.frames.present.all()  # and every robot at each

    # formed, from the poses: every robot within the tolerance of its slot
    (pattern,) = run.patterns
    C = np.asarray(pattern.msg.points)
    P = _poses(run, last)
    assert slot_distances(P, C, assign_slots(P, C)).max() <= W.formed_tol_m

    # collisions recounted from the poses (a pair counts when it starts touching)
    collisions, touching, sep = 0, set[tuple[int, int]](), np.inf
    for s in range(last):
        pairs = set(collision_pairs(_poses(run, s), _poses(run, s + 1), W))
        collisions += len(pairs - touching)
        touching = pairs
        sep = min(sep, float(min_separation(_poses(run, s + 1))))
    assert collisions == end["collisions"]
    assert sep == pytest.approx(end["min_separation_m"], abs=1e-5)

    # the commands on the log: every one from rule:assign, the filter in the loop or not
    cmds = run.commands
    assert len(cmds.step) >= ROBOTS * last and set(cmds.brain) == {"rule:assign"}
    changed = int(cmds.safety_changed.sum())
    if safety == "off":
        assert changed == 0
    else:
        assert changed > 0  # ORCA bent some commands on the way in
        assert collisions == 0 and sep >= W.min_separation_m - 1e-6
