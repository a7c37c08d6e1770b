"""The training loop: rollouts in the batch world, Algorithm 1's update, evaluation, files.

One iteration (Algorithm 1, one pass of its outer loop)
    1. *Play game and update memory*: every robot of ``n_envs`` worlds runs the
       current policy for ``rollout_steps`` steps (actions sampled from the
       Gaussian, parameter sharing: one policy, every robot's sample kept).
       Worlds that finish an episode start the next one at once; a truncated
       episode (step limit) is bootstrapped with V of its last observation.
    2. The observation normaliser folds in the new observations.
    3. :func:`trainer.ppo.update.update` (lines 5-23).
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
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from runtime.conditions import Conditions
from runtime.decision.patterns import make_pattern, pattern_label
from runtime.errors import InputError
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, HOLD_SHARE, WorldConfig
from trainer.checkpoints import (
    TrainState,
    best_record,
    fit_decoder,
    is_better,
    load_checkpoint,
    save_checkpoint,
    start_state,
)
from trainer.config import TrainConfig, obs_spec_for, reward_for
from trainer.curve import ProgressBar, curve_row, plot_curve, write_curve
from trainer.ppo.networks import Agent
from trainer.ppo.storage import RolloutBatch
from trainer.ppo.update import UpdateStats, update
from trainer.rollout import (
    IN_PROCESS,
    RESUME_SEED_STRIDE,
    InProcessRollouts,
    RolloutMode,
    RolloutSource,
    attach_teacher,
    behind_filter,
    condition_shares,
    row_memory,
)
from trainer.world.episodes import check_pattern
from trainer.world.training_world import BatchWorld

__all__ = ["RESUME_SEED_STRIDE", "RunPlan", "TrainResult", "train"]
RECENT_EPISODES_PER_ENV = 4
"""The curve's training reward and success average the last this-many x n_envs episodes."""


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
    rollouts: RolloutMode = IN_PROCESS
    """Where the rollouts play: in this process, or on Ray actors (:mod:`trainer.rollout`)."""

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
    rollouts: dict[str, object] | None = None
    """How the rollouts were played (``RolloutMode.describe()``), for the manifest."""


def set_determinism(cfg: TrainConfig) -> None:
    torch.set_num_threads(cfg.threads)
    torch.use_deterministic_algorithms(True)
    torch.manual_seed(cfg.seed)


def artefact_paths(out: Path) -> dict[str, Path]:
    """The files a run leaves beside its brain ``out``."""
    stem = out.with_suffix("")
    return {
        "curve_csv": stem.with_name(stem.name + ".curve.csv"),
        "curve_png": stem.with_name(stem.name + ".curve.png"),
        "checkpoint": stem.with_name(stem.name + ".ckpt.pt"),
        "best": stem.with_name(stem.name + ".best.pt"),
    }


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
    """Deterministic policy, the first episode of ``episodes`` seeded worlds; behind the safety
    filter when the run trains behind it (``cfg.train_safety``), else without. A run that pays
    for the filter's changes (``reward.safety_penalty``) or takes its lesson
    (``safety_imitation``) trains to be safe without it, and is judged without it. A run under
    a mixture of conditions is judged on each one's share of
    the episodes, split as its envs are."""
    parts = [_evaluate_under(agent, cfg, pattern, (a, b), seed, world,
                             cfg.with_(conditions=spec).world_conditions)
             for (a, b), spec in condition_shares(cfg, episodes)]
    ok, formed, steps, collisions, error = (np.concatenate(c) for c in zip(*parts, strict=True))
    return EvalSummary(
        success_rate=float(ok.mean()),
        mean_steps=float(steps[formed].mean()) if formed.any() else math.nan,
        collisions=int(collisions.sum()),
        formation_error=float(error.mean()),
    )


