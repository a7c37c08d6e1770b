"""The training loop: rollouts in the batch world, Algorithm 1's update, evaluation, files.

One iteration (Algorithm 1, one pass of its outer loop)
    1. *Play game and update memory*: every robot of ``n_envs`` worlds runs the
       current policy for ``rollout_steps`` steps (actions sampled from the
       Gaussian, parameter sharing: one policy, every robot's sample kept).
       Worlds that finish an episode start the next one at once; a truncated
       episode (step limit) is bootstrapped with V of its last observation.
    2. The observation normaliser folds in the new observations.
    3. :func:`trainer.update.update` (lines 5-23).
    4. Every ``eval_every`` iterations, a **held-out evaluation**: the
       deterministic policy (the mean, as the exported brain acts) on
       ``eval_episodes`` starts drawn from a seed stream training never uses
       (``seed + eval_seed_offset``), the same starts every time, without the
       safety filter (it measures the raw policy). Its success rate (formed
       within the step limit with no collision) is what ``--until-success``
       reads and what picks the **best checkpoint**; noisy training episodes
       are only logged.

Stopping: per pattern stage, at ``episodes`` training episodes, at a held-out
success >= ``until_success``, or after ``time_budget_s`` seconds, whichever
comes first. With several patterns (``--patterns circle,cross,line,heart``,
the paper's Fig. 5) each stage continues from where the last one ended, and
the curve records which pattern each row belongs to.

Files, beside the brain ``<stem>.onnx``:
``<stem>.json`` (manifest), ``<stem>.curve.csv`` and ``<stem>.curve.png``
(learning curve), ``<stem>.ckpt.pt`` (latest state, for ``--resume``) and
``<stem>.best.pt`` (best held-out evaluation, for ``--init``).

Determinism: with the same config and seed on CPU, two runs give identical
curves (wall-clock columns aside): the world's generators are seeded, action
noise and minibatches come from one seeded ``torch.Generator``,
``torch.use_deterministic_algorithms(True)`` and a fixed thread count. A
resumed run continues with the saved generator state but fresh worlds (seeded
from the seed and the iteration), so it is reproducible but not bit-identical
to an uninterrupted run.
"""

from __future__ import annotations

import copy
import csv
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from runtime.errors import InputError
from runtime.observation import ObservationSpec
from runtime.patterns import pattern_label
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from trainer.config import TrainConfig
from trainer.export import BrainFileError, agent_from_onnx, read_manifest
from trainer.networks import Agent, gaussian_logprob
from trainer.storage import Rollout
from trainer.training_world import BatchWorld, RewardConfig, check_pattern
from trainer.update import Optimisers, UpdateStats, make_optimisers, update

CURVE_FIELDS = (
    "iteration",
    "stage",
    "pattern",
    "episodes",
    "agent_steps",
    "wall_s",
    "mean_reward",
    "train_success",
    "eval_success",
    "eval_steps",
    "kl",
    "kl_encoder",
    "kl_coef",
    "ae_loss",
    "policy_loss",
    "value_loss",
    "std",
    "explained_var",
    "lr_scale",
)
WALL_FIELDS = ("wall_s",)
RESUME_SEED_STRIDE = 7919
VALUE_WARMUP_ITERATIONS = 3


class InitError(InputError):
    """An ``--init`` or ``--resume`` file that cannot be used; one-line message."""


@dataclass
class RunPlan:
    """What to train on and when to stop (the config says how)."""

    patterns: Sequence[str]
    out: Path
    episodes: int | None = None
    """Per stage: stop after this many training episodes."""
    until_success: float | None = None
    """Per stage: stop once the held-out success rate reaches this."""
    time_budget_s: float | None = None
    """Per stage: stop after this many seconds."""
    init: str | None = None
    resume: str | None = None
    checkpoint_every: int = 20
    log_every: int = 10
    progress: bool | None = None
    """tqdm bar on stderr; None: only when stderr is a terminal."""
    write_files: bool = True
    world: WorldConfig = DEFAULT_WORLD

    def __post_init__(self) -> None:
        if self.episodes is None and self.until_success is None and self.time_budget_s is None:
            raise ValueError("give a stop: episodes, until_success or time_budget_s")


