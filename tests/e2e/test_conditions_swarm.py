"""End to end under real-world conditions (the ``realistic`` preset): robots that sense the
world's poses with 5 cm noise, a step late and 10 % lost, and track their peers, in a world
whose wheels have a 10 % gain spread and actuation noise: the team forms and nothing
collides (ground truth, recomputed from the log's poses)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from runtime.decision.formation import assign_slots, slot_distances
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.log.reader import read_log

pytestmark = pytest.mark.timeout(180)
COND = "realistic"


def test_a_noisy_late_lossy_swarm_forms_without_collision(
    procs: Any, tmp_path: Path, kit: Any
) -> None:
    swarm, port, log = f"e2e-cond-{os.getpid()}", kit.free_port(), tmp_path / "cond.mcap"
    world = procs.world(swarm, port, "--robots", "6", "--patterns", "circle", "--seed", "4",
                        "--record", str(log), "--json", "--wait-robots-s", "60",
                        "--conditions", COND)
    robots = [procs.robot(swarm, port, i, "--exit-after-silence-s", "2", "--conditions", COND,
                          "--sensing-seed", "4", "--estimator", "--brain", "rule:frame-balanced")
              for i in range(6)]
    assert world.wait(timeout=150) == 0, procs.log("world")
    for r in robots:
        assert r.wait(timeout=30) == 0
    result = json.loads(procs.log("world").strip().splitlines()[-1])
    phase = result["phases"][0]
    assert phase["formed"] and phase["collisions"] == 0, phase

    run = read_log(log)
    P = run.frames.xy  # (steps, n, 2), ground truth
    assert run.frames.present.all()
    d = np.linalg.norm(P[:, :, None] - P[:, None], axis=-1)
    d[:, np.arange(6), np.arange(6)] = np.inf
    assert float(d.min()) >= DEFAULT_WORLD.min_separation_m - 1e-3
    end = run.events_of("phase_end")[0]["end_step"]
    pattern = np.asarray(run.events_of("pattern")[-1]["points"])
    _, final = run.frames.at(end)
    far = slot_distances(final, pattern, assign_slots(final, pattern)).max()
    assert far <= DEFAULT_WORLD.formed_tol_m
