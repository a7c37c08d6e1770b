"""The training world's reward: paper eq. 6 plus two documented extras, per robot per step.

::

    r_i = R_g + R_c * c_i + beta * r_p + w_prog * prog_i + B * formed - w_trav * m_i

``c_i``: collisions robot i took part in this step. ``r_p`` is the *change* of
the formation error (eq. 7, the RMS distance under the best assignment and
translation), ``r_p = (err_{t-1} - err_t) / (v_max dt)``: a potential-based
form of eq. 7 (Ng et al. 1999), which telescopes over an episode to the error
removed, so it cannot be farmed and does not change which policy is optimal;
normalised so that the whole team moving at full speed straight at its slots
scores about +1. ``prog_i = (|p_i(t-1) - g_i| - |p_i(t) - g_i|) / (v_max dt)``
in [-1, 1]: robot i's own progress toward ``g_i``, the slot it was shown in its
observation at t-1 (the shared assignment's slot in world coordinates). A
training-only, per-robot credit signal; 0 disables it. ``formed``: 1 on the
step the pattern is formed (every robot). ``m_i = |p_i(t) - p_i(t-1)| / (v_max dt)``
in [0, 1]: the metres robot i moved this step, in full-speed steps; with the
step penalty it pays for exactly what the evaluation measures (steps until the
whole team is formed, metres travelled, contacts). 0 by default.

Reward constants (``RewardConfig()``; per robot, per step)

    ================ ======= =====================================================
    constant         default why
    ================ ======= =====================================================
    step_penalty     -0.05   R_g, fatigue (paper: negative constant). Small next
                             to the dense terms (O(1) per step) so it does not
                             drown them, large enough that dawdling short of
                             "formed" costs: at gamma = 0.99 hovering forever is
                             worth -5, so finishing is always better.
    collision_penalty -1.0   R_c per collision the robot is part of: 20 steps of
                             fatigue, one full-speed step of the robot's own
                             progress. A detour of a few steps is cheaper than a
                             contact, and pushing into a neighbour (no progress,
                             -1 every step) never pays.
    beta             1.0     weight of r_p (team progress, change form, above).
                             Summed over an episode it is the initial error in
                             steps (about 30-40 from uniform starts here): a
                             dense team signal on the paper's own term.
    progress_weight  1.0     per-robot progress toward its own slot: the
                             training-only credit signal that, in a calibration
                             run (DESIGN.md), made the difference between a
                             circle formed within 2 minutes of training and one
                             not formed after 12. 0 gives the paper's reward.
    formed_bonus     1.0     once, to every robot, on the formed step: marks
                             success in the return; the fatigue already makes
                             ending early pay, so it stays modest.
    travel_penalty   0.0     per full-speed step of motion (m_i above). Equal to
                             the step penalty, a step of the team and a step's
                             worth of one robot's travel cost the same.
    safety_penalty   0.0     per v_max of change the safety filter made to the
                             robot's command, when a run trains behind it
                             (``train_safety``): the filter keeps the training
                             safe and this teaches the brain to ask for what the
                             filter lets through, so that it is safe without it.
                             Paid by the rollout (:mod:`trainer.rollout`), where
                             the filter runs.
    proximity_penalty 0.0    per peer closer than ``2R + proximity_m``, growing
                             linearly from 0 there to this at contact (``2R``):
                             a dense signal before the sparse collision, for a
                             brain that is to keep its distance without the
                             filter (raw). Never paid by a formed pattern whose
                             slots are ``proximity_m`` or more apart beyond 2R.
    proximity_m      0.05    that band (m).
    ================ ======= =====================================================

    ``PAPER_REWARD`` is eq. 6 alone (no progress term, no bonus).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.types import Array, BoolArray, IntArray


@dataclass(frozen=True)
class RewardConfig:
    """Reward constants, per robot per step (see the module docstring's table)."""

    step_penalty: float = -0.05
    collision_penalty: float = -1.0
    beta: float = 1.0
    progress_weight: float = 1.0
    formed_bonus: float = 1.0
    travel_penalty: float = 0.0
    safety_penalty: float = 0.0
    proximity_penalty: float = 0.0
    proximity_m: float = 0.05


DEFAULT_REWARD = RewardConfig()
"""The documented defaults (the table above)."""

PAPER_REWARD = RewardConfig(progress_weight=0.0, formed_bonus=0.0)
"""The paper's eq. 6 alone: fatigue, collisions, team progress."""


def step_reward(
    cfg: RewardConfig,
    hits: IntArray,
    error_before: Array,
    error: Array,
    X: Array,
    goals_before: Array,
    dist_before: Array,
    formed: BoolArray,
    reach: float,
    dist_after: Array | None = None,
    X_before: Array | None = None,
    two_r: float = 0.2,
) -> Array:
    """One step's reward per robot, (N, E), robot-major as the training world keeps it.

    ``hits`` (N, E) collisions each robot took part in; ``error_before``,
    ``error`` (E,) formation error before and after the step (m); ``X``
    (2, N, E) positions after it; ``goals_before`` (2, N, E) the slots shown in
    the last observation and ``dist_before`` (N, E) the distances to them (m);
    ``formed`` (E,); ``reach`` = v_max dt (m). ``dist_after`` (N, E): each robot's
    distance to its goal *after* the step, for goals that move with the team (the rank
    matching's): the progress is then a difference of one per-robot potential, which
    telescopes over an episode, so goals that swap cannot be farmed; None: the distance
    to ``goals_before``. ``X_before`` (2, N, E): positions before the step, for the
    travel penalty (skipped without them). ``two_r`` (m): the distance between centres at
    contact, for the proximity penalty.
    """
    reward = cfg.collision_penalty * hits + cfg.step_penalty
    reward += (cfg.beta / reach) * (error_before - error)
    if cfg.progress_weight:
        after_len = dist_after
        if after_len is None:
            after = X - goals_before
            after_len = np.sqrt(after[0] * after[0] + after[1] * after[1])
        reward += (cfg.progress_weight / reach) * (dist_before - after_len)
    if cfg.travel_penalty and X_before is not None:
        moved = X - X_before
        reward -= (cfg.travel_penalty / reach) * np.sqrt(moved[0] * moved[0] + moved[1] * moved[1])
    if cfg.proximity_penalty:
        reward -= cfg.proximity_penalty * closeness(X, two_r, cfg.proximity_m)
    if cfg.formed_bonus and formed.any():
        reward[:, formed] += cfg.formed_bonus
    out: Array = reward.astype(np.float64, copy=False)
    return out


def closeness(X: Array, two_r: float, band_m: float) -> Array:
    """Each robot's closeness to its peers (N, E) from positions ``X`` (2, N, E): the sum
    over peers of ``1 - (d - two_r) / band_m`` clipped to [0, 1], 0 for a peer ``band_m``
    or more beyond contact, 1 at contact or closer."""
    dx = X[0][:, None, :] - X[0][None, :, :]
    dy = X[1][:, None, :] - X[1][None, :, :]
    d = np.sqrt(dx * dx + dy * dy)  # (N, N, E)
    near = np.clip(1.0 - (d - two_r) / band_m, 0.0, 1.0)
    n = X.shape[1]
    near[np.arange(n), np.arange(n)] = 0.0
    out: Array = near.sum(axis=1)
    return out
