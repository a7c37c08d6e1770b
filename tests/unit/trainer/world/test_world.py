"""Tests of the batch training world (trainer/world/training_world.py)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.decision.formation import (
    assign_slots_batch,
    count_collisions,
    formation_error_batch,
    is_formed,
    min_separation,
    robot_pairs,
    slot_distances,
    slot_positions,
    swept_contacts,
    swept_pair_distance,
)
from runtime.decision.observation import ObservationSpec, general_observation, paper_observation
from runtime.decision.patterns import make_pattern
from runtime.world_config import DEFAULT_WORLD
from trainer.world.contacts import CONTACT_TOL_M
from trainer.world.reward import PAPER_REWARD, RewardConfig
from trainer.world.training_world import BatchWorld

W = DEFAULT_WORLD
TWO_R = W.min_separation_m
REACH = W.max_step_m
GENERAL = ObservationSpec("general", k_neighbours=4)
Arr = npt.NDArray[np.float64]


def make(n_envs: int = 4, n_robots: int = 6, **kw: object) -> BatchWorld:
    kw.setdefault("seed", 0)
    kw.setdefault("obs_spec", GENERAL)
    patterns = kw.pop("patterns", ("circle", "line", "heart"))
    spec = kw.pop("obs_spec")
    return BatchWorld(n_envs, n_robots, patterns, spec, **kw)  # type: ignore[arg-type]


def to_slots(w: BatchWorld) -> Arr:
    """Full speed straight at each robot's slot (stopping on it)."""
    g = w.goals - w.positions
    dist = np.linalg.norm(g, axis=-1, keepdims=True)
    out: Arr = g / np.maximum(dist, REACH) * W.v_max_mps
    return out


def still(w: BatchWorld) -> Arr:
    return np.zeros((w.n_envs, w.n_robots, 2))


# ------------------------------------------------------------------ resets


def test_seeded_resets_are_reproducible() -> None:
    a, b, c = make(seed=7), make(seed=7), make(seed=8)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.pattern, b.pattern)
    assert not np.allclose(a.positions, c.positions)
    a.reset()
    b.reset()
    np.testing.assert_array_equal(a.positions, b.positions)
    a.reset(seed=7)
    np.testing.assert_array_equal(a.positions, make(seed=7).positions)


def test_env_episodes_do_not_depend_on_other_envs() -> None:
    small, big = make(n_envs=3, seed=5), make(n_envs=6, seed=5)
    np.testing.assert_array_equal(small.positions, big.positions[:3])  # independent of E
    for _ in range(3):  # env 0 lives through extra episodes in one world only
        small.reset(env_ids=np.array([0]))
    rng = np.random.default_rng(1)
    small.step(rng.uniform(-1, 1, (3, 6, 2)))  # and different motion
    big.step(rng.uniform(-1, 1, (6, 6, 2)))
    small.reset(env_ids=np.array([1, 2]))
    big.reset(env_ids=np.array([2, 1]))
    np.testing.assert_array_equal(small.positions[1:], big.positions[1:3])
    np.testing.assert_array_equal(small.pattern[1:], big.pattern[1:3])


def test_starts_respect_separation_and_arena() -> None:
    w = make(n_envs=32, n_robots=20)
    for _ in range(5):
        w.reset()
        assert np.all(min_separation(w.positions) >= W.start_separation_m)
        assert np.all((w.positions >= 0) & (w.positions <= W.arena_m))
        np.testing.assert_array_equal(w.prev_positions, w.positions)


def test_a_start_pattern_starts_every_episode_formed_in_it() -> None:
    """A transition: the start pattern formed (each robot within half the tolerance of its
    point, at the arena's centre), jittered per env from its own generator, reproducibly."""
    w = make(n_envs=8, n_robots=10, patterns=("cross",), start_pattern="circle", seed=3)
    w.reset()
    circle = make_pattern("circle", 10)
    for e in range(8):
        assert is_formed(w.positions[e], circle)
        off = w.positions[e] - (circle - circle.mean(axis=0) + 0.5 * W.arena_m)
        assert np.hypot(off[:, 0], off[:, 1]).max() <= 0.5 * W.formed_tol_m
        assert not is_formed(w.positions[e], make_pattern("cross", 10))
    assert not np.allclose(w.positions[0], w.positions[1])  # each env its own jitter
    again = make(n_envs=8, n_robots=10, patterns=("cross",), start_pattern="circle", seed=3)
    again.reset()
    np.testing.assert_array_equal(again.positions, w.positions)


