"""The per-robot controller and the batch decision path: one pipeline, two callers."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from support.brains import onnx_brain
from support.rows import reference_rows

from runtime.brain.brain import BrainManifest, RuleBrain
from runtime.decision import formation
from runtime.decision.controller import Controller
from runtime.decision.formation import assign_slots, formation_error, slot_positions
from runtime.decision.observation import ObservationSpec
from runtime.decision.patterns import make_pattern
from runtime.decision.pipeline import (
    ERR_BRAIN,
    ERR_NONFINITE,
    ERR_TEAM,
    commands,
    decide_batch,
)
from runtime.decision.rules import plan_targets
from runtime.decision.safety import OrcaParams
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD


class ConstBrain:
    """Answers the same velocity for every robot (or raises)."""

    def __init__(self, v: tuple[float, float], spec: ObservationSpec | None = None) -> None:
        self.brain_id = f"const:{v}"
        self.spec = spec or ObservationSpec("general")
        self.manifest: BrainManifest | None = None
        self.v = v
        self.seen: list[NDArray[Any]] = []  # the rows it was asked about, copied

    def act(self, obs: NDArray[Any]) -> NDArray[np.float64]:
        self.seen.append(np.array(obs, copy=True))
        if self.v == (-1.0, -1.0):
            raise RuntimeError("broken brain")
        return np.tile(np.array(self.v, dtype=np.float64), (len(obs), 1))


def spread(n: int, rng: np.random.Generator, side: float = 3.0) -> NDArray[np.float64]:
    """n positions at least 2.5R apart."""
    pts: list[NDArray[np.float64]] = []
    while len(pts) < n:
        p = rng.uniform(0, side, 2)
        if all(np.linalg.norm(p - q) >= W.start_separation_m for q in pts):
            pts.append(p)
    return np.array(pts)


def run_team(
    n: int, pattern: str, steps: int, safety: OrcaParams | None, seed: int = 0
) -> tuple[NDArray[np.float64], list[NDArray[np.float64]], NDArray[np.float64]]:
    rng = np.random.default_rng(seed)
    pos = spread(n, rng)
    C = make_pattern(pattern, n)
    ctrls = [Controller(RuleBrain(), W, safety) for _ in range(n)]
    track = [pos]
    for t in range(steps):
        v = np.array([ctrls[i].decide(i, pos, C, t).velocity for i in range(n)])
        pos = pos + W.dt_s * v
        track.append(pos)
    return pos, track, C


# ----------------------------------------------------------------------- rule brain


def test_rule_brain_drives_straight_to_its_slot_and_stops() -> None:
    n = 6
    rng = np.random.default_rng(1)
    pos = spread(n, rng)
    C = make_pattern("circle", n)
    _, min_steps = formation.lower_bounds(pos, C)
    ctrls = [Controller(RuleBrain(), W, None) for _ in range(n)]
    formed_at = None
    for t in range(80):
        ds = [ctrls[i].decide(i, pos, C, t) for i in range(n)]
        slots = np.array([d.slot for d in ds])
        sv = slot_positions(pos, C, slots) - pos
        want = sv / W.dt_s
        sp = np.linalg.norm(want, axis=1, keepdims=True)
        want = np.where(sp > W.v_max_mps, want * W.v_max_mps / np.maximum(sp, 1e-300), want)
        v = np.array([d.velocity for d in ds])
        np.testing.assert_allclose(v, want, atol=1e-12)  # straight at its slot, <= v_max
        assert np.linalg.norm(v, axis=1).max() <= W.v_max_mps
        pos = pos + W.dt_s * v
        if formed_at is None and formation_error(pos, C) < 1e-9:
            formed_at = t + 1
        if formed_at is not None and t >= formed_at + 3:
            assert np.all(v == 0.0)  # parked: exactly still
    assert formed_at is not None and formed_at <= 1.1 * min_steps + 2


def test_rule_brain_with_safety_forms_without_collisions() -> None:
    n = 8
    pos, track, C = run_team(n, "cross", 120, safety=OrcaParams(), seed=3)
    assert formation_error(pos, C) < W.formed_tol_m
    for a, b in itertools.pairwise(track):
        assert formation.collision_pairs(a, b) == []


# ------------------------------------------------------------------------ contract


def test_clamps_to_v_max() -> None:
    rng = np.random.default_rng(0)
    pos = spread(5, rng)
    C = make_pattern("circle", 5)
    for safety in (None, OrcaParams()):
        c = Controller(ConstBrain((30.0, -40.0)), W, safety)
        d = c.decide(0, pos, C, 0)
        assert np.hypot(*d.velocity) <= W.v_max_mps
        assert d.brain_velocity == (30.0, -40.0)
        assert not d.error


@pytest.mark.parametrize("v", [(np.nan, 0.0), (0.0, np.inf), (-1.0, -1.0)])
def test_bad_brain_output_holds_still(v: tuple[float, float]) -> None:
    rng = np.random.default_rng(0)
    pos = spread(4, rng)
    c = Controller(ConstBrain(v), W)
    d = c.decide(1, pos, make_pattern("line", 4), 0)
    assert d.velocity == (0.0, 0.0) and not d.safety_changed
    assert d.error == (ERR_BRAIN if v == (-1.0, -1.0) else ERR_NONFINITE)
    assert d.slot >= 0  # the assignment was made before the brain ran
    if v != (-1.0, -1.0):  # the batch path holds a non-finite robot still too
        assert d.brain_velocity == v or np.isnan(d.brain_velocity[0])
        frames = np.stack([pos, pos, pos])[None]
        vel, _, changed = decide_batch(ConstBrain(v), frames, make_pattern("line", 4))
        assert np.all(vel == 0.0) and not changed.any()


def test_team_size_change_resets_history_and_slots() -> None:
    rng = np.random.default_rng(2)
    pos = spread(5, rng)
    c = Controller(RuleBrain(), W, None)
    c.decide(0, pos, make_pattern("circle", 5), 0)
    c.decide(0, pos + 0.05, make_pattern("circle", 5), 1)
    assert c.previous_slots is not None and len(c.previous_slots) == 5
    d = c.decide(0, pos[:4], make_pattern("circle", 4), 2)
    assert c.previous_slots is not None and len(c.previous_slots) == 4
    # fresh history: the velocity estimate in the observation is zero again
    assert not d.error


def test_wrong_pattern_size_or_paper_team_holds_still() -> None:
    rng = np.random.default_rng(2)
    pos = spread(5, rng)
    d = Controller(RuleBrain(), W).decide(0, pos, make_pattern("circle", 4), 0)
    assert d.velocity == (0.0, 0.0) and d.error == ERR_TEAM
    paper = ConstBrain((0.1, 0.0), ObservationSpec("paper", n_robots=4))
    d = Controller(paper, W).decide(0, pos, make_pattern("circle", 5), 0)
    assert d.velocity == (0.0, 0.0) and d.error == ERR_TEAM
    assert not paper.seen  # the brain was not asked


def test_set_brain_takes_effect_next_decision() -> None:
    rng = np.random.default_rng(4)
    pos = spread(3, rng) * 3
    C = make_pattern("line", 3)
    c = Controller(RuleBrain(), W, None)
    a = c.decide(0, pos, C, 0)
    c.set_brain(ConstBrain((0.25, 0.0)))
    b = c.decide(0, pos, C, 1)
    assert a.velocity != b.velocity and b.velocity == (0.25, 0.0)
    assert c.brain.brain_id.startswith("const:")


# ------------------------------------------------------- single path == shared builders


def test_controller_assignment_is_the_shared_one() -> None:
    rng = np.random.default_rng(7)
    for trial in range(40):
        n = int(rng.integers(2, 14)) if trial < 30 else int(rng.integers(20, 60))
        C = make_pattern("heart" if trial % 2 else "circle", n)
        c = Controller(RuleBrain(), W, None)
        prev_slots = None
        pos = spread(n, rng)
        for t in range(4):
            d = c.decide(int(rng.integers(0, n)), pos, C, t)
            ref = assign_slots(pos, C, prev_slots)
            assert c.previous_slots is not None
            np.testing.assert_array_equal(c.previous_slots, ref)
            assert not d.error
            prev_slots = ref
            pos = pos + rng.uniform(-0.1, 0.1, pos.shape)


def test_the_assignment_stays_the_shared_one_while_a_team_forms_and_holds() -> None:
    """Step after step the robot's solver starts warm from its last slots and potentials;
    its slots are still every step those of assign_slots with the hysteresis rule."""
    n = 30
    rng = np.random.default_rng(3)
    C = make_pattern("circle", n)
    pos = rng.uniform(0.0, 4.0, (n, 2))
    c = Controller(RuleBrain(), W, None)
    ref = None
    for t in range(120):
        vel = np.array([c.decide(i, pos, C, t).velocity for i in range(n)])
        ref = assign_slots(pos, C, ref)
        assert c.previous_slots is not None
        assert c.previous_slots.tolist() == ref.tolist(), t
        pos = pos + W.dt_s * vel + rng.normal(0.0, 1e-3, pos.shape)  # a little noise
    assert formation_error(pos, C) < 0.01  # it formed, and held under the noise


def test_commands_clamp_filter_and_hold_a_non_finite_robot_still() -> None:
    pos = np.array([[[0.0, 0.0], [0.25, 0.0], [3.0, 3.0]]])
    prev = pos - [[[-0.1, 0.0], [0.1, 0.0], [0.0, 0.0]]]  # 0 and 1 closing at 1 m/s each
    act = np.array([[[1.0, 0.0], [np.nan, 0.0], [3.0, 4.0]]])
    vel, changed = commands(act, pos, prev, None, W)  # the clamp only
    assert vel[0, 0].tolist() == [1.0, 0.0] and vel[0, 1].tolist() == [0.0, 0.0]
    assert vel[0, 2].tolist() == pytest.approx([0.6, 0.8], abs=1e-15)
    assert not changed.any()
    vel, changed = commands(act.reshape(3, 2), pos, prev, OrcaParams(), W)  # (E n, 2) too
    assert changed.tolist() == [[True, False, False]]  # 0 sees 1 closing: filtered
    assert vel[0, 1].tolist() == [0.0, 0.0]  # a non-finite brain velocity holds still
    assert vel[0, 0, 1] < -0.1 and np.hypot(*vel[0, 0]) <= W.v_max_mps  # it swerves right
    assert vel[0, 2].tolist() == pytest.approx([0.6, 0.8], abs=1e-15)  # alone: clamped only


@pytest.mark.parametrize("spec", [ObservationSpec("general", k_neighbours=3),
                                  ObservationSpec("general", k_neighbours=9),
                                  ObservationSpec("plan", k_neighbours=4, travel_weight=0.25)],
                         ids=["general-3", "general-9", "plan-4"])
def test_the_row_a_brain_reads_is_the_documented_row(spec: ObservationSpec) -> None:
    """Through the controller a brain reads the row of the layout, built from the shared
    assignment's slot (or the plan's) and the velocity estimate of the last two frames."""
    rng = np.random.default_rng(12)
    n = 7
    C = make_pattern("heart", n)
    pos = spread(n, rng, side=2.0)
    brain = ConstBrain((0.0, 0.0), spec)
    ctrls = [Controller(brain, W, None) for _ in range(n)]
    prev, slots = pos, None
    for t in range(3):
        brain.seen.clear()
        for i in range(n):
            ctrls[i].decide(i, pos, C, t)
        slots = assign_slots(pos, C, slots)  # with the hysteresis rule, as the robots
        if spec.name == "plan":
            target, K = plan_targets(pos[None], C[None], slots[None], spec.travel_weight, W)
            want = reference_rows(pos, prev, target[0], spec.k_neighbours, W, float(K[0]))
        else:
            want = reference_rows(pos, prev, slot_positions(pos, C, slots), spec.k_neighbours)
        got = np.concatenate(brain.seen)
        assert got.shape == (n, spec.dim)
        # the slot columns within the plan frame's rounding, the rest exactly
        np.testing.assert_allclose(got[:, :4], want[:, :4], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got[:, 4:], want[:, 4:])  # velocities, neighbours
        prev, pos = pos, pos + rng.uniform(-0.05, 0.05, pos.shape)


def test_a_repeated_step_refreshes_the_newest_frame() -> None:
    """Realtime: the same step decided again replaces frame t and keeps t-1, so the
    velocity estimate is the newest poses against the last step's."""
    pos0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    pos1, pos1b = pos0 + 0.02, pos0 + 0.05
    brain = ConstBrain((0.0, 0.0), ObservationSpec("general", k_neighbours=2))
    c = Controller(brain, W, None)
    C = make_pattern("line", 3)
    c.decide(0, pos0, C, 0)
    c.decide(0, pos1, C, 1)
    np.testing.assert_allclose(brain.seen[-1][0, 4:6], [0.2, 0.2], rtol=1e-12)
    c.decide(0, pos1b, C, 1)  # step 1 again, newer poses
    np.testing.assert_allclose(brain.seen[-1][0, 4:6], [0.5, 0.5], rtol=1e-12)
    c.decide(0, pos1b, C, 2)  # the next step shifts
    np.testing.assert_array_equal(brain.seen[-1][0, 4:6], [0.0, 0.0])
    c.decide(0, pos1b + 0.01, C, None)  # no step given: every call shifts
    c.decide(0, pos1b + 0.03, C, None)
    np.testing.assert_allclose(brain.seen[-1][0, 4:6], [0.2, 0.2], rtol=1e-12)


