"""Checkpoints of a training run: the state a run carries, saved, resumed, fine-tuned from.

A checkpoint (``<stem>.ckpt.pt``: the latest state, for ``--resume``;
``<stem>.best.pt``: the state at the best held-out evaluation, for ``--init``) is a
``torch.save`` of one dict, read back with ``weights_only=True``::

    config, obs_dim, observation, agent, optimisers, kl_coef, iteration, episodes,
    agent_steps, wall_s, stage, curve, best, best_state, generator

``best`` is ``{"success", "steps", "iteration", "state"}``: the held-out success
rate and mean steps of the best policy so far (of the last pattern stage), its
iteration and its weights; ``best_state`` repeats the weights for ``--init``.

``--init`` takes an ONNX brain or a ``.pt`` checkpoint (its best weights) of the
same observation; a brain carries no value network and no decoder, so the run
first fits them (:data:`VALUE_WARMUP_ITERATIONS`, :func:`fit_decoder`).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from runtime.decision.observation import ObservationSpec
from runtime.errors import InputError
from trainer.config import TrainConfig, obs_spec_for
from trainer.ppo.export import BrainFileError, agent_from_onnx, read_manifest
from trainer.ppo.networks import Agent, with_memory
from trainer.ppo.update import Optimisers, make_optimisers

VALUE_WARMUP_ITERATIONS = 3
"""Iterations that train only the value network after ``--init`` from a brain."""
DECODER_FIT_STEPS = 200
DECODER_FIT_ROWS = 4096


class InitError(InputError):
    """An ``--init`` or ``--resume`` file that cannot be used; one-line message."""


def new_best(agent: Agent) -> dict[str, Any]:
    """The best record before any evaluation."""
    return {"success": -1.0, "steps": math.inf, "iteration": -1, "state": agent.state_dict(),
            "collisions": math.inf}


def is_better(success: float, mean_steps: float, best: dict[str, Any],
              collisions: float = 0.0) -> bool:
    """Higher held-out success; as high with fewer collisions (in the episodes that failed:
    a brain whose runs all form is told apart by how often it touched a neighbour in the others);
    as high and as few in fewer steps. A record without collisions (an older checkpoint's)
    counts none."""
    best_success, best_steps = float(best["success"]), float(best["steps"])
    best_hits = float(best.get("collisions", 0.0))
    if success != best_success:
        return success > best_success
    if collisions != best_hits:
        return collisions < best_hits
    return mean_steps < best_steps


def best_record(success: float, mean_steps: float, iteration: int, agent: Agent,
                collisions: float = 0.0) -> dict[str, Any]:
    """A best record holding a copy of the agent's weights now."""
    return {"success": success, "steps": mean_steps, "iteration": iteration,
            "collisions": collisions, "state": copy.deepcopy(agent.state_dict())}


@dataclass
class TrainState:
    """What the training loop carries from one iteration to the next: what a checkpoint holds."""

    agent: Agent
    opt: Optimisers
    gen: torch.Generator
    """Action noise and minibatches: the run's one random stream."""
    kl_coef: float
    best: dict[str, Any]
    iteration: int = 0
    episodes: int = 0
    agent_steps: int = 0
    wall0_s: float = 0.0
    """Wall time spent before a resume."""
    stage0: int = 0
    """The pattern stage to start (or resume) at."""
    curve: list[dict[str, Any]] = field(default_factory=list)
    fit_decoder: bool = False
    """Fit a fresh decoder to the encoder before the first update (``--init`` from ONNX)."""
    value_warmup: int = 0
    """Iterations left that train only the value network."""


def start_state(cfg: TrainConfig, spec: ObservationSpec, v_max_mps: float,
                ck: dict[str, Any] | None, init: str | None) -> TrainState:
    """A fresh run, a resumed one (``ck``), or one fine-tuning ``init``."""
    gen = torch.Generator().manual_seed(cfg.seed)
    agent = Agent(spec.input_dim, cfg, v_max_mps)
    st = TrainState(agent, make_optimisers(agent, cfg), gen, cfg.kl_coef_init, new_best(agent))
    if ck is not None:
        _resume(st, ck)
    elif init:
        st.agent = load_init(init, cfg, v_max_mps, spec.input_dim)
        st.opt = make_optimisers(st.agent, cfg)
        st.fit_decoder = Path(init).suffix == ".onnx"
    # a brain carries no value network: fit a fresh one for a few iterations before the policy
    # moves on its advantages (and, for Pattern-RL, a fresh decoder to the brain's encoder)
    st.value_warmup = VALUE_WARMUP_ITERATIONS if st.fit_decoder else 0
    return st


def _resume(st: TrainState, ck: dict[str, Any]) -> None:
    st.agent.load_state_dict(ck["agent"])
    for o, s in zip(st.opt, ck["optimisers"], strict=True):
        if o is not None and s is not None:
            o.load_state_dict(s)
    st.kl_coef, st.iteration, st.episodes = ck["kl_coef"], ck["iteration"], ck["episodes"]
    st.agent_steps, st.wall0_s, st.stage0 = ck["agent_steps"], ck["wall_s"], ck["stage"]
    st.curve = ck["curve"]
    st.best = ck["best"]
    st.gen.set_state(ck["generator"])


def save_checkpoint(path: Path, st: TrainState, cfg: TrainConfig, spec: ObservationSpec,
                    wall_s: float, stage: int, patterns: Sequence[str] = ()) -> None:
    """Write the run as it stands (atomically: a temporary file, then a rename).
    ``patterns``: the run's pattern stages, which a resume without ``--pattern`` goes on with."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(
        {
            "config": cfg.to_dict(),
            "obs_dim": spec.input_dim,
            "observation": spec.to_dict(),
            "agent": st.agent.state_dict(),
            "optimisers": [o.state_dict() if o is not None else None for o in st.opt],
            "kl_coef": st.kl_coef,
            "iteration": st.iteration,
            "episodes": st.episodes,
            "agent_steps": st.agent_steps,
            "wall_s": wall_s,
            "stage": stage,
            "patterns": [str(p) for p in patterns],
            "curve": st.curve,
            "best": st.best,
            "best_state": st.best["state"],
            "generator": st.gen.get_state(),
        },
        tmp,
    )
    tmp.replace(path)


def load_checkpoint(p: Path) -> dict[str, Any]:
    """A checkpoint's dict; :class:`InitError` when it is not one."""
    try:
        ck: dict[str, Any] = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises unpickling and zip errors alike
        raise InitError(f"cannot read checkpoint {p}: {str(e).splitlines()[0][:200]}") from None
    if not isinstance(ck, dict) or "agent" not in ck or "config" not in ck:
        raise InitError(f"{p} is not a Pattern-RL checkpoint")
    return ck


def load_init(path: str, cfg: TrainConfig, v_max_mps: float, obs_dim: int) -> Agent:
    """An agent to fine-tune from: an ONNX brain or a ``.pt`` checkpoint."""
    p = Path(path)
    if not p.is_file():
        raise InitError(f"cannot read --init {path}: no such file")
    spec = obs_spec_for(cfg)
    if p.suffix == ".onnx":
        try:
            theirs = read_manifest(p).observation.to_dict()
            agent = agent_from_onnx(p, cfg, v_max_mps)
        except BrainFileError as e:
            raise InitError(str(e)) from None
    else:
        ck = load_checkpoint(p)
        ck_cfg = TrainConfig.from_dict(ck["config"])
        if ck_cfg.algo != cfg.algo:
            raise InitError(f"{path} was trained with --algo {ck_cfg.algo}, not {cfg.algo}")
        theirs = ck["observation"]
        agent = Agent(int(ck["obs_dim"]), ck_cfg, v_max_mps)
        agent.load_state_dict(ck.get("best_state") or ck["agent"])
    rows_only = {k: v for k, v in spec.to_dict().items() if k != "frames"}
    if spec.frames > 1 and theirs == rows_only:
        # a brain without memory grows one: it starts reading its older rows with zero weights
        agent = with_memory(agent, spec.frames, cfg.with_(residual=agent.residual), v_max_mps)
        theirs = spec.to_dict()
    if theirs != spec.to_dict() or agent.obs_dim != obs_dim:
        raise InitError(
            f"{path} reads the observation {theirs}, this run builds {spec.to_dict()} "
            f"(--obs {cfg.obs}, {cfg.n_robots} robots)"
        )
    return agent


@torch.no_grad()
def fit_decoder(agent: Agent, opt: Optimisers, obs: torch.Tensor) -> None:
    """After loading an ONNX brain (no decoder inside): fit a fresh decoder to the frozen encoder.

    Otherwise the first auto-encoder steps would pull the encoder the policy
    relies on towards whatever a random decoder needs. ``obs`` (S, D) raw.
    """
    if agent.decoder is None or opt.ae is None:
        return
    dec_opt = torch.optim.Adam(agent.decoder.parameters(), lr=1e-3)
    # a few thousand rows do
    target = agent.normaliser(obs[:: max(1, obs.shape[0] // DECODER_FIT_ROWS)])
    e = agent.encoder(target)
    with torch.enable_grad():
        for _ in range(DECODER_FIT_STEPS):
            loss = (agent.decoder(e) - target).pow(2).sum(-1).mean()
            dec_opt.zero_grad()
            loss.backward()
            dec_opt.step()
