"""Rollouts on Ray actors (``patternrl train --ray [ADDRESS] --ray-workers K``).

Imported only when a run asks for Ray (the ``distributed`` extra). Each of the
K actors holds its own :class:`~trainer.world.training_world.BatchWorld` with a
share of the run's envs (:func:`trainer.rollout.env_shares`); per iteration
the driver puts the agent in the object store once, every actor plays
``rollout_steps`` steps of its envs with :func:`trainer.rollout.collect_rollout`
(the very function the in-process source calls) and returns its samples, and
the driver joins them and runs the update. Seeds and noise: see
:mod:`trainer.rollout`.

Without an address a local Ray instance is started with one CPU per worker,
no dashboard and quiet logs, and shut down at the end; with one the driver
joins that cluster (``ray start --head`` on one machine, ``ray start
--address HEAD:6379`` on the others; every machine needs this project
installed with the same versions) and only disconnects at the end.
"""

from __future__ import annotations

import logging
import os
from typing import Any

import numpy as np
import torch

from runtime.errors import InputError
from runtime.world_config import WorldConfig
from trainer.config import TrainConfig
from trainer.ppo.networks import Agent
from trainer.ppo.storage import RolloutBatch
from trainer.rollout import (
    RolloutMode,
    RolloutResult,
    collect_parts,
    env_shares,
    join_batches,
    stage_parts,
    worker_generator,
)

LOCAL_OBJECT_STORE_BYTES = 256 * 1024 * 1024
"""A local instance's object store: an iteration's samples are a few MB."""


class RayError(InputError):
    """Ray is missing, or the cluster cannot be reached; one-line message."""


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise RayError(
            "--ray needs Ray: pip install 'patternrl[distributed]'"
        ) from None
    return ray


class RayCluster:
    """The driver's connection to Ray for one run: a local instance, or a running cluster."""

    def __init__(self, mode: RolloutMode) -> None:
        ray = _ray()
        self.ray = ray
        if ray.is_initialized():  # a caller (a notebook, a test) already connected: use it
            self.owned = False
            return
        self.owned = True
        kwargs: dict[str, Any] = {
            "include_dashboard": False,
            "log_to_driver": False,
            "logging_level": logging.ERROR,
        }
        try:
            if mode.address:
                ray.init(address=mode.address, **kwargs)
            else:
                cpus = max(1, min(mode.workers, os.cpu_count() or 1))
                ray.init(num_cpus=cpus, object_store_memory=LOCAL_OBJECT_STORE_BYTES, **kwargs)
        except (ConnectionError, RuntimeError, ValueError) as e:
            where = mode.address or "a local instance"
            raise RayError(f"cannot start Ray on {where}: {str(e).splitlines()[0][:200]}") from None

    def close(self) -> None:
        """Shut a local instance down; disconnect from a cluster (which keeps running)."""
        if self.owned and self.ray.is_initialized():
            self.ray.shutdown()


class RolloutWorker:
    """One actor: a share ``[a, b)`` of the stage's envs and, with K > 1, its own noise."""

    def __init__(self, cfg: TrainConfig, world: WorldConfig, pattern: str, it: int, stage: int,
                 share: tuple[int, int], worker: int, own_noise: bool) -> None:
        torch.set_num_threads(cfg.threads)
        torch.use_deterministic_algorithms(True)
        self.v_max_mps = world.v_max_mps
        self.parts = stage_parts(cfg, world, pattern, it, stage, share)
        self.gen = worker_generator(cfg, stage, it, worker) if own_noise else None

    def collect(self, agent: Agent, gen_state: torch.Tensor | None
                ) -> tuple[RolloutBatch, list[float], list[bool], torch.Tensor | None]:
        """A rollout of this worker's envs; the run's generator state in and out when given."""
        gen = self.gen
        if gen_state is not None:
            gen = torch.Generator()
            gen.set_state(gen_state)
        assert gen is not None
        ro = collect_parts(agent, self.parts, gen, self.v_max_mps)
        return ro.batch, ro.returns, ro.success, gen.get_state() if gen_state is not None else None


class RayRollouts:
    """The rollout source on K Ray actors (see the module docstring)."""

    def __init__(self, cfg: TrainConfig, world: WorldConfig, pattern: str, it: int, stage: int,
                 mode: RolloutMode) -> None:
        ray = _ray()
        self.ray = ray
        shares = env_shares(cfg.n_envs, mode.workers)
        actor = ray.remote(num_cpus=1)(RolloutWorker)
        single = mode.workers == 1
        self.workers = [
            actor.remote(cfg, world, pattern, it, stage, share, w, not single)
            for w, share in enumerate(shares)
        ]
        self.single = single

    def collect(self, agent: Agent, gen: torch.Generator) -> RolloutResult:
        ref = self.ray.put(agent)
        gen_state = gen.get_state() if self.single else None
        parts = self.ray.get([w.collect.remote(ref, gen_state) for w in self.workers])
        if self.single:
            gen.set_state(parts[0][3])  # the worker drew the run's noise: go on from there
        batch = join_batches([p[0] for p in parts])
        returns = [r for p in parts for r in p[1]]
        success = [s for p in parts for s in p[2]]
        return RolloutResult(batch, np.zeros((0,), dtype=np.float32), returns, success)

    def close(self) -> None:
        for w in self.workers:
            self.ray.kill(w)
        self.workers = []


__all__ = ["RayCluster", "RayError", "RayRollouts", "RolloutWorker"]