def test_a_swapped_brain_with_another_width_reads_its_own_row() -> None:
    rng = np.random.default_rng(6)
    pos = spread(6, rng)
    C = make_pattern("circle", 6)
    narrow = ConstBrain((0.1, 0.0), ObservationSpec("general", k_neighbours=2))
    wide = ConstBrain((0.0, 0.1), ObservationSpec("general", k_neighbours=8))
    c = Controller(narrow, W, None)
    assert c.decide(3, pos, C, 0).velocity == (0.1, 0.0)
    c.set_brain(wide)
    assert c.decide(3, pos, C, 1).velocity == (0.0, 0.1)
    c.set_brain(narrow)
    assert c.decide(3, pos, C, 2).velocity == (0.1, 0.0)
    assert [r.shape for r in narrow.seen] == [(1, 16), (1, 16)]
    assert [r.shape for r in wide.seen] == [(1, 46)]
    mask = wide.seen[0][0, 6:].reshape(8, 5)[:, 4]
    assert mask.tolist() == [1.0] * 5 + [0.0] * 3  # 5 others, padded to 8


def test_a_numpy_integer_robot_index_decides_as_a_python_int() -> None:
    pos = np.random.default_rng(0).uniform(0.0, 3.0, (5, 2))
    C = make_pattern("circle", 5)
    want = Controller(RuleBrain()).decide(2, pos, C, 0)
    got = Controller(RuleBrain()).decide(np.int64(2), pos, C, 0)  # type: ignore[arg-type]
    assert got.velocity == want.velocity and got.slot == want.slot


