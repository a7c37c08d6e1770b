"""Where a training run's rollouts come from: the batch world in this process, or Ray actors.

The training loop (:mod:`trainer.train`) asks a :class:`RolloutSource` for one
rollout per iteration and learns from it; it does not know where the worlds
run. Two sources:

``InProcessRollouts``
    One :class:`~trainer.world.training_world.BatchWorld` of ``n_envs`` envs in the
    trainer's own thread (the default).

``RayRollouts`` (:mod:`trainer.ray_rollouts`, ``patternrl train --ray``)
    K Ray actors, each holding its own world of a share of the ``n_envs``
    envs (worker w owns envs ``[a_w, b_w)``): each iteration the driver puts
    the policy's weights in Ray's object store, every actor plays its share
    and the driver joins the K rollouts along the env axis and learns.

Seeds: env e's starts come from child e of ``SeedSequence(world_seed)``
whichever worker owns it (``BatchWorld(first_env=a_w)``), so K workers draw
the very starts one process would. Action noise: with one source of noise
(in-process, or a single Ray worker that is handed the run's generator state
and hands it back) every draw is the in-process draw, so one Ray worker
trains the same brain bit for bit; with K > 1 workers, worker w draws from
its own generator seeded from (seed, stage, iteration at the stage's start, w).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
import torch

from runtime.conditions import Conditions
from runtime.decision.pipeline import commands
from runtime.decision.safety import OrcaParams
from runtime.types import Array, F32Array
from runtime.world_config import WorldConfig
from trainer.config import TrainConfig, obs_spec_for, reward_for
from trainer.ppo.networks import Agent, gaussian_logprob
from trainer.ppo.storage import Rollout, RolloutBatch
from trainer.world.memory import RowMemory
from trainer.world.training_world import BatchWorld

RESUME_SEED_STRIDE = 7919
"""A resumed run's worlds are seeded from ``seed + RESUME_SEED_STRIDE * iteration``."""


@dataclass(frozen=True)
class RolloutMode:
    """How a run plays its rollouts: in-process, or on ``workers`` Ray actors."""

    ray: bool = False
    address: str | None = None
    """A running Ray cluster (``ray start --head`` prints it); None starts a local instance."""
    workers: int = 1

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ValueError(f"--ray-workers must be >= 1, got {self.workers}")

    def describe(self) -> dict[str, object]:
        """What the manifest records."""
        if not self.ray:
            return {"mode": "in-process"}
        return {"mode": "ray", "workers": self.workers, "address": self.address or "local"}


IN_PROCESS = RolloutMode()


def env_shares(n_envs: int, workers: int) -> list[tuple[int, int]]:
    """Each worker's envs ``[a, b)``: ``n_envs`` split as evenly as possible, in order."""
    if workers > n_envs:
        raise ValueError(f"{workers} Ray workers need at least as many envs, got {n_envs}")
    base, extra = divmod(n_envs, workers)
    out, a = [], 0
    for w in range(workers):
        b = a + base + (1 if w < extra else 0)
        out.append((a, b))
        a = b
    return out


def stage_world(cfg: TrainConfig, world: WorldConfig, pattern: str, it: int, stage: int,
                share: tuple[int, int] | None = None, conditions: Conditions | None = None
                ) -> tuple[BatchWorld, F32Array]:
    """A stage's worlds (all envs, or the ``share`` [a, b) of them) and their first observation,
    under ``conditions`` (default: the run's one)."""
    a, b = share if share is not None else (0, cfg.n_envs)
    world_seed = cfg.seed + RESUME_SEED_STRIDE * it  # it = 0 unless resumed
    bw = BatchWorld(b - a, cfg.n_robots, pattern, obs_spec_for(cfg), world=world,
                    reward=reward_for(cfg), seed=world_seed, first_env=a,
                    rank_goals=cfg.front in ("rank", "slots"),
                    conditions=conditions if conditions is not None else cfg.world_conditions,
                    hold_steps=cfg.hold_steps,
                    crowd=(cfg.crowded_share, cfg.crowded_arena_m))
    obs = bw.observe()
    if cfg.desync:
        # every world starts at once; cut each first episode at a random step (a
        # time-limit cut, bootstrapped) so that later memories mix all episode phases
        rng = np.random.default_rng([cfg.seed, it, stage])
        bw.steps[:] = rng.integers(0, bw.step_limit, size=cfg.n_envs)[a:b]
    return bw, obs


def condition_shares(cfg: TrainConfig, n_envs: int | None = None
                     ) -> list[tuple[tuple[int, int], str]]:
    """Each of the run's conditions (its spec) with its envs ``[a, b)`` of ``n_envs`` (default
    the run's): a mixture's envs split as evenly as possible, in the mixture's order."""
    specs = cfg.condition_specs
    return list(zip(env_shares(n_envs or cfg.n_envs, len(specs)), specs, strict=True))


@dataclass
class WorldPart:
    """The envs of one stage under one condition: a world, its observation, its memory."""

    cfg: TrainConfig
    """The run's settings with this part's ``n_envs`` and condition."""
    bw: BatchWorld
    obs: F32Array
    rows: RowMemory


