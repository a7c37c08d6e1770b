"""The heap settled before a loop, and the collector's pauses timed."""

from __future__ import annotations

import gc

from runtime import heap


def test_settle_freezes_what_the_set_up_made_and_pauses_count_each_collection() -> None:
    made = [{"n": i} for i in range(1000)]  # containers the collector tracks
    try:
        heap.settle()
        assert gc.get_freeze_count() >= len(made)
        with heap.Pauses() as p:
            gc.collect(0)
            gc.collect()
        gc.collect()  # after the block: not counted
        f = p.figures()
        assert f["count"][0] >= 1 and f["count"][2] >= 1
        assert all(t >= m >= 0.0 for t, m in zip(f["total_ms"], f["max_ms"], strict=True))
        assert p._callback not in gc.callbacks
    finally:
        gc.unfreeze()