@pytest.mark.parametrize("kind", ["rule", "onnx-general", "onnx-paper"])
@pytest.mark.parametrize("safety", [None, OrcaParams()])
def test_single_and_batch_paths_agree(kind: str, safety: OrcaParams | None) -> None:
    rng = np.random.default_rng(11)
    n, E, T = 6, 3, 5
    if kind == "rule":
        brain: Any = RuleBrain()
    elif kind == "onnx-general":
        brain = onnx_brain(ObservationSpec("general"))
    else:
        brain = onnx_brain(ObservationSpec("paper", n_robots=n))
    C = make_pattern("circle", n)
    # E teams, each a random walk of T steps (close enough for the filter to act)
    walks = []
    for _ in range(E):
        p = spread(n, rng, side=1.2)
        w = [p]
        for _ in range(T - 1):
            w.append(w[-1] + rng.uniform(-0.08, 0.08, p.shape))
        walks.append(np.array(w))
    walks_a = np.array(walks)  # (E, T, n, 2)
    ctrls = [[Controller(brain, W, safety) for _ in range(n)] for _ in range(E)]
    prev_slots = None
    changed_any = False
    for t in range(T):
        frames = np.stack([walks_a[:, max(t - j, 0)] for j in range(3)], axis=1)  # (E,3,n,2)
        vel, slots, changed = decide_batch(brain, frames, C, prev_slots, safety, W)
        prev_slots = slots
        changed_any |= bool(changed.any())
        for e in range(E):
            for i in range(n):
                d = ctrls[e][i].decide(i, walks_a[e, t], C, t)
                assert d.slot == slots[e, i]
                if kind == "rule":  # same arithmetic throughout: the very same numbers
                    np.testing.assert_array_equal(d.velocity, vel[e, i])
                else:  # onnxruntime's batch and single-row kernels round differently
                    np.testing.assert_allclose(d.velocity, vel[e, i], rtol=1e-6, atol=1e-6)
                assert d.safety_changed == changed[e, i]
    if safety is not None:
        assert changed_any  # the comparison covered filtered decisions too