def stage_parts(cfg: TrainConfig, world: WorldConfig, pattern: str, it: int, stage: int,
                share: tuple[int, int] | None = None) -> list[WorldPart]:
    """A stage's worlds (all envs, or the ``share`` [a, b) of them), one part per condition
    of the run that the share meets; env e lives under the same condition whoever holds it."""
    a, b = share if share is not None else (0, cfg.n_envs)
    parts = []
    for (ca, cb), spec in condition_shares(cfg):
        lo, hi = max(a, ca), min(b, cb)
        if lo < hi:
            part_cfg = cfg.with_(n_envs=hi - lo, conditions=spec)
            bw, obs = stage_world(cfg, world, pattern, it, stage, (lo, hi),
                                  part_cfg.world_conditions)
            parts.append(WorldPart(part_cfg, bw, obs, row_memory(part_cfg, hi - lo, bw.obs_dim)))
    return parts


class RolloutResult(NamedTuple):
    """What one rollout gathered."""

    batch: RolloutBatch
    obs: F32Array
    """The observation after the rollout, (E, N, D): where the next one starts."""
    returns: list[float]
    """Return of every episode that ended during the rollout."""
    success: list[bool]
    """Whether each of those formed with no collision."""


class RolloutSource(Protocol):
    """One rollout per call, from wherever the worlds live."""

    def collect(self, agent: Agent, gen: torch.Generator) -> RolloutResult:
        """``rollout_steps`` steps of every env under ``agent`` (noise from ``gen``)."""

    def close(self) -> None:
        """Release the worlds (and workers)."""


def worker_generator(cfg: TrainConfig, stage: int, it: int, worker: int) -> torch.Generator:
    """Worker ``worker``'s action-noise stream when K > 1 workers play."""
    seed = int(np.random.SeedSequence([cfg.seed, stage, it, worker]).generate_state(1)[0])
    return torch.Generator().manual_seed(seed)


def behind_filter(vel: Array, bw: BatchWorld, params: OrcaParams = OrcaParams()  # noqa: B008
                  ) -> Array:
    """The robots' safety filter between the brain and the world (``cfg.train_safety``):
    :func:`runtime.decision.pipeline.commands` with its defaults (or ``params``), the landing
    horizon of a plan observation's team included, as ``eval`` and the robots run it."""
    steps_left = bw.plan_steps_left if bw.obs_spec.name == "plan" else None  # as observed
    out: Array = commands(vel, bw.positions, bw.prev_positions, params, bw.world,
                          steps_left)[0]
    return out


def attach_teacher(agent: Agent) -> None:
    """Give ``agent`` its ``safety_imitation`` teacher: a frozen copy of itself as it is now (an
    attribute, not a sub-module: it is in no checkpoint and no exported brain)."""
    teacher = copy.deepcopy(agent)
    teacher.requires_grad_(False)
    object.__setattr__(agent, "lesson_teacher", teacher)


def safety_lesson(teacher: Agent, x: torch.Tensor, base: torch.Tensor, bw: BatchWorld,
                  v_max_mps: float, margin_m: float) -> F32Array:
    """``safety_imitation``'s targets for this step, (E, N, 2) in the policy's units (v_max, the
    rule's ``base`` removed): the safety filter's command (:func:`behind_filter` with a radius
    margin of ``margin_m``, the world as it is now) for the teacher's on the same rows ``x``."""
    E, N = bw.positions.shape[:2]
    with torch.no_grad():
        want = teacher.act_team_mps(x, N).numpy().reshape(E, N, 2).astype(np.float64)
    safe = behind_filter(want, bw, OrcaParams(radius_margin_m=margin_m))
    out: F32Array = ((safe - base.numpy().reshape(E, N, 2)) / v_max_mps).astype(np.float32)
    return out


def row_memory(cfg: TrainConfig, n_envs: int, dim: int) -> RowMemory:
    """The run's brain memory for ``n_envs`` worlds (none when ``memory_frames`` is 1)."""
    return RowMemory(cfg.memory_frames, n_envs, cfg.n_robots, dim)