def test_crowded_starts_draw_a_share_of_teams_in_a_small_square() -> None:
    """With ``crowd = (share, side)`` about that share of the episodes start in a square of
    ``side`` at the arena's centre, still apart; without it every seed draws what it did."""
    side, n_envs = 2.0, 200
    w = make(n_envs=n_envs, n_robots=10, crowd=(0.5, side), seed=11)
    lo, hi = 0.5 * (W.arena_m - side), 0.5 * (W.arena_m + side)
    inside = ((w.positions >= lo) & (w.positions <= hi)).all(axis=(1, 2))
    spread = np.ptp(w.positions, axis=1).max(axis=1)
    assert 0.35 < inside.mean() < 0.65  # the share, within its binomial spread
    assert np.all(spread[inside] <= side)
    assert np.all(min_separation(w.positions) >= W.start_separation_m)
    assert (spread[~inside] > side).all()  # the others spread over the arena
    plain, zero = make(n_envs=8, n_robots=10, seed=11), make(n_envs=8, n_robots=10,
                                                              crowd=(0.0, side), seed=11)
    np.testing.assert_array_equal(plain.positions, zero.positions)
    with pytest.raises(ValueError, match="do not fit apart in a crowded square"):
        make(n_robots=10, crowd=(0.5, 0.5))
    with pytest.raises(ValueError, match="crowded share"):
        make(crowd=(1.5, side))


def test_patterns_drawn_per_env_and_random_shapes() -> None:
    w = make(n_envs=16, patterns=("circle", "line"))
    assert set(w.pattern_ids.tolist()) == {0, 1}
    for e in range(16):
        name = w.patterns[w.pattern_ids[e]]
        np.testing.assert_allclose(w.pattern[e], make_pattern(name, 6), atol=1e-12)
    r = make(n_envs=4, patterns="random")
    assert not np.allclose(r.pattern[0], r.pattern[1])
    assert np.all(min_separation(r.pattern) >= TWO_R)


def test_refuses_bad_configs() -> None:
    with pytest.raises(ValueError, match="v_max"):
        make(world=W.with_(v_max_mps=3.0))
    with pytest.raises(ValueError, match="robots"):
        make(obs_spec=ObservationSpec("paper", n_robots=5))
    with pytest.raises(ValueError, match="pattern"):
        make(patterns=())


# -------------------------------------------------------------- kinematics


def test_actions_clamped_and_nan_held() -> None:
    w = make(n_envs=1, n_robots=3)
    P0 = np.array([[[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]]])
    w.reset_to(P0)
    a = np.array([[[30.0, 40.0], [0.3, 0.4], [np.nan, 1.0]]])
    w.step(a)
    moved = w.positions - P0
    np.testing.assert_allclose(moved[0, 0], [0.6 * REACH, 0.8 * REACH])  # clamped, direction kept
    np.testing.assert_allclose(moved[0, 1], [0.03, 0.04])
    np.testing.assert_array_equal(moved[0, 2], [0.0, 0.0])
    assert np.isnan(a[0, 2, 0])  # the caller's array is untouched
    np.testing.assert_allclose(w.travel[0], [REACH, 0.05, 0.0])


def test_head_on_robots_stop_at_contact_and_collide() -> None:
    w = make(n_envs=2, n_robots=3)
    P0 = np.array([[0.0, 0.0], [TWO_R + 0.1, 0.0], [5.0, 5.0]])
    w.reset_to(np.stack([P0, P0 + 0.5]))
    push = np.zeros((2, 3, 2))
    push[:, 0, 0], push[:, 1, 0] = 1.0, -1.0  # drive into each other
    for t in range(4):
        res = w.step(push)
        gap = np.linalg.norm(w.positions[:, 0] - w.positions[:, 1], axis=-1)
        assert np.all(gap >= TWO_R - CONTACT_TOL_M)
        np.testing.assert_array_equal(res.collisions, [1, 1])  # counted every step they push
        np.testing.assert_array_equal(w.last_robot_collisions[:, :2], 1)
        np.testing.assert_array_equal(w.last_robot_collisions[:, 2], 0)
        if t == 0:  # symmetric push: both end at exactly 2R around the midpoint
            np.testing.assert_allclose(gap, TWO_R, atol=1e-9)
            mid = P0[:2, 0].mean() + np.array([0.0, 0.5])
            np.testing.assert_allclose(w.positions[:, :2, 0].mean(1), mid)
    assert np.all(w.episode_collisions == 4)


