"""What a robot senses of its team under :class:`runtime.conditions.Conditions`.

:class:`Sensor` turns the true positions of each step into each observer's view, batched
over B observers (B = envs x robots in ``eval`` and the training world, B = 1 in a robot
process that simulates its sensors). Per observer b, team member j and step t:

1. **Latency.** A peer is sensed as it was ``latency_steps`` ago; the observer's own pose
   ``own_latency_steps`` ago (odometry: 0). Until that much history exists the oldest
   step stands in.
2. **Visibility.** A peer farther than ``range_m`` from the observer (now), or not among
   its ``k_nearest``, is not sensed this step.
3. **Loss.** A sensed peer's update is lost with chance ``loss``.
4. **Noise.** A received peer position gets Gaussian noise of sigma ``noise_m`` per axis.
5. **Memory.** A peer not received this step keeps its last received position; ``age``
   says how old each position is (steps). At the first step every peer is received (the
   start-up roll call), so a view never lacks a row.

The output is a view per observer, (B, n, 2), with each row's age (B, n). Each observer
draws from its own generator, so a robot's noise does not depend on how many others are
simulated beside it.
"""

from __future__ import annotations

import numpy as np

from runtime.conditions import Conditions
from runtime.types import Array, IntArray

__all__ = ["Sensor"]


class Sensor:
    """Views of B observers under ``conditions``; see the module docstring.

    ``observer``: (B,) each observer's row in its team. ``seeds``: one seed per observer
    (an int each, or a :class:`numpy.random.SeedSequence`).
    """

    def __init__(self, conditions: Conditions, observer: IntArray,
                 seeds: list[int] | list[np.random.SeedSequence]) -> None:
        self.conditions = conditions
        self.observer = np.asarray(observer, dtype=np.int64)
        if len(seeds) != len(self.observer):
            raise ValueError("one seed per observer")
        self._rngs = [np.random.default_rng(s) for s in seeds]
        self.reset()

    def reset(self, observers: IntArray | None = None) -> None:
        """Forget the history (all observers, or those given): the next step is a start."""
        if observers is None:
            self._history: list[Array] = []
            self._view: Array | None = None
            self._age: IntArray | None = None
        elif self._view is not None and self._age is not None:
            self._age[observers] = -1  # a start for these rows: every peer received

    def sense(self, truth: Array) -> tuple[Array, IntArray]:
        """This step's views ((B, n, 2) m) and ages ((B, n) steps) from the true positions
        ``truth`` (B, n, 2) (each observer's team as it is now)."""
        c = self.conditions
        P = np.asarray(truth, dtype=np.float64)
        B, n, _ = P.shape
        if self._view is not None and self._view.shape != P.shape:  # the team changed
            self.reset()
        if self._view is None or self._age is None:
            self._view = np.empty((B, n, 2))
            self._age = np.full((B, n), -1, dtype=np.int64)
        fresh = self._age < 0  # a start: everything received
        self._history.insert(0, P.copy())
        del self._history[c.history_steps + 1:]
        starting = fresh.all(axis=1)
        if starting.any():  # an observer's start: no earlier step of this team to sense
            for h in self._history[1:]:
                h[starting] = P[starting]
        late = self._history[min(c.latency_steps, len(self._history) - 1)]
        own = self._history[min(c.own_latency_steps, len(self._history) - 1)]
        received = np.ones((B, n), dtype=bool)
        if c.range_m != np.inf or c.k_nearest:
            me = P[np.arange(B), self.observer]  # (B, 2) where each observer is now
            d2 = ((late - me[:, None]) ** 2).sum(-1)
            d2[np.arange(B), self.observer] = np.inf  # not its own neighbour
            if c.range_m != np.inf:
                received &= d2 <= c.range_m ** 2
            if 0 < c.k_nearest < n - 1:
                kth = np.partition(d2, c.k_nearest - 1, axis=1)[:, c.k_nearest - 1:c.k_nearest]
                received &= d2 <= kth
        meas = late.copy()
        for b, rng in enumerate(self._rngs):  # each observer its own stream
            if c.loss > 0:
                received[b] &= rng.random(n) >= c.loss
            if c.noise_m > 0:
                meas[b] += rng.normal(0.0, c.noise_m, (n, 2))
        received |= fresh
        self._view[received] = meas[received]
        self._age += 1
        self._age[received] = c.latency_steps
        rows = np.arange(B)
        self._view[rows, self.observer] = own[rows, self.observer]
        self._age[rows, self.observer] = c.own_latency_steps
        return self._view.copy(), self._age.copy()