def _evaluate_under(agent: Agent, cfg: TrainConfig, pattern: str, share: tuple[int, int],
                    seed: int, world: WorldConfig, conditions: Conditions
                    ) -> tuple[BoolArray, BoolArray, Array, IntArray, Array]:
    """:func:`evaluate_policy`'s episodes ``[a, b)``, all under ``conditions``: success,
    formed, steps, collisions and final error per episode."""
    filtered = (cfg.train_safety and not reward_for(cfg).safety_penalty
                and not cfg.safety_imitation)
    first, episodes = share[0], share[1] - share[0]
    bw = BatchWorld(
        episodes,
        cfg.n_robots,
        pattern,
        obs_spec_for(cfg),
        world=world,
        reward=reward_for(cfg),
        seed=seed,
        first_env=first,
        conditions=conditions,
        hold_steps=cfg.hold_steps,
    )
    obs = bw.observe()
    rows = row_memory(cfg, episodes, bw.obs_dim)  # a brain with memory's older rows
    held = np.ones(episodes, bool)
    done = np.zeros(episodes, bool)
    formed = np.zeros(episodes, bool)
    steps = np.zeros(episodes)
    collisions = np.zeros(episodes, np.int64)
    error = np.zeros(episodes)
    while not done.all():
        x = rows.stack(obs)
        act = agent.act_team_mps(torch.from_numpy(x.reshape(-1, x.shape[-1])), cfg.n_robots)
        vel = act.numpy().reshape(episodes, cfg.n_robots, 2)
        res = bw.step(behind_filter(vel, bw) if filtered else vel)
        rows.advance(x, res.done)
        obs = res.obs
        ep = res.episode
        if ep is not None:
            new = ~done[ep.env_ids]
            ids = ep.env_ids[new]
            formed[ids], steps[ids] = ep.formed[new], ep.steps[new]
            collisions[ids], error[ids] = ep.collisions[new], ep.final_error[new]
            if cfg.hold_steps and ep.held is not None:
                held[ids] = ep.held[new] >= HOLD_SHARE
            done[ids] = True
    return formed & (collisions == 0) & held, formed, steps, collisions, error


# ------------------------------------------------------------------- rollouts


def rollout_source(cfg: TrainConfig, plan: RunPlan, pattern: str, it: int, stage: int
                   ) -> RolloutSource:
    """The plan's rollout source for one stage (Ray is imported only when asked for)."""
    if not plan.rollouts.ray:
        return InProcessRollouts(cfg, plan.world, pattern, it, stage)
    from trainer.ray_rollouts import RayRollouts

    return RayRollouts(cfg, plan.world, pattern, it, stage, plan.rollouts)


# ------------------------------------------------------------------- one run


@dataclass
class _Run:
    """What every step of the loop reads: the run's settings, files and clock."""

    cfg: TrainConfig
    plan: RunPlan
    files: dict[str, Path]
    t_start: float
    """``time.perf_counter()`` at the start, less the wall time before a resume."""
    progress: ProgressBar
    on_iteration: Callable[[dict[str, Any]], None] | None

    def wall_s(self) -> float:
        return time.perf_counter() - self.t_start

    def save(self, st: TrainState, path: Path, wall_s: float, stage: int) -> None:
        save_checkpoint(path, st, self.cfg, obs_spec_for(self.cfg), wall_s, stage,
                        self.plan.patterns)


@dataclass
class _Stage:
    """One pattern of the plan, being trained."""

    index: int
    pattern: str
    eps0: int
    """Training episodes before this stage."""
    t0: float
    """``time.perf_counter()`` at its start."""
    returns: list[float]
    success: list[bool]