def test_near_miss_is_no_collision() -> None:
    w = make(n_envs=1, n_robots=2)
    w.reset_to(np.array([[[0.0, 0.0], [1.0, TWO_R + 0.01]]]))
    a = np.array([[[1.0, 0.0], [-1.0, 0.0]]])
    total = sum(int(w.step(a).collisions[0]) for _ in range(10))  # they pass by, 1 cm apart
    assert total == 0
    assert w.positions[0, 0, 0] > w.positions[0, 1, 0]


def test_crowd_driven_to_centre_never_interpenetrates() -> None:
    w = make(n_envs=8, n_robots=10, build_obs=False)
    rng = np.random.default_rng(3)
    saw = 0
    for _ in range(120):
        P = w.positions
        a = (P.mean(1, keepdims=True) - P) * 5.0 + rng.normal(0, 0.3, P.shape)
        prev = w.positions
        res = w.step(a)
        saw += int(res.collisions.sum())
        live = ~res.done
        assert np.all(min_separation(w.positions[live]) >= TWO_R - CONTACT_TOL_M)
        step = np.linalg.norm(w.positions[live] - prev[live], axis=-1)
        assert np.all(np.isfinite(step))
    assert saw > 100  # the crowd did push


def test_jam_that_does_not_clear_holds_robots_still(monkeypatch: pytest.MonkeyPatch) -> None:
    import trainer.world.contacts as world_module

    monkeypatch.setattr(world_module, "CONTACT_SWEEPS", 1)  # too few sweeps for a chain
    w = make(n_envs=1, n_robots=4, build_obs=False)
    start = np.array([[[0.0, 0.0], [TWO_R + 0.01, 0.0], [2 * TWO_R + 0.02, 0.0], [5.0, 5.0]]])
    w.reset_to(start)
    a = np.zeros((1, 4, 2))
    a[0, 0, 0], a[0, 2, 0] = 1.0, -1.0  # squeeze the middle robot from both sides
    res = w.step(a)
    assert w.contact_fallbacks > 0
    assert np.all(min_separation(w.positions) >= TWO_R - CONTACT_TOL_M)
    assert res.collisions[0] >= 2


@settings(max_examples=40)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 16))
def test_no_overlap_after_any_step(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    w = make(n_envs=3, n_robots=n, build_obs=False)
    # a packed cluster (jittered grid, gaps of 0-2 cm) driven in random directions
    side = int(np.ceil(np.sqrt(n)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n]
    P = grid * (TWO_R + 0.02) + rng.uniform(0.0, 0.01, (3, n, 2))
    assert np.all(min_separation(P) >= TWO_R)
    w.reset_to(P)
    total = 0
    for _ in range(3):
        res = w.step(rng.uniform(-2, 2, (3, n, 2)))
        assert np.all(min_separation(w.positions) >= TWO_R - CONTACT_TOL_M)
        total += int(res.collisions.sum())
    assert total > 0 or n == 2


@settings(max_examples=40)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 9), spread=st.sampled_from([0.5, 1.5, 4.0]))
def test_swept_contacts_is_the_runtime_collision_check(seed: int, n: int, spread: float) -> None:
    rng = np.random.default_rng(seed)
    E = 6
    P0 = rng.uniform(0, spread, (E, n, 2))
    P1 = P0 + rng.uniform(-REACH, REACH, (E, n, 2))
    P1[0, 0], P1[0, 1] = P0[0, 1], P0[0, 0]  # two robots swap places: they pass through
    limit = TWO_R - CONTACT_TOL_M
    X0 = np.ascontiguousarray(P0.transpose(2, 1, 0))
    ours = swept_contacts(X0, np.ascontiguousarray((P1 - P0).transpose(2, 1, 0)), limit)
    i, j, D = robot_pairs(n)
    np.testing.assert_array_equal(D @ X0, X0[:, j] - X0[:, i])  # exact differences
    theirs = swept_pair_distance(P0, P1) < limit
    np.testing.assert_array_equal(ours.T, theirs[:, i, j])
    np.testing.assert_array_equal(ours.sum(axis=0), count_collisions(P0, P1))
    assert ours[0, 0]  # the swap


