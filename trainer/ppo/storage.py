"""Rollout memory ("mem" in Algorithm 1) and the returns computed from it.

One policy drives every robot (parameter sharing), so every robot's sample is
stored: arrays are time-major, ``(T, E, N, ...)`` for T steps of E worlds of N
robots, and flattened to ``T * E * N`` samples for the update.

Returns (Algorithm 1, line 11)
    ``Phi_t = sum_{t' >= t} gamma^(t'-t) r_t'``: the reward-to-go. The action
    taken at t only affects what comes after it, so rewards before t are not
    counted. ``r_t`` is the reward *received after* acting at t (the world
    returns it from ``step``), which is why the sum starts at t' = t: in the
    paper's notation that reward is already "after t". A rollout is cut every T
    steps; where an episode is still running at the cut, the tail is
    bootstrapped with the value of the next observation. An episode that ends
    (formed, collided-out or at the step limit) is not bootstrapped.

Advantages
    ``mc`` (the paper): ``A = Phi - V``. ``gae``: generalised advantage
    estimation (Schulman et al. 2016), ``A = sum (gamma lambda)^k delta_{t+k}``,
    with returns ``A + V`` as the value target; ``gae_lambda = 1`` gives back
    ``mc`` exactly.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from numpy.typing import NDArray

F32 = NDArray[np.float32]


class RolloutBatch(NamedTuple):
    """Flat training samples, one row per (step, world, robot). Tensors, float32."""

    obs: torch.Tensor  # (S, D) what the normaliser reads: the observation or the front end's
    actions: torch.Tensor  # (S, 2) sampled actions in units of v_max
    old_mean: torch.Tensor  # (S, 2) behaviour policy mean (units of v_max)
    old_std: torch.Tensor  # (S, 2) behaviour policy std
    old_logprob: torch.Tensor  # (S,)
    returns: torch.Tensor  # (S,) value targets Phi
    advantages: torch.Tensor  # (S,)
    safe_mean: torch.Tensor | None = None  # (S, 2) safety_imitation's target (v_max)


class Rollout:
    """Fixed-size, time-major memory for one iteration's samples."""

    def __init__(self, steps: int, n_envs: int, n_robots: int, obs_dim: int) -> None:
        shape = (steps, n_envs, n_robots)
        self.obs = np.zeros((*shape, obs_dim), np.float32)
        self.actions = np.zeros((*shape, 2), np.float32)
        self.mean = np.zeros((*shape, 2), np.float32)
        self.std = np.zeros((*shape, 2), np.float32)
        self.logprob = np.zeros(shape, np.float32)
        self.rewards = np.zeros(shape, np.float32)
        self.values = np.zeros(shape, np.float32)
        self.dones = np.zeros((steps, n_envs), np.float32)  # episode ended after step t
        self.safe_mean: F32 | None = None  # (T, E, N, 2) the filter's lesson, where taken
        self.t = 0

    def add(
        self,
        obs: F32,
        actions: F32,
        mean: F32,
        std: F32,
        logprob: F32,
        values: F32,
        rewards: F32,
        dones: NDArray[np.bool_],
    ) -> None:
        t = self.t
        self.obs[t], self.actions[t], self.mean[t], self.std[t] = obs, actions, mean, std
        self.logprob[t], self.values[t], self.rewards[t] = logprob, values, rewards
        self.dones[t] = dones
        self.t += 1

    def add_lesson(self, safe_mean: F32) -> None:
        """``safety_imitation``'s targets for the last step (E, N, 2), units of v_max."""
        if self.safe_mean is None:
            self.safe_mean = self.mean.copy()
        self.safe_mean[self.t - 1] = safe_mean

    def batch(
        self, last_values: F32, gamma: float, mode: str = "gae", gae_lambda: float = 0.95
    ) -> RolloutBatch:
        """Returns and advantages, flattened to a :class:`RolloutBatch`."""
        dones = np.broadcast_to(self.dones[..., None], self.rewards.shape)
        if mode == "mc":
            returns = discounted_returns(self.rewards, dones, last_values, gamma)
            adv = returns - self.values
        else:
            adv = gae(self.rewards, self.values, dones, last_values, gamma, gae_lambda)
            returns = adv + self.values

        def flat(a: NDArray[np.float32]) -> torch.Tensor:
            a = np.ascontiguousarray(a, dtype=np.float32)
            n = self.rewards.size
            return torch.from_numpy(a.reshape(n, -1) if a.size > n else a.reshape(n))

        return RolloutBatch(
            obs=flat(self.obs),
            actions=flat(self.actions),
            old_mean=flat(self.mean),
            old_std=flat(self.std),
            old_logprob=flat(self.logprob),
            returns=flat(returns),
            advantages=flat(adv),
            safe_mean=None if self.safe_mean is None else flat(self.safe_mean),
        )


def discounted_returns(
    rewards: F32, dones: NDArray[np.floating], last_values: F32, gamma: float
) -> F32:
    """Reward-to-go Phi over time-major arrays (T, ...), bootstrapped at the cut.

    ``dones[t]`` is 1 when the episode ended with the reward ``rewards[t]``;
    ``last_values`` (...) is V of the observation after the last step.
    """
    out = np.zeros_like(rewards, dtype=np.float32)
    running = np.asarray(last_values, dtype=np.float32)
    for t in reversed(range(rewards.shape[0])):
        running = rewards[t] + gamma * running * (1.0 - dones[t])
        out[t] = running
    return out


def gae(
    rewards: F32,
    values: F32,
    dones: NDArray[np.floating],
    last_values: F32,
    gamma: float,
    gae_lambda: float,
) -> F32:
    """Generalised advantage estimates over time-major arrays (T, ...)."""
    adv = np.zeros_like(rewards, dtype=np.float32)
    running = np.zeros_like(last_values, dtype=np.float32)
    next_values = np.asarray(last_values, dtype=np.float32)
    for t in reversed(range(rewards.shape[0])):
        live = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_values * live - values[t]
        running = delta + gamma * gae_lambda * live * running
        adv[t] = running
        next_values = values[t]
    return adv
