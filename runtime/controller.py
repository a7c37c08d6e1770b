"""Old home of the decision pipeline; it lives in :mod:`runtime.decision`."""

from runtime.decision import (  # re-export: moved to runtime.decision
    Controller,
    Decision,
    decide_batch,
)

__all__ = ["Controller", "Decision", "decide_batch"]
