"""The env-last general observation equals runtime.observation's builder, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.observation import general_observation
from runtime.observation_env_last import general_observation_env_last


def _rm(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a.transpose(2, 1, 0))


@pytest.mark.parametrize(("E", "n", "k", "ties"), [(5, 10, 6, False), (3, 4, 6, False),
                                                  (4, 2, 1, False), (6, 9, 6, True)])
def test_equals_the_runtime_builder(E: int, n: int, k: int, ties: bool) -> None:
    rng = np.random.default_rng(E * 100 + n)
    if ties:  # a lattice: many robots at equal distances, ties broken by index
        P = rng.integers(0, 3, (E, n, 2)).astype(float) * 0.5
        Q = P + rng.integers(-1, 2, (E, n, 2)) * 0.1
    else:
        P = rng.uniform(0, 10, (E, n, 2))
        Q = P + rng.normal(0, 0.07, P.shape)
    S = P + rng.normal(0, 1.0, P.shape)
    want = general_observation(P, Q, S, k).astype(np.float32)
    got = general_observation_env_last(_rm(P), _rm(Q), _rm(S), k)
    assert got.shape == want.shape
    assert np.array_equal(got, want)
