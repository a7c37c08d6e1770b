"""One update of Pattern-RL: Algorithm 1, lines 5-23, top to bottom.

:func:`update` takes one iteration's memory (every robot's samples) and runs,
in the paper's order and with its symbols:

* lines 5-7   the auto-encoder ``I_mu``: P gradient steps on the reconstruction
  loss ``sum (I_mu(o) - o)^2``;
* lines 8-13  the policy ``pi_theta``: M gradient steps (Adam) on the surrogate
  ``J(theta) = ratio * A - lambda * KL(pi_theta || pi_old)``, with
  ``ratio = pi_theta(a|e) / pi_old(a|e)`` and ``e = I_mu(o)``;
* lines 14-18 the value ``V_phi``: B gradient steps on ``(Phi - V_phi(e))^2``;
* lines 19-23 the KL coefficient ``lambda``, adapted against ``kl_target`` and
  clipped to ``[kl_coef_min, kl_coef_max]`` (the paper's vartheta range).

With ``safety_imitation`` > 0 (not in the paper) the policy's M steps fit the safety filter's
command for its teacher's on the same observation (:func:`trainer.rollout.safety_lesson`) in
the surrogate's place: ``w * mean |mu - safe|^2`` over the minibatch, plus the KL penalty as
before (none for ``ppo``), which bounds each step and adapts as before. Fine-tuning the paper
brains on the surrogate and the lesson together undid their forming in 12-16 iterations
(held-out success 83 % -> 0 %; the surrogate alone dipped as low and recovered), the lesson
alone did not: it is behaviour cloning of the filtered teacher on the states the student
reaches (DAgger). The value and the auto-encoder train as before.

``algo="ppo"`` is the paper's ablation, standard PPO: the same function and
networks with the auto-encoder skipped (``e`` is the normalised observation)
and the clipped surrogate ``min(ratio * A, clip(ratio, 1 +- eps) * A)`` in
place of the KL penalty; lambda is left alone.

**Direction of the lambda adaptation.** As printed, Algorithm 1 sets
``lambda <- alpha * lambda`` when KL > beta_high * KL_target and
``lambda <- lambda / alpha`` when KL < beta_low * KL_target, with alpha = 0.5.
That *halves* the penalty exactly when the policy moved too far, and doubles it
when the policy barely moved: a feedback loop that drives the step size away
from the target instead of towards it. The text beside it says the opposite
("this modification ensures the deviation of the new policy from the preceding
policy is relatively small"), and so does the PPO paper's adaptive-KL variant it
extends (Schulman et al. 2017, section 4: beta <- 2 beta when d > 1.5 d_targ).
We implement the direction that bounds the policy change::

    if KL > beta_high * KL_target: lambda <- lambda / alpha   # penalty grows (x2 at alpha = 0.5)
    if KL < beta_low  * KL_target: lambda <- lambda * alpha   # penalty shrinks
    lambda <- clip(lambda, kl_coef_min, kl_coef_max)

with the paper's alpha = 0.5 exposed as ``TrainConfig.kl_alpha``.

The KL is measured against the behaviour policy stored in memory (its mean and
std per sample), so it counts every change of the action distribution, the
auto-encoder's too: ``UpdateStats.kl_encoder`` is the part already there before
the first policy step (the new code ``e`` under the old policy), which lambda
cannot control. It stays around 5 % of the KL at the defaults. (When all worlds
reset in lockstep, each memory held one episode phase and KL swung by 10x from
one iteration to the next, driving lambda to its ceiling: hence the training
loop's desynchronised first episodes.)

Samples are drawn from memory as minibatches of ``cfg.minibatch`` rows: each
of the P, M and B steps takes the next slice of a shuffled permutation, and a
new permutation is drawn when one is used up. All randomness comes from the
``torch.Generator`` passed in, so an update is reproducible.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import torch
from torch import nn

from trainer.config import TrainConfig
from trainer.ppo.networks import Agent, gaussian_kl, gaussian_logprob
from trainer.ppo.storage import RolloutBatch


class Optimisers(NamedTuple):
    """Adam for each network, optimised separately as the paper does."""

    ae: torch.optim.Optimizer | None
    policy: torch.optim.Optimizer
    value: torch.optim.Optimizer


class UpdateStats(NamedTuple):
    ae_loss: float  # mean reconstruction loss of the last P steps (nan for ppo)
    policy_loss: float  # mean -J(theta) over the M steps
    value_loss: float  # mean (Phi - V)^2 over the B steps
    kl: float  # KL(pi_theta || pi_old) on the whole batch after the M steps
    kl_coef: float  # lambda after adaptation (line 23)
    clip_frac: float  # fraction of samples with |ratio - 1| > clip_coef (diagnostic)
    std: float  # mean action std, units of v_max
    explained_var: float  # 1 - Var(Phi - V) / Var(Phi) before the value steps
    kl_encoder: float  # KL to pi_old before the policy steps: the auto-encoder's (and
    # normaliser's) share of the policy change


def make_optimisers(agent: Agent, cfg: TrainConfig) -> Optimisers:
    ae = None
    if agent.decoder is not None:
        params = [*agent.encoder.parameters(), *agent.decoder.parameters()]
        ae = torch.optim.Adam(params, lr=cfg.lr_ae, eps=1e-5)
    return Optimisers(
        ae=ae,
        policy=torch.optim.Adam(agent.policy.parameters(), lr=cfg.lr_policy, eps=1e-5),
        value=torch.optim.Adam(agent.value.parameters(), lr=cfg.lr_value, eps=1e-5),
    )


def minibatches(n: int, size: int, steps: int, gen: torch.Generator) -> Iterator[torch.Tensor]:
    """``steps`` index sets of ``size`` rows drawn from memory without replacement per pass."""
    size = min(size, n)
    per_pass = n // size
    perm = torch.empty(0, dtype=torch.long)
    for j in range(steps):
        k = j % per_pass
        if k == 0:
            perm = torch.randperm(n, generator=gen)
        yield perm[k * size : (k + 1) * size]


def adapt_kl_coef(kl_coef: float, kl: float, cfg: TrainConfig) -> float:
    """Lines 19-23, in the direction that bounds the policy change (see the module docstring)."""
    if kl > cfg.kl_beta_high * cfg.kl_target:
        kl_coef = kl_coef / cfg.kl_alpha
    elif kl < cfg.kl_beta_low * cfg.kl_target:
        kl_coef = kl_coef * cfg.kl_alpha
    return min(max(kl_coef, cfg.kl_coef_min), cfg.kl_coef_max)


def policy_loss(
    mean: torch.Tensor,
    std: torch.Tensor,
    b: RolloutBatch,
    idx: torch.Tensor,
    advantages: torch.Tensor,
    cfg: TrainConfig,
    kl_coef: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-J(theta) on a minibatch (Pattern-RL's KL penalty or PPO's clip), and the ratios."""
    ratio = (gaussian_logprob(b.actions[idx], mean, std) - b.old_logprob[idx]).exp()
    if cfg.algo == "ppo":
        clipped = ratio.clamp(1.0 - cfg.clip_coef, 1.0 + cfg.clip_coef)
        return -torch.min(ratio * advantages, clipped * advantages).mean(), ratio
    kl = gaussian_kl(mean, std, b.old_mean[idx], b.old_std[idx])
    return -(ratio * advantages - kl_coef * kl).mean(), ratio


