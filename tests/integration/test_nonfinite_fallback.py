"""A brain whose output turns NaN at run time, off its probe observations: the robots keep
forming with the fallback they were given (``--nonfinite-fallback``), and count it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper
from support import ROOT
from support.brains import write_brain
from support.stub_world import TEAM_DEADLINE, RobotProc, StubWorld

from runtime.brain.brain import load_brain, probe_observations
from runtime.decision.formation import collision_pairs, formation_error
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD
NEAR_M = 0.15
"""The brain answers NaN when its own slot is closer than this (L1, metres) but not at it."""


def nan_near_the_slot(directory: Path) -> Path:
    """The shipped general brain, made to answer NaN whenever the robot is within NEAR_M of
    its slot (columns 0:2 of its row; the all-zero row excepted): every probe passes."""
    model = onnx.load(ROOT / "exports" / "general.onnx")
    g = model.graph
    del model.metadata_props[:]
    for node in g.node:
        node.output[:] = ["action_raw" if o == "action" else o for o in node.output]
    g.initializer.extend([
        numpy_helper.from_array(np.array([0], np.int64), "c0"),
        numpy_helper.from_array(np.array([2], np.int64), "c2"),
        numpy_helper.from_array(np.array([1], np.int64), "ax1"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(np.array(NEAR_M, np.float32), "near"),
        numpy_helper.from_array(np.array(np.nan, np.float32), "nan"),
    ])
    g.node.extend([
        helper.make_node("Slice", ["obs", "c0", "c2", "ax1"], ["slot"]),
        helper.make_node("Abs", ["slot"], ["slot_abs"]),
        helper.make_node("ReduceSum", ["slot_abs", "ax1"], ["dist"], keepdims=1),
        helper.make_node("Greater", ["dist", "zero"], ["moved"]),
        helper.make_node("Less", ["dist", "near"], ["near_slot"]),
        helper.make_node("And", ["moved", "near_slot"], ["poisoned"]),
        helper.make_node("Where", ["poisoned", "nan", "zero"], ["poison"]),
        helper.make_node("Add", ["action_raw", "poison"], ["action"]),
    ])
    del g.value_info[:]
    onnx.checker.check_model(model)
    spec = load_brain(str(ROOT / "exports" / "general.onnx"), W).spec
    probes = probe_observations(spec, W)
    dist = np.abs(probes[:, 0:2]).sum(axis=1)
    assert not np.any((dist > 0) & (dist < NEAR_M)), "a probe would see the NaN"
    return write_brain(directory, "nan_near_slot", spec, model, sign=True)


def test_a_brain_nan_at_run_time_is_replaced_by_the_rule_and_counted(tmp_path: Path) -> None:
    brain = nan_near_the_slot(tmp_path)
    n = 4
    world = StubWorld("tnonfinite")
    robots = [RobotProc(world, i, str(brain), *TEAM_DEADLINE)  # --nonfinite-fallback rule
              for i in range(n)]
    try:
        world.wait_alive(set(range(n)), timeout=30.0)
        for i in range(n):
            world.wait_status(i, lambda s: True, 30.0, f"first status of robot {i}")
        C = world.publish_pattern("circle", n)
        rng = np.random.default_rng(5)
        pos = C + rng.uniform(-1.0, 1.0, (n, 2)) + np.array([1.0, 0.5])
        step, formed = 0, False
        while step < 120 and not formed:
            new, _ = world.lockstep(pos, step)
            assert collision_pairs(pos, new) == []
            pos, step = new, step + 1
            formed = formation_error(pos, C) < W.formed_tol_m
        assert formed, f"not formed in {step} steps: error {formation_error(pos, C):.3f} m"
        # every robot set 8 cm inward of its slot (no translation brings them back): each
        # comes back through the brain's NaN, whatever way it came the first time
        inward = pos.mean(axis=0) - pos
        pos = pos + 0.08 * inward / np.linalg.norm(inward, axis=1, keepdims=True)
        for _ in range(40):  # bounded: back in formation
            new, _ = world.lockstep(pos, step)
            assert collision_pairs(pos, new) == []
            pos, step = new, step + 1
            if formation_error(pos, C) < W.formed_tol_m:
                break
        assert formation_error(pos, C) < W.formed_tol_m, "not formed again"
        # the brain's NaN was met (within NEAR_M of the slot) and counted
        # a status a second: on a loaded machine the first one that counts may be slow to come
        sts = [world.wait_status(i, lambda s: s.nonfinite_fallbacks > 0, 30.0,
                                 f"robot {i} counting its fallbacks") for i in range(n)]
        assert all("decided by rule:frame-balanced" in s.last_error for s in sts)
        assert all(s.errors == 0 for s in sts), [s.last_error for s in sts]
    finally:
        for r in robots:
            r.interrupt()
        for r in robots:
            _, _, err = r.finish(timeout=15.0)
            assert "Traceback" not in err
        world.close()
