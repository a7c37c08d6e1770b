"""The training world under imperfect sensing: each robot's row is the one its robot process
builds from its own view (trainer/world/sensed.py against runtime/decision/local.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from runtime.brain.brain import load_brain
from runtime.conditions import parse_conditions
from runtime.decision.local import LocalDecisions, Perception
from runtime.decision.observation import ObservationSpec
from runtime.decision.patterns import make_pattern
from trainer.config import TrainConfig
from trainer.world.sensed import SensedRows
from trainer.world.training_world import BatchWorld


class RecordingBrain:
    """A brain that holds still and keeps every row it was given."""

    def __init__(self, spec: ObservationSpec) -> None:
        self.brain_id, self.spec, self.manifest = "recording", spec, None
        self.rows: list[np.ndarray] = []

    def act(self, obs: Any) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float64)
        self.rows.append(o.copy())
        return np.zeros((o.shape[0], 2))


@pytest.mark.parametrize("obs", ["plan", "general"])
@pytest.mark.parametrize("spec", ["realistic", "noise_m=0.1,latency_steps=2", "k_nearest=3",
                                  "landing", "late landing", "local landing"])
def test_each_robots_row_is_what_its_robot_builds_from_its_own_view(obs: str, spec: str) -> None:
    """``landing``: 10 cm noise with the team next to its slots, so that every plan lands in
    its averaged centroid frame (runtime.decision.settle) from the first step on; ``late
    landing``: exact views 3 steps late, the team next to its slots, so that every plan lands
    in the plan's frame it keeps, then in the centroid frame; ``local landing``: the first,
    each robot seeing its 3 nearest, so that its frame is the one its peers in view show."""
    E, n, seed = 2, 6, 7
    landing = spec in ("landing", "late landing", "local landing")
    spec = {"landing": "noise_m=0.1", "late landing": "latency_steps=3",
            "local landing": "noise_m=0.1,k_nearest=3"}.get(spec, spec)
    cond = parse_conditions(spec)
    ospec = ObservationSpec(obs, k_neighbours=4, travel_weight=0.25 if obs == "plan" else 0.0)
    rows = SensedRows(cond, ospec, E, n, seed)
    observer = np.tile(np.arange(n), E)
    seeds = [np.random.SeedSequence((seed, e, i)) for e in range(E) for i in range(n)]
    rows.perception = Perception(cond, observer, seeds, estimator=True)  # LocalDecisions' own
    brain = RecordingBrain(ospec)
    local = LocalDecisions(brain, E, n, cond, estimator=True, safety=None, seed=seed)
    rng = np.random.default_rng(3)
    pattern = np.stack([make_pattern("circle", n)] * E)
    pattern -= pattern.mean(axis=1, keepdims=True)
    truth = rng.uniform(0.0, 3.0, (E, n, 2))
    drift = rng.normal(0.0, 0.05, (E, n, 2))
    if landing:
        truth = pattern + 1.5 + rng.normal(0.0, 0.03, (E, n, 2))
        drift = rng.normal(0.0, 0.005, (E, n, 2))
    for _ in range(12 if landing else 6):
        brain.rows.clear()
        local.decide(truth, pattern)
        want = np.concatenate(brain.rows).reshape(E, n, -1)
        got, _ = rows.rows(truth, pattern)
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-5)
        truth = truth + drift


def test_a_training_world_under_sensing_steps_and_restarts_its_robots() -> None:
    """The shipped plan brain in a realistic training world: finite rows, episodes that end and
    start again (the robots' roll call), rewards and 'formed' from ground truth."""
    b = load_brain("exports/general.onnx")
    bw = BatchWorld(4, 8, "circle", b.spec, seed=3, conditions=parse_conditions("realistic"))
    perfect = BatchWorld(4, 8, "circle", b.spec, seed=3)
    obs = bw.observe()
    np.testing.assert_array_equal(obs, perfect.observe())  # the roll call: the team as it is
    still = np.zeros((4, 8, 2))
    assert not np.allclose(bw.step(still).obs, perfect.step(still).obs)  # then through noise
    ended = 0
    for _ in range(200):
        r = bw.step(b.act(obs.reshape(-1, obs.shape[-1])).reshape(4, 8, 2))
        obs = r.obs
        assert np.isfinite(obs).all() and np.isfinite(r.reward).all()
        if r.episode is not None:
            ended += len(r.episode.env_ids)
            assert r.episode.formed.any() or (r.episode.steps >= bw.step_limit).all()
    assert ended >= 4


def test_training_under_sensing_needs_a_row_observation() -> None:
    with pytest.raises(ValueError, match="general or plan"):
        TrainConfig(conditions="realistic", obs="paper")
    TrainConfig(conditions="realistic", obs="plan")
    with pytest.raises(ValueError, match="general and plan"):
        SensedRows(parse_conditions("realistic"), ObservationSpec("paper", n_robots=5), 1, 5, 0)
