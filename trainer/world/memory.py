"""The rows a brain with memory reads, kept for every robot of E training worlds.

A robot's brain with memory (``ObservationSpec.frames`` = K > 1) reads its own last K rows,
newest first, and carries the K - 1 older ones in and out of its graph as ``memory``
(:mod:`runtime.decision.observation`, "Memory"). The training worlds build one row per robot
per step, as a robot does; :class:`RowMemory` is the carrying: it puts the older rows behind
each new row (:meth:`stack`) and keeps the K - 1 newest for the next step (:meth:`advance`),
zeros at an episode's start, as the robot's controller starts from zeros.
"""

from __future__ import annotations

import numpy as np

from runtime.types import BoolArray, F32Array

__all__ = ["RowMemory"]


class RowMemory:
    """The older rows of every robot of E worlds: (E, N, (frames - 1) * dim), zeros at start."""

    def __init__(self, frames: int, n_envs: int, n_robots: int, dim: int) -> None:
        self.size = (frames - 1) * dim
        self.rows = np.zeros((n_envs, n_robots, self.size), dtype=np.float32)

    def stack(self, obs: F32Array) -> F32Array:
        """What the brain reads: each robot's row, then its memory, (E, N, frames * dim)."""
        if not self.size:
            return obs
        return np.concatenate([obs, self.rows], axis=-1)

    def final(self, last: F32Array, stacked: F32Array) -> F32Array:
        """The inputs of the last observations ``last`` (k, N, dim) of k worlds whose episode
        ended, whose inputs of the step before were ``stacked`` (k, N, frames * dim)."""
        if not self.size:
            return last
        return np.concatenate([last, stacked[..., : self.size]], axis=-1)

    def advance(self, stacked: F32Array, done: BoolArray) -> None:
        """After a step that read ``stacked``: its newest rows are the next memory, zeros in
        the worlds that are ``done`` (E,) (a new episode starts there)."""
        if not self.size:
            return
        self.rows = np.ascontiguousarray(stacked[..., : self.size])
        self.rows[done] = 0.0
