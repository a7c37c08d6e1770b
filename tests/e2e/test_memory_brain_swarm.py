"""A brain with memory drives robot processes over Zenoh: each robot validates it (its memory
input and output probed), carries its memory from step to step and forms the pattern.

The brain is the shipped general brain grown to read its last three rows
(:func:`trainer.ppo.networks.with_memory`: the weights on the older rows at zero, so it forms
as the general brain does), exported as ``patternrl train --memory-frames 3`` exports one.
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from runtime.brain.brain import BrainManifest, load_brain

ROOT = Path(__file__).resolve().parents[2]
ROBOTS = 6
FRAMES = 3


@pytest.mark.timeout(120)
def test_robots_run_a_brain_with_memory_and_form(procs: Any, tmp_path: Path, kit: Any) -> None:
    from sim_bridge.log.report import report_log
    from trainer.config import TrainConfig
    from trainer.ppo.export import agent_from_onnx, write_brain
    from trainer.ppo.networks import with_memory

    general = load_brain(str(ROOT / "exports" / "general.onnx"))
    assert general.manifest is not None
    spec = general.manifest.observation
    cfg = TrainConfig(obs=spec.name, travel_weight=spec.travel_weight)
    agent = agent_from_onnx(ROOT / "exports" / "general.onnx", cfg, 1.0)
    grown = with_memory(agent, FRAMES, cfg.with_(residual=agent.residual,
                                                 memory_frames=FRAMES), 1.0)
    path = tmp_path / "mem.onnx"
    write_brain(grown, path, BrainManifest(observation=replace(spec, frames=FRAMES)))
    brain = load_brain(str(path))
    assert brain.spec.memory_dim == (FRAMES - 1) * spec.dim

    swarm, port, log = f"e2e-memory-{os.getpid()}", kit.free_port(), tmp_path / "mem.mcap"
    world = procs.world(swarm, port, "--robots", str(ROBOTS), "--patterns", "circle",
                        "--seed", "5", "--record", str(log), "--wait-robots-s", "60", "--json")
    for i in range(ROBOTS):
        procs.start(f"robot{i}", "robot", "--swarm", swarm, "--id", str(i), "--zenoh-port",
                    str(port), "--brain", str(path))
    assert world.wait(timeout=100) == 0, procs.log("world")[-3000:]
    result = json.loads(procs.log("world").strip().splitlines()[-1])
    assert result["all_formed"], result
    rep = report_log(log)
    (phase,) = rep.phases
    assert phase.formed and phase.collisions == 0
    assert set(phase.brains) == {brain.brain_id}  # every command from the brain with memory