class EvalSummary(NamedTuple):
    success_rate: float
    mean_steps: float  # over formed episodes (nan if none)
    collisions: int
    formation_error: float


@dataclass
class TrainResult:
    curve: list[dict[str, Any]]
    best_eval_success: float
    best_iteration: int
    best_state: dict[str, Any]
    agent: Agent
    episodes: int
    wall_s: float
    stopped: str
    config: TrainConfig


def obs_spec_for(cfg: TrainConfig) -> ObservationSpec:
    if cfg.obs == "paper":
        return ObservationSpec("paper", n_robots=cfg.n_robots)
    return ObservationSpec("general", k_neighbours=cfg.k_neighbours)


def reward_for(cfg: TrainConfig) -> RewardConfig:
    return RewardConfig(**cfg.reward)


def set_determinism(cfg: TrainConfig) -> None:
    torch.set_num_threads(cfg.threads)
    torch.use_deterministic_algorithms(True)
    torch.manual_seed(cfg.seed)


# ------------------------------------------------------------------- evaluation


@torch.no_grad()
def evaluate_policy(
    agent: Agent,
    cfg: TrainConfig,
    pattern: str,
    episodes: int,
    seed: int,
    world: WorldConfig = DEFAULT_WORLD,
) -> EvalSummary:
    """Deterministic policy, no safety filter, the first episode of ``episodes`` seeded worlds."""
    bw = BatchWorld(
        episodes,
        cfg.n_robots,
        pattern,
        obs_spec_for(cfg),
        world=world,
        reward=reward_for(cfg),
        seed=seed,
    )
    obs = bw.observe()
    done = np.zeros(episodes, bool)
    formed = np.zeros(episodes, bool)
    steps = np.zeros(episodes)
    collisions = np.zeros(episodes, np.int64)
    error = np.zeros(episodes)
    while not done.all():
        act = agent.act_mps(torch.from_numpy(obs.reshape(-1, bw.obs_dim)))
        res = bw.step(act.numpy().reshape(episodes, cfg.n_robots, 2))
        obs = res.obs
        ep = res.episode
        if ep is not None:
            new = ~done[ep.env_ids]
            ids = ep.env_ids[new]
            formed[ids], steps[ids] = ep.formed[new], ep.steps[new]
            collisions[ids], error[ids] = ep.collisions[new], ep.final_error[new]
            done[ids] = True
    ok = formed & (collisions == 0)
    return EvalSummary(
        success_rate=float(ok.mean()),
        mean_steps=float(steps[formed].mean()) if formed.any() else math.nan,
        collisions=int(collisions.sum()),
        formation_error=float(error.mean()),
    )


# ------------------------------------------------------------------ init, resume


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
        ck = _load_checkpoint(p)
        ck_cfg = TrainConfig.from_dict(ck["config"])
        if ck_cfg.algo != cfg.algo:
            raise InitError(f"{path} was trained with --algo {ck_cfg.algo}, not {cfg.algo}")
        theirs = ck["observation"]
        agent = Agent(int(ck["obs_dim"]), ck_cfg, v_max_mps)
        agent.load_state_dict(ck.get("best_state") or ck["agent"])
    if theirs != spec.to_dict() or agent.obs_dim != obs_dim:
        raise InitError(
            f"{path} reads the observation {theirs}, this run builds {spec.to_dict()} "
            f"(--obs {cfg.obs}, {cfg.n_robots} robots)"
        )
    return agent


def _load_checkpoint(p: Path) -> dict[str, Any]:
    try:
        ck: dict[str, Any] = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises unpickling and zip errors alike
        raise InitError(f"cannot read checkpoint {p}: {str(e).splitlines()[0][:200]}") from None
    if not isinstance(ck, dict) or "agent" not in ck or "config" not in ck:
        raise InitError(f"{p} is not a Pattern-RL checkpoint")
    return ck


