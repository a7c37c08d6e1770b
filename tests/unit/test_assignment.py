"""The batched assignment proof against scipy: random, tie-heavy and degenerate batches."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.assignment import certify_assignment, is_permutation
from runtime.formation import (
    _sq_cost,
    assign_slots_batch,
    assign_slots_env_last,
    keeps_previous,
    linear_sum_assignment,
)


def _reference(P: np.ndarray, C: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """What assign_slots_batch gave before the proof: scipy per env, then the hysteresis rule."""
    cost = _sq_cost(P, np.broadcast_to(C, P.shape))
    slots = np.stack([linear_sum_assignment(c)[1] for c in cost]).astype(np.int64)
    new = np.take_along_axis(cost, slots[..., None], -1)[..., 0].sum(-1)
    old = np.take_along_axis(cost, previous[..., None], -1)[..., 0].sum(-1)
    keep = keeps_previous(new, old)
    slots[keep] = previous[keep]
    return slots


def _perms(rng: np.random.Generator, E: int, n: int) -> np.ndarray:
    return np.stack([rng.permutation(n) for _ in range(E)]).astype(np.int64)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), E=st.integers(1, 12), n=st.integers(1, 9),
       grid=st.booleans(), jitter=st.sampled_from([0.0, 1e-9, 1e-3, 0.3]))
def test_batch_equals_scipy_with_hysteresis(seed: int, E: int, n: int, grid: bool,
                                            jitter: float) -> None:
    rng = np.random.default_rng(seed)
    if grid:  # tie-heavy: robots and slots on a coarse lattice, many equal costs
        P = rng.integers(0, 3, (E, n, 2)).astype(float)
        C = rng.integers(0, 3, (E, n, 2)).astype(float)
    else:
        P = rng.uniform(0, 10, (E, n, 2))
        C = rng.uniform(-2, 2, (E, n, 2))
    # the previous step's assignment, at slightly different positions (the world's case)
    if jitter:
        prev = assign_slots_batch(P + rng.normal(0, jitter, P.shape), C)
    else:
        prev = _perms(rng, E, n)
    got = assign_slots_batch(P, C, previous=prev)
    assert np.array_equal(got, _reference(P, C, prev))


def test_certificate_is_a_proof_on_random_batches() -> None:
    """Every env it certifies has no assignment cheaper by more than n * tol (scipy's optimum)."""
    rng = np.random.default_rng(7)
    E, n, tol = 200, 8, 1e-6
    P, C = rng.uniform(0, 10, (E, n, 2)), rng.uniform(-2, 2, (E, n, 2))
    cost = _sq_cost(P, C)
    best = np.stack([linear_sum_assignment(c)[1] for c in cost])
    prev = np.where(rng.random((E, 1)) < 0.5, best, _perms(rng, E, n))  # optimal or not
    cert = certify_assignment(cost.transpose(1, 2, 0).copy(), prev.T.copy(), tol, None, n + 1)
    opt = np.take_along_axis(cost, best[..., None], -1)[..., 0].sum(-1)
    old = np.take_along_axis(cost, prev[..., None], -1)[..., 0].sum(-1)
    assert cert.settled.any() and not cert.settled.all()
    assert (old[cert.settled] - opt[cert.settled] <= n * tol + 1e-9).all()
    # with n + 1 rounds from zero, Bellman-Ford settles every optimal assignment
    assert cert.settled[np.isclose(old, opt, rtol=0, atol=1e-9)].all()


def test_degenerate_and_invalid_previous() -> None:
    """One robot, all robots on one point, and a previous that is no permutation."""
    P1, C1 = np.zeros((3, 1, 2)), np.zeros((3, 1, 2))
    prev1 = np.zeros((3, 1), dtype=np.int64)
    assert np.array_equal(assign_slots_batch(P1, C1, previous=prev1), prev1)
    P = np.ones((4, 5, 2))  # every cost equal: any assignment is optimal, previous is kept
    C = np.random.default_rng(0).uniform(-1, 1, (4, 5, 2))
    prev = _perms(np.random.default_rng(1), 4, 5)
    assert np.array_equal(assign_slots_batch(P, C, previous=prev), _reference(P, C, prev))
    bad = prev.copy()
    bad[0] = 0  # not a permutation: never certified, solved, and the rule applied as before
    assert not is_permutation(bad.T)[0]
    cost = _sq_cost(P, C).transpose(1, 2, 0).copy()
    out = assign_slots_env_last(cost, bad.T.copy())
    assert np.array_equal(out.T, _reference(P, C, bad))


def test_world_steps_keep_scipys_assignment() -> None:
    """The training world's every step equals scipy per env with the hysteresis rule."""
    from runtime.observation import ObservationSpec
    from trainer.training_world import BatchWorld

    w = BatchWorld(8, 6, ("circle", "line"), ObservationSpec("general"), seed=5, build_obs=False)
    rng = np.random.default_rng(0)
    for _ in range(80):
        prev = w.slots.copy()
        res = w.step(rng.uniform(-1.0, 1.0, (8, 6, 2)))
        live = ~res.done  # finished envs were reset and solved afresh
        want = _reference(w.positions[live], w.pattern[live], prev[live])
        assert np.array_equal(w.slots[live], want)