def train(
    cfg: TrainConfig,
    plan: RunPlan,
    on_iteration: Callable[[dict[str, Any]], None] | None = None,
) -> TrainResult:
    """Train per ``plan``; writes checkpoints and the curve when ``plan.write_files``.

    A resumed run (``plan.resume``) goes on with the configuration saved in its checkpoint.
    """
    ck = load_checkpoint(Path(plan.resume)) if plan.resume else None
    if ck is not None:
        cfg = TrainConfig.from_dict(ck["config"])
    set_determinism(cfg)
    for p in plan.patterns:  # a bad pattern fails now, with its one-line message
        check_pattern(p, cfg.n_robots, plan.world)
        if cfg.front in ("slots", "transport") and p == "random":
            raise InputError(f"a brain with the {cfg.front} front end carries one pattern; "
                             "train it on a named pattern or a points file, not 'random'")
    st = start_state(cfg, obs_spec_for(cfg), plan.world.v_max_mps, ck, plan.init)
    if cfg.safety_imitation:
        attach_teacher(st.agent)
    total_eps = plan.episodes * (len(plan.patterns) - st.stage0) if plan.episodes else None
    run = _Run(cfg, plan, artefact_paths(plan.out), time.perf_counter() - st.wall0_s,
               ProgressBar(plan.progress, total_eps, plan.log_every), on_iteration)
    stopped = "budget"
    cluster = None
    if plan.rollouts.ray:
        from trainer.ray_rollouts import RayCluster

        cluster = RayCluster(plan.rollouts)
    try:
        for stage in range(st.stage0, len(plan.patterns)):
            stopped = _train_stage(run, st, stage)
    finally:
        run.progress.close()
        if cluster is not None:
            cluster.close()
    return _finish(run, st, stopped)


def _train_stage(run: _Run, st: TrainState, stage: int) -> str:
    """Train one pattern until one of the plan's stops; which one."""
    cfg, plan = run.cfg, run.plan
    pattern = plan.patterns[stage]
    front = st.agent.front
    if front is not None and front.with_slots:  # the brain carries the stage's pattern
        front.set_pattern(make_pattern(pattern, cfg.n_robots, plan.world))
    source = rollout_source(cfg, plan, pattern, st.iteration, stage)
    try:
        return _stage_loop(run, st, stage, pattern, source)
    finally:
        source.close()


def _stage_loop(run: _Run, st: TrainState, stage: int, pattern: str, source: RolloutSource
                ) -> str:
    cfg, plan = run.cfg, run.plan
    eps0 = st.episodes if stage > st.stage0 or not plan.resume else _stage_start(st.curve)
    sg = _Stage(stage, pattern, eps0, time.perf_counter(), [], [])
    while True:
        ro = source.collect(st.agent, st.gen)
        st.agent_steps += cfg.n_envs * cfg.n_robots * cfg.rollout_steps
        st.episodes += len(ro.returns)
        sg.returns += ro.returns
        sg.success += ro.success
        lr_scale = _lr_scale(cfg, plan, st.episodes - sg.eps0, time.perf_counter() - sg.t0)
        stats = _learn(st, ro.batch, cfg, lr_scale)
        ev = _evaluate(run, st, sg)
        row = _record(run, st, sg, ev, stats, lr_scale, len(ro.returns))
        _checkpoint(run, st, stage, float(row["wall_s"]))
        stop = _stop_reason(plan, ev, st.episodes - sg.eps0, time.perf_counter() - sg.t0)
        if stop is not None:
            return stop


def _learn(st: TrainState, batch: RolloutBatch, cfg: TrainConfig, lr_scale: float
           ) -> UpdateStats:
    """The normaliser, then Algorithm 1 lines 5-23, at the scaled learning rates."""
    if st.fit_decoder:
        fit_decoder(st.agent, st.opt, batch.obs)
        st.fit_decoder = False
    if not cfg.freeze_normaliser:
        st.agent.normaliser.update(batch.obs)
    base_lrs = [cfg.lr_ae, cfg.lr_policy, cfg.lr_value]  # in Optimisers order
    for o_, lr in zip(st.opt, base_lrs, strict=True):
        for g in o_.param_groups if o_ is not None else []:
            g["lr"] = lr * lr_scale
    step_cfg = cfg
    if st.value_warmup > 0:
        step_cfg = cfg.with_(ae_steps=0, policy_steps=0)
        st.value_warmup -= 1
    stats = update(st.agent, st.opt, batch, step_cfg, st.kl_coef, st.gen)
    st.kl_coef = stats.kl_coef
    st.iteration += 1
    return stats