# ---------------------------------------------------------------- assignment


def test_world_assignment_is_the_solvers() -> None:
    w = make(n_envs=8, n_robots=8, build_obs=False)
    rng = np.random.default_rng(0)
    for _ in range(60):
        slots_before, pattern = w.slots.copy(), w.pattern.copy()
        res = w.step(rng.uniform(-1, 1, (8, 8, 2)))
        live = ~res.done
        expect = assign_slots_batch(w.positions, pattern, previous=slots_before)
        np.testing.assert_array_equal(w.slots[live], expect[live])


# ------------------------------------------------------------ termination


def test_formed_detection_and_auto_reset() -> None:
    w = make(n_envs=2, n_robots=5, step_limit=50)
    C = w.pattern.copy()
    exact = C[0] + 4.0
    off = C[1] + 4.0
    off[2, 0] += 0.1  # one robot 0.1 m off: not formed
    w.reset_to(np.stack([exact, off]))
    res = w.step(still(w))
    np.testing.assert_array_equal(res.formed, [True, False])
    np.testing.assert_array_equal(res.done, [True, False])
    assert not res.truncated.any()
    ep = res.episode
    assert ep is not None
    np.testing.assert_array_equal(ep.env_ids, [0])
    assert ep.formed[0] and ep.steps[0] == 1 and ep.collisions[0] == 0
    assert ep.final_error[0] == pytest.approx(0.0, abs=1e-12)
    assert ep.travel[0] == 0.0
    # env 0 restarted: a fresh random start, counters at zero, obs of the new episode
    assert w.steps[0] == 0 and w.travel[0].sum() == 0.0
    assert not np.allclose(w.positions[0], exact)
    np.testing.assert_array_equal(res.obs, w.observe())
    assert not np.allclose(ep.final_obs[0], res.obs[0])
    # env 1 keeps going
    assert w.steps[1] == 1


def test_formed_uses_tolerance_of_slot_distance() -> None:
    w = make(n_envs=2, n_robots=5)
    C = w.pattern.copy()
    inside, outside = C[0].copy(), C[1].copy()
    inside[0, 0] += 0.9 * W.formed_tol_m * 5 / 4  # centroid shift takes a fifth of it
    outside[0, 0] += 1.1 * W.formed_tol_m * 5 / 4
    w.reset_to(np.stack([inside, outside]))
    res = w.step(still(w))
    np.testing.assert_array_equal(res.formed, [True, False])


def test_truncation_at_step_limit() -> None:
    w = make(n_envs=3, step_limit=5)
    for t in range(1, 6):
        res = w.step(still(w))
        assert res.done.all() == (t == 5)
    assert res.truncated.all() and not res.formed.any()
    assert res.episode is not None
    np.testing.assert_array_equal(res.episode.steps, [5, 5, 5])
    np.testing.assert_array_equal(w.steps, [0, 0, 0])


def test_go_to_slot_forms_every_pattern_within_bounds() -> None:
    w = make(
        n_envs=5,
        n_robots=8,
        patterns=("circle", "line", "cross", "heart", "triangle"),
        compute_bounds=True,
        build_obs=False,
    )
    finished = []
    for _ in range(200):
        res = w.step(to_slots(w))
        if res.episode is not None:
            finished.append(res.episode)
        if len(finished) >= 5:
            break
    formed = np.concatenate([ep.formed for ep in finished])
    assert formed.all()
    for ep in finished:
        assert ep.lower_bound_steps is not None and ep.lower_bound_travel is not None
        assert np.all(ep.steps >= ep.lower_bound_steps)
        assert np.all(ep.travel >= ep.lower_bound_travel - 1e-9)
        assert np.all(ep.steps <= 1.3 * ep.lower_bound_steps + 3)


