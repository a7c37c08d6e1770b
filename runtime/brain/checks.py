"""What a brain must answer before a robot runs it: its inputs and outputs, and finite actions
(and memory) on a fixed set of seeded probe observations.

:func:`runtime.brain.brain.validate_brain_bytes` runs these checks on every brain file and hot
swap; a failure is a one-line :class:`runtime.brain.manifest.BrainError`.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Final

import numpy as np
import onnxruntime as ort

from runtime.brain.manifest import BrainError, error_line
from runtime.decision.observation import (
    ObservationSpec,
    general_observation,
    paper_observation,
)
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

if TYPE_CHECKING:
    from runtime.brain.brain import OnnxBrain

__all__ = [
    "ACTION_NAME",
    "INPUT_NAME",
    "MEMORY_NAME",
    "MEMORY_OUT_NAME",
    "STD_NAME",
    "check_io",
    "probe",
    "probe_observations",
]

INPUT_NAME: Final = "obs"
MEMORY_NAME: Final = "memory"
MEMORY_OUT_NAME: Final = "memory_out"
ACTION_NAME: Final = "action"
STD_NAME: Final = "std"
N_PROBES: Final = 32
PROBE_SEED: Final = 20240917
WARM_RUNS: Final = 20


def probe_observations(spec: ObservationSpec, world: WorldConfig = DEFAULT_WORLD) -> Array:
    """A fixed, seeded set of plausible observations for ``spec``, (N_PROBES, spec.dim).

    Built with the real builders from random teams (so masks, slot features and
    velocities look like what a robot sees), plus an all-zero row. Cached: a
    robot validating a swap does not rebuild them (read-only array).
    """
    return _probes(spec, world)


@functools.lru_cache(maxsize=16)
def _probes(spec: ObservationSpec, world: WorldConfig) -> Array:
    rng = np.random.default_rng(PROBE_SEED)
    rows: list[Array] = [np.zeros((1, spec.dim))]
    if spec.name == "paper":
        n = spec.n_robots
        while sum(len(r) for r in rows) < N_PROBES:
            p0 = rng.uniform(0, world.arena_m, (n, 2))
            steps = rng.uniform(-1, 1, (2, n, 2)) * world.max_step_m
            frames = np.stack([p0, p0 - steps[0], p0 - steps[0] - steps[1]])
            rows.append(paper_observation(frames))
    else:
        k = spec.k_neighbours
        while sum(len(r) for r in rows) < N_PROBES:
            n = int(rng.integers(2, k + 4))
            p = rng.uniform(0, world.arena_m * 0.3, (n, 2))
            prev = p - rng.uniform(-1, 1, (n, 2)) * world.max_step_m
            slots = p + rng.normal(0, 1.0, (n, 2))
            rows.append(general_observation(p, prev, slots, k=k, world=world))
    out: Array = np.concatenate(rows)[:N_PROBES]
    out.setflags(write=False)
    return out


def _static_dim(d: object) -> int | None:
    return d if isinstance(d, int) and d > 0 else None


def check_io(session: ort.InferenceSession, spec: ObservationSpec) -> None:
    inputs = session.get_inputs()
    names = [i.name for i in inputs]
    want = [INPUT_NAME, MEMORY_NAME] if spec.memory_dim else [INPUT_NAME]
    if names != want:
        raise BrainError(f"brain inputs are {names}, but its spec "
                         f"(frames {spec.frames}) needs exactly {want}")
    if spec.memory_dim:
        _check_memory(session, spec.memory_dim)
    inp = inputs[0]
    if inp.type != "tensor(float)":
        raise BrainError(f"brain input '{INPUT_NAME}' is {inp.type}, expected tensor(float)")
    shape = list(inp.shape)
    if len(shape) != 2:
        raise BrainError(f"brain input '{INPUT_NAME}' has shape {shape}, expected [batch, obs_dim]")
    if _static_dim(shape[0]) is not None:
        raise BrainError(
            f"brain input '{INPUT_NAME}' has a fixed batch {shape[0]}, expected a dynamic axis"
        )
    if shape[1] != spec.dim:
        raise BrainError(
            f"brain input '{INPUT_NAME}' has obs_dim {shape[1]}, "
            f"but its spec '{spec.name}' needs {spec.dim}"
        )
    outputs = {o.name: o for o in session.get_outputs()}
    if ACTION_NAME not in outputs:
        raise BrainError(f"brain outputs are {sorted(outputs)}, expected '{ACTION_NAME}'")
    extra = sorted(set(outputs) - {ACTION_NAME, STD_NAME, MEMORY_OUT_NAME})
    if extra:
        raise BrainError(f"brain has unexpected outputs {extra}")
    act = outputs[ACTION_NAME]
    if act.type != "tensor(float)":
        raise BrainError(f"brain output '{ACTION_NAME}' is {act.type}, expected tensor(float)")
    ashape = list(act.shape)
    if len(ashape) != 2 or (_static_dim(ashape[1]) is not None and ashape[1] != 2):
        raise BrainError(f"brain output '{ACTION_NAME}' has shape {ashape}, expected [batch, 2]")


def _check_memory(session: ort.InferenceSession, memory_dim: int) -> None:
    """A brain with memory's ``memory`` input and ``memory_out`` output: float32
    [batch, memory_dim] both, the batch dynamic."""
    for kind, io in (("input", session.get_inputs()[1]),
                     ("output", {o.name: o for o in session.get_outputs()}.get(MEMORY_OUT_NAME))):
        name = MEMORY_NAME if kind == "input" else MEMORY_OUT_NAME
        if io is None:
            raise BrainError(f"brain has memory but no output '{MEMORY_OUT_NAME}'")
        shape = list(io.shape)
        if (io.type != "tensor(float)" or len(shape) != 2 or _static_dim(shape[0]) is not None
                or shape[1] != memory_dim):
            raise BrainError(f"brain {kind} '{name}' is {io.type} {shape}, expected "
                             f"tensor(float) [batch, {memory_dim}]")


def probe(brain: OnnxBrain, world: WorldConfig) -> None:
    """Run ``brain`` on the probes (and its memory twice): shapes right, every value finite."""
    probes = probe_observations(brain.spec, world)
    try:
        batch = brain.act(probes)
        singles = [brain.act(probes[i : i + 1]) for i in range(min(4, len(probes)))]
        for _ in range(WARM_RUNS):
            brain.act(probes[:1])
        if brain.memory_dim:  # the memory it answers, carried twice
            k = len(probes)
            _, mem = brain.act_memory(probes, np.zeros((k, brain.memory_dim), np.float32))
            batch_m, mem = brain.act_memory(probes, mem)
            if mem.shape != (k, brain.memory_dim) or not np.isfinite(mem).all():
                raise BrainError(f"brain answers a memory of shape {list(mem.shape)} or "
                                 f"non-finite, expected [{k}, {brain.memory_dim}] finite")
            batch = np.concatenate([batch, batch_m])
    except BrainError:
        raise
    except Exception as e:
        raise BrainError(f"brain failed on probe observations: {error_line(e)}") from None
    if batch.shape != ((2 if brain.memory_dim else 1) * len(probes), 2):
        raise BrainError(
            f"brain answered shape {list(batch.shape)} for {len(probes)} probes, "
            f"expected [{len(probes)}, 2]"
        )
    if not np.isfinite(batch).all() or not all(np.isfinite(s).all() for s in singles):
        bad = int((~np.isfinite(batch).all(axis=1)).sum())
        raise BrainError(f"brain outputs non-finite actions on {bad} of {len(probes)} probes")
    if any(s.shape != (1, 2) for s in singles):
        raise BrainError("brain answered a wrong shape for a batch of 1")