def safety_lesson_loss(mean: torch.Tensor, b: RolloutBatch, idx: torch.Tensor,
                       cfg: TrainConfig) -> torch.Tensor:
    """``safety_imitation`` times the mean over the minibatch of ``|mu - safe|^2`` (0 without
    the lesson)."""
    if not cfg.safety_imitation or b.safe_mean is None:
        return mean.new_zeros(())
    return cfg.safety_imitation * (mean - b.safe_mean[idx]).pow(2).sum(-1).mean()


def _step(
    opt: torch.optim.Optimizer, loss: torch.Tensor, params: list[nn.Parameter], cfg: TrainConfig
) -> None:
    opt.zero_grad(set_to_none=True)
    loss.backward()  # type: ignore[no-untyped-call]
    nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
    opt.step()


def update(
    agent: Agent,
    opt: Optimisers,
    b: RolloutBatch,
    cfg: TrainConfig,
    kl_coef: float,
    gen: torch.Generator,
) -> UpdateStats:
    """Algorithm 1, lines 5-23, on one iteration's memory ``b``; the stats hold the new lambda."""
    n = b.obs.shape[0]
    obs = agent.normaliser(b.obs)  # the normaliser is frozen during an update

    # ---- lines 5-7: train the auto-encoder on the stored observations
    ae_loss = float("nan")
    if cfg.uses_autoencoder and opt.ae is not None and agent.decoder is not None:
        ae_params = [*agent.encoder.parameters(), *agent.decoder.parameters()]
        losses = []
        for idx in minibatches(n, cfg.minibatch, cfg.ae_steps, gen):
            recon = agent.decoder(agent.encoder(obs[idx]))
            loss = (recon - obs[idx]).pow(2).sum(-1).mean()  # I(mu)
            _step(opt.ae, loss, ae_params, cfg)
            losses.append(loss.item())
        ae_loss = sum(losses) / max(len(losses), 1)

    with torch.no_grad():
        e = agent.encoder(obs)  # e_i^t = I_mu(o_i^t); the policy and value do not train I_mu
        mean, std = agent.policy(e)  # the policy not yet updated, on the new code e
        kl_encoder = float(gaussian_kl(mean, std, b.old_mean, b.old_std).mean())
        values = agent.value(e)
        var_phi = b.returns.var()
        explained_var = float(1.0 - (b.returns - values).var() / var_phi) if var_phi > 0 else 0.0

    # ---- lines 8-13: update the policy network, M steps on J(theta)
    pol_params = list(agent.policy.parameters())
    pol_losses, clip_hits = [], 0.0
    for idx in minibatches(n, cfg.minibatch, cfg.policy_steps, gen):
        adv = b.advantages[idx]  # A = Phi - V_phi(e) (or its GAE form), from the rollout
        if cfg.norm_adv:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        mean, std = agent.policy(e[idx])
        if cfg.safety_imitation:  # the lesson in the surrogate's place; the KL term stays
            adv = torch.zeros_like(adv)
        loss, ratio = policy_loss(mean, std, b, idx, adv, cfg, kl_coef)
        loss = loss + safety_lesson_loss(mean, b, idx, cfg)
        _step(opt.policy, loss, pol_params, cfg)
        pol_losses.append(loss.item())
        clip_hits += float(((ratio - 1.0).abs() > cfg.clip_coef).float().mean())

    # ---- lines 14-18: update the value network, B steps on (Phi - V)^2
    val_params = list(agent.value.parameters())
    val_losses = []
    for idx in minibatches(n, cfg.minibatch, cfg.value_steps, gen):
        loss = (b.returns[idx] - agent.value(e[idx])).pow(2).mean()  # nu(phi)
        _step(opt.value, loss, val_params, cfg)
        val_losses.append(loss.item())

    # ---- lines 19-23: adapt the KL penalty coefficient lambda, keep it in range
    with torch.no_grad():
        mean, std = agent.policy(e)
        kl = float(gaussian_kl(mean, std, b.old_mean, b.old_std).mean())
    if cfg.algo == "pattern-rl" and cfg.policy_steps > 0:
        kl_coef = adapt_kl_coef(kl_coef, kl, cfg)

    return UpdateStats(
        ae_loss=ae_loss,
        policy_loss=sum(pol_losses) / max(len(pol_losses), 1),
        value_loss=sum(val_losses) / max(len(val_losses), 1),
        kl=kl,
        kl_coef=kl_coef,
        clip_frac=clip_hits / max(len(pol_losses), 1),
        std=float(std.mean()),
        explained_var=explained_var,
        kl_encoder=kl_encoder,
    )