def collect_rollout(agent: Agent, bw: BatchWorld, obs: F32Array, cfg: TrainConfig,
                    gen: torch.Generator, v_max_mps: float,
                    rows: RowMemory | None = None) -> RolloutResult:
    """Algorithm 1, *play game and update memory*: ``rollout_steps`` steps of every robot.

    Actions are sampled from the Gaussian (noise from ``gen``); worlds that finish
    an episode start the next at once; a time-limit cut is bootstrapped with
    V of the episode's last observation. ``rows``: a brain with memory's older rows
    (carried from one rollout to the next); None: a brain without memory.
    """
    E, N, T = cfg.n_envs, cfg.n_robots, cfg.rollout_steps
    mem = Rollout(T, E, N, agent.feature_dim)  # holds what the normaliser reads
    rows = rows if rows is not None else RowMemory(1, E, N, bw.obs_dim)
    safety_w = reward_for(cfg).safety_penalty
    teacher = getattr(agent, "lesson_teacher", None) if cfg.safety_imitation else None
    returns: list[float] = []
    success: list[bool] = []
    with torch.no_grad():
        for _ in range(T):
            x = rows.stack(obs)  # the row, then the brain's memory of its older rows
            xt = torch.from_numpy(x.reshape(E * N, -1))
            front = agent.front_features(xt, N)
            e = agent.encoder(agent.normaliser(front))
            mean, std = agent.policy(e)
            value = agent.value(e)
            a = mean + std * torch.randn(mean.shape, generator=gen)
            logp = gaussian_logprob(a, mean, std)
            base = agent.base_mps(xt)  # 0 unless residual
            vel = (a * v_max_mps + base).numpy().reshape(E, N, 2)
            moved = behind_filter(vel, bw) if cfg.train_safety else vel
            lesson = None if teacher is None else safety_lesson(
                teacher, xt, base, bw, v_max_mps, cfg.lesson_margin_m)
            res = bw.step(moved)
            reward = res.reward.copy()
            if cfg.train_safety and safety_w:  # what the filter had to change, per v_max
                reward -= safety_w * np.hypot(*(moved - vel).transpose(2, 0, 1)) / v_max_mps
            ep = res.episode
            if ep is not None:
                trunc = res.truncated[ep.env_ids]
                if trunc.any():  # bootstrap a time-limit cut with V(last obs)
                    final = rows.final(ep.final_obs[trunc], x[ep.env_ids[trunc]])
                    last = torch.from_numpy(final.reshape(-1, x.shape[-1]))
                    v_last = agent.value(agent.features(last, N)).numpy()
                    reward[ep.env_ids[trunc]] += cfg.gamma * v_last.reshape(-1, N)
                returns += ep.episode_return.tolist()
                success += (ep.formed & (ep.collisions == 0)).tolist()
            mem.add(front.numpy().reshape(E, N, -1), a.numpy().reshape(E, N, 2),
                    mean.numpy().reshape(E, N, 2), std.numpy().reshape(E, N, 2),
                    logp.numpy().reshape(E, N), value.numpy().reshape(E, N), reward, res.done)
            if lesson is not None:
                mem.add_lesson(lesson)
            rows.advance(x, res.done)
            obs = res.obs
        o_t = torch.from_numpy(rows.stack(obs).reshape(E * N, -1))
        last_values = agent.value(agent.features(o_t, N)).numpy().reshape(E, N)
    batch = mem.batch(last_values, cfg.gamma, cfg.returns, cfg.gae_lambda)
    return RolloutResult(batch, obs, returns, success)


def join_batches(batches: list[RolloutBatch]) -> RolloutBatch:
    """Several rollouts' samples as one batch (one batch as it is)."""
    if len(batches) == 1:
        return batches[0]
    def cat(cols: tuple[torch.Tensor | None, ...]) -> torch.Tensor | None:
        return None if any(c is None for c in cols) else torch.cat(
            [c for c in cols if c is not None])

    return RolloutBatch._make(cat(cols) for cols in zip(*batches, strict=True))


def collect_parts(agent: Agent, parts: list[WorldPart], gen: torch.Generator,
                  v_max_mps: float) -> RolloutResult:
    """:func:`collect_rollout` on every part in turn (one noise stream), joined; each part
    goes on from where its rollout ended."""
    results = []
    for p in parts:
        ro = collect_rollout(agent, p.bw, p.obs, p.cfg, gen, v_max_mps, p.rows)
        p.obs = ro.obs
        results.append(ro)
    if len(results) == 1:
        return results[0]
    return RolloutResult(join_batches([r.batch for r in results]),
                         np.concatenate([r.obs for r in results]),
                         [x for r in results for x in r.returns],
                         [x for r in results for x in r.success])


class InProcessRollouts:
    """The stage's worlds in this process: :func:`collect_rollout` on each condition's
    ``BatchWorld`` (one unless the run mixes conditions)."""

    def __init__(self, cfg: TrainConfig, world: WorldConfig, pattern: str, it: int, stage: int
                 ) -> None:
        self.cfg, self.v_max_mps = cfg, world.v_max_mps
        self.parts = stage_parts(cfg, world, pattern, it, stage)

    def collect(self, agent: Agent, gen: torch.Generator) -> RolloutResult:
        return collect_parts(agent, self.parts, gen, self.v_max_mps)

    def close(self) -> None:
        pass


__all__ = [
    "IN_PROCESS",
    "RESUME_SEED_STRIDE",
    "InProcessRollouts",
    "RolloutMode",
    "RolloutResult",
    "RolloutSource",
    "WorldPart",
    "attach_teacher",
    "behind_filter",
    "collect_parts",
    "collect_rollout",
    "condition_shares",
    "env_shares",
    "join_batches",
    "row_memory",
    "safety_lesson",
    "stage_parts",
    "stage_world",
    "worker_generator",
]