@torch.no_grad()
def _warm_start(agent: Agent, opt: Optimisers, obs: torch.Tensor, cfg: TrainConfig) -> None:
    """After loading an ONNX brain (no decoder inside): fit a fresh decoder to the frozen encoder.

    Otherwise the first auto-encoder steps would pull the encoder the policy
    relies on towards whatever a random decoder needs.
    """
    if agent.decoder is None or opt.ae is None:
        return
    dec_opt = torch.optim.Adam(agent.decoder.parameters(), lr=1e-3)
    target = agent.normaliser(obs[:: max(1, obs.shape[0] // 4096)])  # a few thousand rows do
    e = agent.encoder(target)
    with torch.enable_grad():
        for _ in range(200):
            loss = (agent.decoder(e) - target).pow(2).sum(-1).mean()
            dec_opt.zero_grad()
            loss.backward()
            dec_opt.step()


# ---------------------------------------------------------------------- files


def write_curve(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=CURVE_FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt(r.get(k)) for k in CURVE_FIELDS})


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def plot_curve(path: Path, rows: list[dict[str, Any]], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = [r["episodes"] for r in rows]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a1.plot(ep, [r["mean_reward"] for r in rows], lw=1)
    a1.set_ylabel("mean episode reward")
    a1.set_title(title)
    ev = [(r["episodes"], r["eval_success"]) for r in rows if not math.isnan(r["eval_success"])]
    a2.plot(ep, [r["train_success"] for r in rows], lw=1, alpha=0.6, label="training episodes")
    if ev:
        a2.plot(*zip(*ev, strict=True), "o-", ms=3, label="held-out, deterministic")
    a2.set_ylabel("success rate")
    a2.set_xlabel("training episodes")
    a2.set_ylim(-0.02, 1.02)
    a2.legend(loc="lower right")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    stages = [r["episodes"] for i, r in enumerate(rows) if i and r["stage"] != rows[i - 1]["stage"]]
    for x in stages:
        a1.axvline(x, color="grey", ls=":")
        a2.axvline(x, color="grey", ls=":")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def artefact_paths(out: Path) -> dict[str, Path]:
    stem = out.with_suffix("")
    return {
        "curve_csv": stem.with_name(stem.name + ".curve.csv"),
        "curve_png": stem.with_name(stem.name + ".curve.png"),
        "checkpoint": stem.with_name(stem.name + ".ckpt.pt"),
        "best": stem.with_name(stem.name + ".best.pt"),
    }


# ---------------------------------------------------------------------- train


class _Progress:
    """A tqdm bar on stderr when it is a terminal; else one plain line every N iterations."""

    def __init__(self, enabled: bool | None, total: int | None, log_every: int) -> None:
        self.bar: Any = None
        self.log_every = log_every
        use_bar = sys.stderr.isatty() if enabled is None else enabled
        if use_bar:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="ep", file=sys.stderr, dynamic_ncols=True)
        self.quiet = enabled is False

    def update(self, row: dict[str, Any], new_episodes: int) -> None:
        fields = {
            "rew": f"{row['mean_reward']:.2f}",
            "succ": f"{row['train_success']:.2f}",
            "eval": "-" if math.isnan(row["eval_success"]) else f"{row['eval_success']:.2f}",
            "kl": f"{row['kl']:.4f}",
            "lam": f"{row['kl_coef']:.3g}",
        }
        if self.bar is not None:
            self.bar.set_description(f"{row['pattern']}")
            self.bar.set_postfix(fields, refresh=False)
            self.bar.update(new_episodes)
        elif not self.quiet and row["iteration"] % self.log_every == 0:
            text = " ".join(f"{k}={v}" for k, v in fields.items())
            print(
                f"train it={row['iteration']} {row['pattern']} ep={row['episodes']} "
                f"t={row['wall_s']:.0f}s {text}",
                file=sys.stderr,
                flush=True,
            )

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def train(
    cfg: TrainConfig,
    plan: RunPlan,
    on_iteration: Callable[[dict[str, Any]], None] | None = None,
) -> TrainResult:
    """Train per ``plan``; writes checkpoints and the curve when ``plan.write_files``.

    A resumed run (``plan.resume``) goes on with the configuration saved in its checkpoint.
    """
    ck = _load_checkpoint(Path(plan.resume)) if plan.resume else None
    if ck is not None:
        cfg = TrainConfig.from_dict(ck["config"])
    set_determinism(cfg)
    world = plan.world
    spec = obs_spec_for(cfg)
    for p in plan.patterns:  # a bad pattern fails now, with its one-line message
        check_pattern(p, cfg.n_robots, world)
    gen = torch.Generator().manual_seed(cfg.seed)
    files = artefact_paths(plan.out)

    def save(path: Path, wall_s: float, stage: int) -> None:
        """Checkpoint the run as it stands now (reads the loop's current state)."""
        _save(path, agent, opt, cfg, spec, kl_coef, it, episodes, agent_steps, wall_s, stage,
              curve, best, gen)

    agent = Agent(spec.dim, cfg, world.v_max_mps)
    opt = make_optimisers(agent, cfg)
    kl_coef = cfg.kl_coef_init
    it, episodes, agent_steps, wall0, stage0 = 0, 0, 0, 0.0, 0
    curve: list[dict[str, Any]] = []
    best: dict[str, Any] = {
        "success": -1.0,
        "steps": math.inf,
        "iteration": -1,
        "state": agent.state_dict(),
    }
    warm_start = False
    if ck is not None:
        agent.load_state_dict(ck["agent"])
        for o, s in zip(opt, ck["optimisers"], strict=True):
            if o is not None and s is not None:
                o.load_state_dict(s)
        kl_coef, it, episodes = ck["kl_coef"], ck["iteration"], ck["episodes"]
        agent_steps, wall0, stage0 = ck["agent_steps"], ck["wall_s"], ck["stage"]
        curve = ck["curve"]
        best = ck["best"]
        gen.set_state(ck["generator"])
    elif plan.init:
        agent = load_init(plan.init, cfg, world.v_max_mps, spec.dim)
        opt = make_optimisers(agent, cfg)
        warm_start = Path(plan.init).suffix == ".onnx"
    # a brain carries no value network: fit a fresh one for a few iterations before the policy
    # moves on its advantages (and, for Pattern-RL, a fresh decoder to the brain's encoder)
    value_warmup = VALUE_WARMUP_ITERATIONS if warm_start else 0

    E, N, T = cfg.n_envs, cfg.n_robots, cfg.rollout_steps
    v_max = world.v_max_mps
    t_start = time.perf_counter() - wall0
    stopped = "budget"
    total_eps = plan.episodes * (len(plan.patterns) - stage0) if plan.episodes else None
    progress = _Progress(plan.progress, total_eps, plan.log_every)
    base_lrs = [cfg.lr_ae, cfg.lr_policy, cfg.lr_value]  # in Optimisers order
    try:
        for stage in range(stage0, len(plan.patterns)):
            pattern = plan.patterns[stage]
            label = pattern_label(pattern)
            world_seed = cfg.seed + RESUME_SEED_STRIDE * it  # it = 0 unless resumed
            bw = BatchWorld(
                E, N, pattern, spec, world=world, reward=reward_for(cfg), seed=world_seed
            )
            obs = bw.observe()
            if cfg.desync:
                # every world starts at once; cut each first episode at a random step (a
                # time-limit cut, bootstrapped) so that later memories mix all episode phases
                rng = np.random.default_rng([cfg.seed, it, stage])
                bw.steps[:] = rng.integers(0, bw.step_limit, size=E)
            stage_eps0 = episodes if stage > stage0 or not plan.resume else _stage_start(curve)
            stage_t0 = time.perf_counter()
            ep_returns: list[float] = []
            ep_success: list[bool] = []
            stage_best = -1.0
            while True:
                # ---- 1. play game and update memory: T steps of every robot of E worlds
                mem = Rollout(T, E, N, bw.obs_dim)
                it_returns, it_success = [], []
                with torch.no_grad():
                    for _ in range(T):
                        o_t = torch.from_numpy(obs.reshape(E * N, -1))
                        e = agent.features(o_t)
                        mean, std = agent.policy(e)
                        value = agent.value(e)
                        a = mean + std * torch.randn(mean.shape, generator=gen)
                        logp = gaussian_logprob(a, mean, std)
                        res = bw.step((a * v_max).numpy().reshape(E, N, 2))
                        reward = res.reward.copy()
                        ep = res.episode
                        if ep is not None:
                            trunc = res.truncated[ep.env_ids]
                            if trunc.any():  # bootstrap a time-limit cut with V(last obs)
                                last = torch.from_numpy(ep.final_obs[trunc].reshape(-1, bw.obs_dim))
                                v_last = agent.value(agent.features(last)).numpy()
                                reward[ep.env_ids[trunc]] += cfg.gamma * v_last.reshape(-1, N)
                            it_returns += ep.episode_return.tolist()
                            it_success += (ep.formed & (ep.collisions == 0)).tolist()
                        mem.add(
                            obs,
                            a.numpy().reshape(E, N, 2),
                            mean.numpy().reshape(E, N, 2),
                            std.numpy().reshape(E, N, 2),
                            logp.numpy().reshape(E, N),
                            value.numpy().reshape(E, N),
                            reward,
                            res.done,
                        )
                        obs = res.obs
                    o_t = torch.from_numpy(obs.reshape(E * N, -1))
                    last_values = agent.value(agent.features(o_t)).numpy().reshape(E, N)
                batch = mem.batch(last_values, cfg.gamma, cfg.returns, cfg.gae_lambda)
                agent_steps += E * N * T
                episodes += len(it_returns)
                ep_returns += it_returns
                ep_success += it_success

                # ---- 2. normaliser, then 3. Algorithm 1 lines 5-23
                if warm_start:
                    _warm_start(agent, opt, batch.obs, cfg)
                    warm_start = False
                agent.normaliser.update(batch.obs)
                lr_scale = _lr_scale(
                    cfg, plan, episodes - stage_eps0, time.perf_counter() - stage_t0
                )
                for o_, lr in zip(opt, base_lrs, strict=True):
                    for g in o_.param_groups if o_ is not None else []:
                        g["lr"] = lr * lr_scale
                step_cfg = cfg
                if value_warmup > 0:
                    step_cfg = cfg.with_(ae_steps=0, policy_steps=0)
                    value_warmup -= 1
                stats: UpdateStats = update(agent, opt, batch, step_cfg, kl_coef, gen)
                kl_coef = stats.kl_coef
                it += 1

                # ---- 4. held-out evaluation, best checkpoint
                ev: EvalSummary | None = None
                if it % cfg.eval_every == 0:
                    ev = evaluate_policy(
                        agent,
                        cfg,
                        pattern,
                        cfg.eval_episodes,
                        cfg.seed + cfg.eval_seed_offset,
                        world,
                    )
                    stage_best = max(stage_best, ev.success_rate)
                    better = ev.success_rate > best["success"] or (
                        ev.success_rate == best["success"] and ev.mean_steps < best["steps"]
                    )
                    if stage == len(plan.patterns) - 1 and better:
                        best = {
                            "success": ev.success_rate,
                            "steps": ev.mean_steps,
                            "iteration": it,
                            "state": copy.deepcopy(agent.state_dict()),
                        }
                        if plan.write_files:
                            save(files["best"], time.perf_counter() - t_start, stage)

                recent = ep_returns[-4 * E :]
                row: dict[str, Any] = {
                    "iteration": it,
                    "stage": stage,
                    "pattern": label,
                    "episodes": episodes,
                    "agent_steps": agent_steps,
                    "wall_s": time.perf_counter() - t_start,
                    "mean_reward": float(np.mean(recent)) if recent else math.nan,
                    "train_success": float(np.mean(ep_success[-4 * E :])) if recent else math.nan,
                    "eval_success": ev.success_rate if ev else math.nan,
                    "eval_steps": ev.mean_steps if ev else math.nan,
                    "kl": stats.kl,
                    "kl_encoder": stats.kl_encoder,
                    "kl_coef": kl_coef,
                    "ae_loss": stats.ae_loss,
                    "policy_loss": stats.policy_loss,
                    "value_loss": stats.value_loss,
                    "std": stats.std,
                    "explained_var": stats.explained_var,
                    "lr_scale": lr_scale,
                }
                curve.append(row)
                progress.update(row, len(it_returns))
                if on_iteration is not None:
                    on_iteration(row)
                if plan.write_files and it % plan.checkpoint_every == 0:
                    save(files["checkpoint"], float(row["wall_s"]), stage)
                    write_curve(files["curve_csv"], curve)

                # ---- stop this stage?
                if plan.until_success is not None and ev and ev.success_rate >= plan.until_success:
                    stopped = "success"
                    break
                if plan.episodes is not None and episodes - stage_eps0 >= plan.episodes:
                    stopped = "episodes"
                    break
                if plan.time_budget_s is not None and (
                    time.perf_counter() - stage_t0 >= plan.time_budget_s
                ):
                    stopped = "time"
                    break
    finally:
        progress.close()

    wall = time.perf_counter() - t_start
    if best["iteration"] < 0:  # never evaluated: evaluate the final policy once
        ev = evaluate_policy(
            agent, cfg, plan.patterns[-1], cfg.eval_episodes, cfg.seed + cfg.eval_seed_offset, world
        )
        best = {
            "success": ev.success_rate,
            "steps": ev.mean_steps,
            "iteration": it,
            "state": copy.deepcopy(agent.state_dict()),
        }
    if plan.write_files:
        save(files["checkpoint"], wall, len(plan.patterns) - 1)
        write_curve(files["curve_csv"], curve)
        title = f"{cfg.algo}, {cfg.obs} observation, {N} robots, " + " > ".join(
            pattern_label(p) for p in plan.patterns
        )
        plot_curve(files["curve_png"], curve, title)
    final_agent = copy.deepcopy(agent)  # same shapes (an --init brain may set the latent size)
    final_agent.load_state_dict(best["state"])
    return TrainResult(
        curve=curve,
        best_eval_success=float(best["success"]),
        best_iteration=int(best["iteration"]),
        best_state=best["state"],
        agent=final_agent,
        episodes=episodes,
        wall_s=wall,
        stopped=stopped,
        config=cfg,
    )


def _stage_start(curve: list[dict[str, Any]]) -> int:
    """Episodes at the start of the last stage in a resumed curve."""
    if not curve:
        return 0
    stage = curve[-1]["stage"]
    before = [r["episodes"] for r in curve if r["stage"] < stage]
    return int(before[-1]) if before else 0


def _lr_scale(cfg: TrainConfig, plan: RunPlan, stage_eps: int, stage_s: float) -> float:
    """Linear decay over the stage's budget (episodes or time) when ``cfg.lr_decay``."""
    if not cfg.lr_decay:
        return 1.0
    fracs = []
    if plan.episodes:
        fracs.append(stage_eps / plan.episodes)
    if plan.time_budget_s:
        fracs.append(stage_s / plan.time_budget_s)
    return max(0.05, 1.0 - max(fracs)) if fracs else 1.0


def _save(
    path: Path,
    agent: Agent,
    opt: Optimisers,
    cfg: TrainConfig,
    spec: ObservationSpec,
    kl_coef: float,
    it: int,
    episodes: int,
    agent_steps: int,
    wall_s: float,
    stage: int,
    curve: list[dict[str, Any]],
    best: dict[str, Any],
    gen: torch.Generator,
) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(
        {
            "config": cfg.to_dict(),
            "obs_dim": spec.dim,
            "observation": spec.to_dict(),
            "agent": agent.state_dict(),
            "optimisers": [o.state_dict() if o is not None else None for o in opt],
            "kl_coef": kl_coef,
            "iteration": it,
            "episodes": episodes,
            "agent_steps": agent_steps,
            "wall_s": wall_s,
            "stage": stage,
            "curve": curve,
            "best": best,
            "best_state": best["state"],
            "generator": gen.get_state(),
        },
        tmp,
    )
    tmp.replace(path)