# ------------------------------------------------------------------ reward


def test_reward_of_standing_still_is_the_fatigue() -> None:
    cfg = RewardConfig()
    w = make(n_envs=3, reward=cfg)
    res = w.step(still(w))
    np.testing.assert_allclose(res.reward, cfg.step_penalty, atol=1e-6)
    assert res.reward.dtype == np.float32 and res.reward.shape == (3, 6)


def test_reward_terms_signs() -> None:
    cfg = RewardConfig(step_penalty=-0.05, collision_penalty=-1.0, beta=1.0, progress_weight=1.0)
    w = make(n_envs=2, n_robots=6, reward=cfg)
    toward = w.step(to_slots(w)).reward
    assert np.all(toward > 0)  # straight at the slot: progress beats fatigue
    w.reset()
    away = w.step(-to_slots(w)).reward
    assert np.all(away < cfg.step_penalty)
    # per-robot progress is bounded by one full step
    only_prog = make(n_envs=2, reward=RewardConfig(0.0, 0.0, 0.0, 1.0, 0.0))
    r = only_prog.step(to_slots(only_prog)).reward
    assert np.all(r <= 1.0 + 1e-6) and np.all(r > 0.5)


def test_collision_penalty_hits_only_the_robots_involved() -> None:
    cfg = RewardConfig(step_penalty=-0.1, collision_penalty=-1.0, beta=0.0, progress_weight=0.0)
    w = make(n_envs=1, n_robots=3, reward=cfg)
    w.reset_to(np.array([[[0.0, 0.0], [TWO_R + 0.05, 0.0], [5.0, 5.0]]]))
    a = np.zeros((1, 3, 2))
    a[0, 0, 0] = 1.0
    r = w.step(a).reward[0]
    np.testing.assert_allclose(r, [-1.1, -1.1, -0.1], atol=1e-6)


def test_team_progress_telescopes_to_error_removed() -> None:
    cfg = RewardConfig(step_penalty=0.0, collision_penalty=0.0, beta=1.0, progress_weight=0.0)
    w = make(n_envs=3, reward=cfg, build_obs=False)
    err0 = w.error.copy()
    total = np.zeros(3)
    for _ in range(20):
        total += w.step(to_slots(w)).reward[:, 0]
    np.testing.assert_allclose(total, (err0 - w.error) / REACH, rtol=1e-4)


def test_formed_bonus_once_on_formation() -> None:
    cfg = RewardConfig(step_penalty=0.0, collision_penalty=0.0, beta=0.0, progress_weight=0.0,
                       formed_bonus=2.5)  # fmt: skip
    w = make(n_envs=1, n_robots=4, reward=cfg)
    w.reset_to(w.pattern + 1.0)
    np.testing.assert_allclose(w.step(still(w)).reward, 2.5)
    assert PAPER_REWARD.progress_weight == 0.0 and PAPER_REWARD.formed_bonus == 0.0


# ------------------------------------------------------------- observation


def test_general_observation_matches_runtime_builder() -> None:
    w = make(n_envs=3, n_robots=7)
    assert w.obs_dim == GENERAL.dim
    rng = np.random.default_rng(0)
    for _ in range(3):
        res = w.step(rng.uniform(-1, 1, (3, 7, 2)))
    assert res.obs.shape == (3, 7, GENERAL.dim) and res.obs.dtype == np.float32
    goals = slot_positions(w.positions, w.pattern, w.slots)
    np.testing.assert_allclose(goals, w.goals, rtol=0, atol=1e-12)
    expect = general_observation(w.positions, w.prev_positions, goals, k=4, world=W)
    np.testing.assert_allclose(res.obs, expect.astype(np.float32))
    # from the world's own slot positions: the runtime builder's numbers, bit for bit
    same = general_observation(w.positions, w.prev_positions, w.goals, k=4, world=W)
    assert np.array_equal(res.obs, same.astype(np.float32))
    # the world's error and slot distances are the runtime's
    np.testing.assert_allclose(w.error, formation_error_batch(w.positions, w.pattern, w.slots))
    d = slot_distances(w.positions, w.pattern, w.slots)
    assert np.all(np.linalg.norm(w.positions - w.goals, axis=-1) == pytest.approx(d))


