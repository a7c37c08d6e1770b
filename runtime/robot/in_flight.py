"""This robot's commands still on their way to being applied: where it will be when the next
one is.

In realtime the world applies a robot's newest command each step, even one decided from the
poses of a few steps before (up to :data:`MAX_COMMAND_AGE_STEPS`), each command for one step
at most (see ``sim_bridge/world/world_link.py``). A robot whose commands arrive k steps late
therefore decides from poses that do not yet show the motion of its last commands, and a
decision that ignored them would count that motion twice: near its slot it would overshoot,
and a swarm that is late for long would circle around its pattern instead of forming it.

:class:`InFlight` keeps the commands this robot sent, when, and how late each went out
(the newest step heard when it was sent, minus its own step). Deciding on the poses of step
s, the robot expects its command to be applied ``lag`` steps later (the median lag of its
last commands) and moves its own position, for the decision, by what the world applies to
it meanwhile, by the world's rule: at each step j, the newest command sent before the poses
of j + 1 came (the end of step j; for steps still to come, the newest sent so far), if not
applied at an earlier step and no older than :data:`MAX_COMMAND_AGE_STEPS`. On time (lag 0)
nothing moves. The world's guard (``sim_bridge/world/stale_guard.py``), not this
prediction, is what keeps stale motions safe.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Final, NamedTuple

MAX_COMMAND_AGE_STEPS: Final = 3
"""realtime: the oldest command (steps since its poses) the world applies by default."""
LAG_SAMPLES: Final = 5
"""Commands whose lateness makes the expected lag (their median)."""
HISTORY: Final = 16
"""Commands kept (more than the oldest the world applies, and the lags above)."""


class Sent(NamedTuple):
    step: int
    vx: float
    vy: float
    t: float
    """``time.monotonic()`` when it went out."""


class InFlight:
    """The commands one robot sent, to predict its own motion until its next one applies."""

    def __init__(self, max_age_steps: int = MAX_COMMAND_AGE_STEPS) -> None:
        self.max_age_steps = max_age_steps
        self._sent: deque[Sent] = deque(maxlen=HISTORY)
        self._lags: deque[int] = deque(maxlen=LAG_SAMPLES)

    def reset(self) -> None:
        """Forget everything (the world restarted, the robot held still)."""
        self._sent.clear()
        self._lags.clear()

    def sent(self, step: int, vx: float, vy: float, t: float, newest_heard: int) -> None:
        """A command for ``step`` went out at ``t``, the newest poses heard being of
        ``newest_heard``."""
        if self._sent and step <= self._sent[-1].step:  # a restart, or a repeat: start again
            self.reset()
        self._sent.append(Sent(step, vx, vy, t))
        self._lags.append(max(0, newest_heard - step))

    @property
    def lag(self) -> int:
        """Steps by which this robot's commands have been late lately (the median)."""
        if not self._lags:
            return 0
        return sorted(self._lags)[len(self._lags) // 2]

    def displacement(self, step: int, arrived: Callable[[int], float | None], dt_s: float
                     ) -> tuple[float, float]:
        """Metres this robot moves, from its pose at ``step``, before a command decided now
        is applied; ``arrived(j)`` is when the poses of step j came (None if not yet)."""
        lag = self.lag
        if not lag or not self._sent:
            return 0.0, 0.0
        dx = dy = 0.0
        applied = -1  # step of the last command applied, replaying the world's rule
        for j in range(self._sent[0].step, step + lag):
            end = arrived(j + 1)
            c = next((c for c in reversed(self._sent) if end is None or c.t < end), None)
            if (c is None or c.step <= applied or c.step > j
                    or j - c.step > self.max_age_steps):
                continue
            applied = c.step
            if j >= step:
                dx += c.vx * dt_s
                dy += c.vy * dt_s
        return dx, dy
