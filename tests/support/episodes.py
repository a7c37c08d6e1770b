"""Comparing a brain with a rule brain on the same seeded episodes."""

from __future__ import annotations

from typing import Any


def assert_same_episodes(brain: Any, rule: Any, safety: Any) -> float:
    """``brain`` and ``rule`` on the same seeded circle episodes: the same steps, travel (to
    float32 rounding) and success. Returns the success rate."""
    import numpy as np

    from trainer.evaluate import evaluate_brain

    kw = {"seed": 77, "safety": safety, "progress": False}
    a = evaluate_brain(brain, "circle", 8, 4, **kw)
    b = evaluate_brain(rule, "circle", 8, 4, **kw)
    assert a.episode_stats["steps"] == b.episode_stats["steps"]
    np.testing.assert_allclose(a.episode_stats["travel_m"], b.episode_stats["travel_m"],
                               rtol=1e-5)
    assert a.success_rate == b.success_rate
    return float(a.success_rate)
