"""The networks of Pattern-RL (paper section III.B and IV.B).

::

    raw obs o [--front end (paper brains, trainer.ppo.front_end)--> f]
              --normaliser--> o' --encoder I_mu--> e --policy pi_theta--> mean, std   (action)
                               \\--decoder (training only: reconstruction loss)
                                                  e --value V_phi--> V(e)

* **Observation normaliser**: running mean and standard deviation of the raw
  observations, updated by the training loop and frozen inside an update;
  baked into the exported brain as constants. Features whose spread is below
  ``STD_FLOOR`` (e.g. the neighbour mask when every neighbour is always
  present) are only centred, not scaled, so a value never seen in training
  stays moderate instead of being blown up by ``1 / std``. Clipped to +-5.
* **Auto-encoder** (Pattern-RL only): encoder ``D -> ae_hidden -> latent``
  (ReLU, linear latent), decoder the mirror image. It is trained only by its
  reconstruction loss (Algorithm 1 lines 5-7); the policy and value networks
  read its code ``e`` and do not back-propagate into it.
* **Policy** ``pi_theta``: 256-128-128 ReLU; a tanh mean and a softplus
  standard deviation (plus a small floor) per action axis, in units of v_max.
  Actions are cartesian velocities ``a = v_max * sample``; the deterministic
  action is ``v_max * tanh(.)``.
* **Value** ``V_phi``: 128-128-256 ReLU and one linear output.

**Residual** (``TrainConfig.residual``, general and plan observations): the
action is a rule's velocity plus ``v_max * tanh(.)`` of the policy. On the
general observation the rule is ``rule:assign``, ``clip_vmax(slot / dt)`` of
the slot vector (columns 0:2); on the plan observation it is the plan's step,
``v_max * columns 2:4`` (``rule:frame`` at the spec's travel weight: every
robot lands on its slot at the same step, exactly). The mean head's weights
and bias start at zero, so a fresh residual brain *is* the rule (to float32
rounding) and learning moves it from there. The rule part is in the exported
graph too (trainer/ppo/export.py).

With ``algo="ppo"`` (the ablation) there is no auto-encoder: policy and value
read the normalised observation directly; the networks are otherwise the same.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from trainer.config import TrainConfig
from trainer.ppo.front_end import RankFrontEnd

NORM_CLIP = 5.0
STD_FLOOR = 1e-3
POLICY_HIDDEN = (256, 128, 128)
VALUE_HIDDEN = (128, 128, 256)
LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


class ObsNormaliser(nn.Module):
    """``clip((o - mean) * inv_std, -5, 5)`` with running statistics (float64 inside)."""

    mean64: torch.Tensor
    var64: torch.Tensor
    count: torch.Tensor
    shift: torch.Tensor
    scale: torch.Tensor

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.register_buffer("mean64", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var64", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("shift", torch.zeros(dim))
        self.register_buffer("scale", torch.ones(dim))

    @torch.no_grad()
    def update(self, x: torch.Tensor | NDArray[np.floating]) -> None:
        """Fold a batch (..., D) into the statistics (Chan et al.'s parallel update)."""
        b = torch.as_tensor(np.asarray(x), dtype=torch.float64).reshape(-1, self.mean64.numel())
        n_b = float(b.shape[0])
        if n_b == 0:
            return
        mean_b, var_b = b.mean(0), b.var(0, unbiased=False)
        n_a = float(self.count)
        total = n_a + n_b
        delta = mean_b - self.mean64
        self.mean64 += delta * (n_b / total)
        self.var64.copy_((self.var64 * n_a + var_b * n_b + delta**2 * (n_a * n_b / total)) / total)
        self.count.fill_(total)
        self._refresh()

    def _refresh(self) -> None:
        std = self.var64.sqrt()
        scale = torch.where(std > STD_FLOOR, 1.0 / std.clamp_min(STD_FLOOR), torch.ones_like(std))
        self.shift.copy_(self.mean64.float())
        self.scale.copy_(scale.float())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = ((obs - self.shift) * self.scale).clamp(-NORM_CLIP, NORM_CLIP)
        return out


def mlp(sizes: list[int], out_gain: float = 1.0) -> nn.Sequential:
    """Linear layers with ReLU between them (none after the last), orthogonal init."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        lin = nn.Linear(sizes[i], sizes[i + 1])
        last = i == len(sizes) - 2
        nn.init.orthogonal_(lin.weight, out_gain if last else math.sqrt(2.0))
        nn.init.zeros_(lin.bias)
        layers.append(lin)
        if not last:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class Policy(nn.Module):
    """pi_theta(a | e): Gaussian with tanh mean and softplus std, both in units of v_max."""

    def __init__(self, in_dim: int, init_std: float = 0.5, min_std: float = 0.02) -> None:
        super().__init__()
        self.trunk = nn.Sequential(mlp([in_dim, *POLICY_HIDDEN], math.sqrt(2.0)), nn.ReLU())
        self.mean_head = nn.Linear(POLICY_HIDDEN[-1], 2)
        self.std_head = nn.Linear(POLICY_HIDDEN[-1], 2)
        nn.init.orthogonal_(self.mean_head.weight, 0.01)
        nn.init.zeros_(self.mean_head.bias)
        nn.init.orthogonal_(self.std_head.weight, 0.01)
        # softplus(b) + min_std = init_std at the start
        nn.init.constant_(self.std_head.bias, math.log(math.expm1(max(init_std - min_std, 1e-3))))
        self.min_std = float(min_std)

    def forward(self, e: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.trunk(e)
        mean = torch.tanh(self.mean_head(h))
        std = nn.functional.softplus(self.std_head(h)) + self.min_std
        return mean, std


class Value(nn.Module):
    """V_phi(e): 128-128-256 ReLU, one output."""

    def __init__(self, in_dim: int) -> None:
        super().__init__()
        self.net = mlp([in_dim, *VALUE_HIDDEN, 1])

    def forward(self, e: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.net(e).squeeze(-1)
        return out


class Agent(nn.Module):
    """Normaliser, auto-encoder (Pattern-RL only), policy and value, with v_max."""

    def __init__(
        self, obs_dim: int, cfg: TrainConfig, v_max_mps: float, dt_s: float = 0.1
    ) -> None:
        super().__init__()
        self.obs_dim = obs_dim  # the raw observation's length (the brain's input)
        self.v_max_mps = float(v_max_mps)
        self.residual = bool(getattr(cfg, "residual", False))
        self.on_plan = cfg.obs == "plan"  # the residual rides on the plan's step
        self.dt_s = float(dt_s)
        self.front: RankFrontEnd | None = None
        if cfg.front != "none":
            self.front = RankFrontEnd(cfg.n_robots, dt_s, v_max_mps * dt_s, mode=cfg.front)
            if obs_dim != 6 * (cfg.n_robots - 1):
                raise ValueError(f"the {cfg.front} front end reads the paper observation "
                                 f"({6 * (cfg.n_robots - 1)} numbers), not {obs_dim}")
            obs_dim = self.front.out_dim
        self.normaliser = ObsNormaliser(obs_dim)
        self.encoder: nn.Module
        self.decoder: nn.Module | None
        if cfg.uses_autoencoder:
            self.encoder = mlp([obs_dim, cfg.ae_hidden, cfg.latent_dim])
            self.decoder = mlp([cfg.latent_dim, cfg.ae_hidden, obs_dim])
            feat = cfg.latent_dim
        else:
            self.encoder = nn.Identity()
            self.decoder = None
            feat = obs_dim
        self.policy = Policy(feat, cfg.init_std, cfg.min_std)
        self.value = Value(feat)
        if self.residual:  # start exactly at the rule
            nn.init.zeros_(self.policy.mean_head.weight)
            nn.init.zeros_(self.policy.mean_head.bias)

    def base_mps(self, obs: torch.Tensor) -> torch.Tensor:
        """The velocity the residual is added to (m/s), (B, 2): the plan's step on the plan
        observation, else ``rule:assign``'s (slot vector / dt clipped to v_max); zeros when
        the agent is not residual."""
        if not self.residual:
            return torch.zeros(*obs.shape[:-1], 2, dtype=obs.dtype)
        if self.on_plan:
            return obs[..., 2:4] * self.v_max_mps
        v = obs[..., 0:2] / self.dt_s
        sp = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
        out: torch.Tensor = v * (self.v_max_mps / torch.clamp_min(sp, self.v_max_mps))
        return out

    def front_features(self, obs: torch.Tensor, team_rows: int = 0) -> torch.Tensor:
        """The fixed front end's output (trainer.ppo.front_end); the observation itself without.
        ``team_rows``: n when the rows come in whole teams (a shortcut, same result)."""
        return obs if self.front is None else self.front(obs, team_rows)

    @property
    def feature_dim(self) -> int:
        """What the normaliser reads: the front end's output, else the observation's length.
        The rollout memory stores this (the front end has no weights, so it is computed once
        per sample, not again in every update)."""
        return int(self.normaliser.shift.numel())

    def features(self, obs: torch.Tensor, team_rows: int = 0) -> torch.Tensor:
        """e = I_mu(normalise(front(o))) for raw observations (B, obs_dim)."""
        out: torch.Tensor = self.encoder(self.normaliser(self.front_features(obs, team_rows)))
        return out

    def act_team_mps(self, obs: torch.Tensor, team_rows: int) -> torch.Tensor:
        """:meth:`act_mps` for rows that come in whole teams of ``team_rows`` robots."""
        mean, _ = self.policy(self.features(obs, team_rows))
        out: torch.Tensor = mean * self.v_max_mps + self.base_mps(obs)
        return out

    def act_mps(self, obs: torch.Tensor) -> torch.Tensor:
        """Deterministic action in m/s: v_max * tanh(.). What the exported brain computes."""
        mean, _ = self.policy(self.features(obs))
        out: torch.Tensor = mean * self.v_max_mps + self.base_mps(obs)
        return out


def gaussian_logprob(a: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """log N(a; mean, diag(std^2)), summed over the last axis."""
    z = (a - mean) / std
    return (-0.5 * z * z - std.log() - LOG_SQRT_2PI).sum(-1)


def gaussian_kl(
    mean: torch.Tensor, std: torch.Tensor, mean_old: torch.Tensor, std_old: torch.Tensor
) -> torch.Tensor:
    """KL(pi || pi_old) for diagonal Gaussians, summed over the last axis."""
    return (
        (std_old / std).log() + (std**2 + (mean - mean_old) ** 2) / (2.0 * std_old**2) - 0.5
    ).sum(-1)


@torch.no_grad()
def with_memory(agent: Agent, frames: int, cfg: TrainConfig, v_max_mps: float) -> Agent:
    """``agent`` (which reads one row) grown to read ``frames`` rows, newest first, acting
    exactly as before: the weights on the older rows start at zero, the normaliser's statistics
    of the older rows are the row's, a decoder reconstructs each row as it did the one.
    What a brain with memory fine-tuned from one without starts from."""
    d = agent.obs_dim
    grown = Agent(frames * d, cfg, v_max_mps, agent.dt_s)
    grown.policy.min_std = agent.policy.min_std
    old = agent.state_dict()
    new = grown.state_dict()
    for key, w in new.items():
        o = old.get(key)
        if o is None:
            continue
        if o.shape == w.shape:
            new[key] = o.clone()
        elif o.dim() == 2 and w.shape == (o.shape[0], frames * o.shape[1]):  # reads the rows
            new[key] = torch.cat([o, torch.zeros(o.shape[0], (frames - 1) * o.shape[1],
                                                 dtype=o.dtype)], dim=1)
        elif o.dim() >= 1 and w.shape[0] == frames * o.shape[0]:  # one value per input
            new[key] = o.repeat(frames, *([1] * (o.dim() - 1)))
    grown.load_state_dict(new)
    return grown