def test_paper_observation_from_three_frames() -> None:
    spec = ObservationSpec("paper", n_robots=5)
    w = make(n_envs=2, n_robots=5, obs_spec=spec)
    assert w.obs_dim == 3 * 4 * 2
    first = w.observe()
    np.testing.assert_allclose(first, paper_observation(np.repeat(w.positions[:, None], 3, 1)))
    rng = np.random.default_rng(0)
    track = [w.positions]
    for _ in range(3):
        res = w.step(rng.uniform(-1, 1, (2, 5, 2)))
        track.append(w.positions)
    frames = np.stack([track[-1], track[-2], track[-3]], axis=1)
    np.testing.assert_array_equal(w.frames, frames)
    assert res.obs.shape == (2, 5, spec.dim)
    np.testing.assert_allclose(res.obs, paper_observation(frames).astype(np.float32))


def test_without_observations() -> None:
    w = make(build_obs=False)
    res = w.step(still(w))
    assert w.obs_dim == 0 and res.obs.shape == (4, 6, 0)


# ----------------------------------------------------------------- patterns


def test_set_patterns_retargets_from_where_robots_stand() -> None:
    w = make(n_envs=2, patterns="circle")
    for _ in range(3):
        w.step(to_slots(w))
    here = w.positions.copy()
    w.set_patterns(["line"])
    np.testing.assert_array_equal(w.positions, here)
    np.testing.assert_allclose(w.pattern, np.stack([make_pattern("line", 6)] * 2), atol=1e-12)
    assert np.all(w.steps == 0)
    assert w.observe().shape == (2, 6, GENERAL.dim)
    w.set_patterns(["cross"], retarget=False)
    np.testing.assert_allclose(w.pattern[0], make_pattern("line", 6), atol=1e-12)
    w.reset()
    np.testing.assert_allclose(w.pattern[0], make_pattern("cross", 6), atol=1e-12)


def test_step_reward_terms() -> None:
    from trainer.world.reward import DEFAULT_REWARD, PAPER_REWARD, step_reward

    hits = np.array([[1], [0]])
    X = np.array([[[0.0], [1.0]], [[0.0], [0.0]]])  # (2, N=2, E=1)
    goals = np.zeros((2, 2, 1))
    dist_before = np.array([[0.1], [1.0]])
    formed = np.array([False])
    err0, err1 = np.array([0.3]), np.array([0.2])
    r = step_reward(PAPER_REWARD, hits, err0, err1, X, goals, dist_before, formed, REACH)
    np.testing.assert_allclose(r[:, 0], [-1.0 - 0.05 + 1.0, -0.05 + 1.0])
    formed = np.array([True])
    r = step_reward(DEFAULT_REWARD, hits, err1, err1, X, goals, dist_before, formed, REACH)
    np.testing.assert_allclose(r[:, 0], [-1.0 - 0.05 + 1.0 + 1.0, -0.05 + 0.0 + 1.0])


def test_the_proximity_penalty_grows_from_the_band_to_contact() -> None:
    """Three robots in a row, 0.22 m and 0.5 m apart (2R = 0.2, band 5 cm): the close pair
    pays 0.6 of the penalty each (2 cm beyond contact), the far one nothing; off by default."""
    import dataclasses

    from trainer.world.reward import DEFAULT_REWARD, step_reward

    X = np.array([[[0.0], [0.22], [0.72]], [[0.0], [0.0], [0.0]]])  # (2, N=3, E=1)
    args = (np.zeros((3, 1), dtype=np.int64), np.zeros(1), np.zeros(1), X, X.copy(),
            np.zeros((3, 1)), np.array([False]), REACH)
    cfg = dataclasses.replace(DEFAULT_REWARD, proximity_penalty=2.0, progress_weight=0.0)
    base = step_reward(dataclasses.replace(cfg, proximity_penalty=0.0), *args, two_r=0.2)
    r = step_reward(cfg, *args, two_r=0.2)
    np.testing.assert_allclose((r - base)[:, 0], [-1.2, -1.2, 0.0])
    np.testing.assert_allclose(step_reward(DEFAULT_REWARD, *args, two_r=0.2),
                               step_reward(DEFAULT_REWARD, *args))