def test_controller_and_batch_agree_on_big_teams_with_the_filter() -> None:
    """40 robots in a tight square, ORCA on: the robot's decisions are decide_batch's."""
    rng = np.random.default_rng(8)
    n = 40
    C = make_pattern("circle", n)
    pos = rng.uniform(0.0, 3.5, (n, 2))
    ctrls = [Controller(RuleBrain()) for _ in range(n)]
    prev_pos, prev_slots = pos, None
    changed = 0
    for t in range(12):
        frames = np.stack([pos, prev_pos, prev_pos])[None]
        vel, slots, ch = decide_batch(RuleBrain(), frames, C, prev_slots, OrcaParams())
        for i in range(n):
            d = ctrls[i].decide(i, pos, C, t)
            assert d.slot == slots[0, i]
            # the rule brain's one-row path takes math.hypot, its batch np.hypot:
            # they may round the last bit differently, nothing else may differ
            np.testing.assert_allclose(d.velocity, vel[0, i], rtol=1e-12, atol=1e-15)
            assert d.safety_changed == ch[0, i]
        changed += int(ch.sum())
        prev_pos, prev_slots = pos, slots
        pos = pos + 0.1 * vel[0]
    assert changed > 0  # the filter acted


def test_decision_reports_latency_and_filter() -> None:
    rng = np.random.default_rng(5)
    pos = spread(10, rng, side=1.5)
    c = Controller(ConstBrain((1.0, 0.0)), W)
    d = c.decide(0, pos, make_pattern("circle", 10), 0)
    assert d.decision_us >= 0.0 and np.isfinite(d.decision_us)  # measured, not bounded
    assert d.safety_change_mps >= 0.0