def _evaluate(run: _Run, st: TrainState, sg: _Stage) -> EvalSummary | None:
    """Every ``eval_every`` iterations, the held-out evaluation; keeps the best checkpoint.

    Only the last pattern stage competes for best: it is the brain the run exports.
    """
    cfg = run.cfg
    if st.iteration % cfg.eval_every != 0:
        return None
    ev = evaluate_policy(st.agent, cfg, sg.pattern, cfg.eval_episodes,
                         cfg.seed + cfg.eval_seed_offset, run.plan.world)
    last_stage = sg.index == len(run.plan.patterns) - 1
    if last_stage and is_better(ev.success_rate, ev.mean_steps, st.best, ev.collisions):
        st.best = best_record(ev.success_rate, ev.mean_steps, st.iteration, st.agent,
                              ev.collisions)
        if run.plan.write_files:
            run.save(st, run.files["best"], run.wall_s(), sg.index)
    return ev


def _record(run: _Run, st: TrainState, sg: _Stage, ev: EvalSummary | None,
            stats: UpdateStats, lr_scale: float, new_episodes: int) -> dict[str, Any]:
    """The iteration's curve row: kept, shown and handed to ``on_iteration``."""
    recent = RECENT_EPISODES_PER_ENV * run.cfg.n_envs
    row = curve_row(
        iteration=st.iteration, stage=sg.index, pattern=pattern_label(sg.pattern),
        episodes=st.episodes, agent_steps=st.agent_steps, wall_s=run.wall_s(),
        recent_returns=sg.returns[-recent:], recent_success=sg.success[-recent:],
        eval_success=ev.success_rate if ev else math.nan,
        eval_steps=ev.mean_steps if ev else math.nan,
        stats=stats, kl_coef=st.kl_coef, lr_scale=lr_scale,
    )
    st.curve.append(row)
    run.progress.update(row, new_episodes)
    if run.on_iteration is not None:
        run.on_iteration(row)
    return row


def _checkpoint(run: _Run, st: TrainState, stage: int, wall_s: float) -> None:
    """Every ``checkpoint_every`` iterations: the latest state and the curve so far."""
    if run.plan.write_files and st.iteration % run.plan.checkpoint_every == 0:
        run.save(st, run.files["checkpoint"], wall_s, stage)
        write_curve(run.files["curve_csv"], st.curve)


def _stop_reason(plan: RunPlan, ev: EvalSummary | None, stage_eps: int, stage_s: float
                 ) -> str | None:
    """``success``, ``episodes`` or ``time`` once the stage is done; None to go on."""
    if plan.until_success is not None and ev and ev.success_rate >= plan.until_success:
        return "success"
    if plan.episodes is not None and stage_eps >= plan.episodes:
        return "episodes"
    if plan.time_budget_s is not None and stage_s >= plan.time_budget_s:
        return "time"
    return None


def _finish(run: _Run, st: TrainState, stopped: str) -> TrainResult:
    """The last checkpoint, the curve's files and the best agent."""
    cfg, plan = run.cfg, run.plan
    wall = run.wall_s()
    if st.best["iteration"] < 0:  # never evaluated: evaluate the final policy once
        ev = evaluate_policy(st.agent, cfg, plan.patterns[-1], cfg.eval_episodes,
                             cfg.seed + cfg.eval_seed_offset, plan.world)
        st.best = best_record(ev.success_rate, ev.mean_steps, st.iteration, st.agent,
                              ev.collisions)
    if plan.write_files:
        run.save(st, run.files["checkpoint"], wall, len(plan.patterns) - 1)
        write_curve(run.files["curve_csv"], st.curve)
        title = f"{cfg.algo}, {cfg.obs} observation, {cfg.n_robots} robots, " + " > ".join(
            pattern_label(p) for p in plan.patterns
        )
        plot_curve(run.files["curve_png"], st.curve, title)
    final_agent = copy.deepcopy(st.agent)  # same shapes (an --init brain may set the latent size)
    final_agent.load_state_dict(st.best["state"])
    return TrainResult(
        curve=st.curve,
        best_eval_success=float(st.best["success"]),
        best_iteration=int(st.best["iteration"]),
        best_state=st.best["state"],
        agent=final_agent,
        episodes=st.episodes,
        wall_s=wall,
        stopped=stopped,
        config=cfg,
        rollouts=plan.rollouts.describe(),
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
