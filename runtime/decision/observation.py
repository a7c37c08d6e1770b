"""Observation builders: the one copy that the trainer and every robot call.

Three specs, each a pure numpy function over a batch (leading axes free):

``paper`` (version 1, fixed n) -- the paper's observation
    The other robots' positions relative to the robot, in three consecutive
    frames (t, t-1, t-2), each frame relative to the robot's own position in
    that frame. Others are listed nearest first by their distance at frame t
    (ties by robot index), and the same order is used in all three frames.
    Layout per robot: ``[frame][other][x, y]`` flattened, dim = 3 * (n-1) * 2.
    At the start of an episode the missing earlier frames repeat frame t.

``general`` (version 1, any n, any pattern) -- our extension
    Separates "which slot" (a shared rule every robot computes alike: the
    centred optimal assignment of :func:`runtime.decision.formation.assign_slots`) from
    "how to get there" (learned). Layout per robot, dim = 6 + 5k:

    ====== ============================================================
    0:2    slot vector: own slot minus own position (m)
    2:4    slot vector / max(|slot vector|, v_max dt): the straight-line
           step, saturated to unit length (dimensionless)
    4:6    own velocity estimate (p_t - p_{t-1}) / dt (m/s)
    6:     k nearest others, nearest first (ties by index), each
           [dx, dy, dvx, dvy, mask]: relative position (m), relative
           velocity (m/s), 1 if present. Padded with zeros when fewer than k.
    ====== ============================================================

``plan`` (version 1, any n, any pattern) -- the general layout in a fixed frame
    The same rows as ``general`` but for two things. The slot (columns 0:2) is
    the robot's slot in the synchronised plan's frame (:func:`runtime.decision.rules.
    plan_targets`: the pattern placed by the ``travel_weight`` blend of the
    fewest-steps frame and the team's centroid, a frame that does not drift as
    the team moves), and columns 2:4 hold that plan's step in units of v_max:
    ``slot vector / (K v_max dt)`` with K the steps left to the team's farthest
    robot. ``v_max * columns 2:4`` is the frame rule's
    velocity at the spec's ``travel_weight`` (``rule:frame-balanced`` at 0.25;
    norm <= v_max): every robot lands on its slot at the same step, exactly,
    when it is followed. A brain acts relative to it
    (``TrainConfig.residual``), so it starts at the rule and lands exactly.

The general and plan rows are built by :class:`runtime.core.general_row.GeneralRows`
(one source, compiled at install), for a robot's own row and for a batch alike.
Velocities are estimated from consecutive frames, as a robot's own sensing
would do; nothing here needs a message beyond positions.

Memory (``frames`` > 1, general and plan only). A brain with memory reads its own last
``frames`` rows, newest first: ``[row_t, row_{t-1}, ..., row_{t-frames+1}]``. The robot
does not keep them: the brain carries them. Its ONNX graph takes the row (``obs``) and
the older rows (``memory``, ``(frames - 1) * dim`` numbers, zeros at the start) and answers
the next memory (``memory_out``: ``[row_t, ..., row_{t-frames+2}]``) beside the action; the
robot hands it back in at its next step (:class:`runtime.decision.controller.Controller`),
and starts from zeros again on a hot swap, a new team or a reset. The contract is a
recurrent state: a brain may put any state there, the robot only carries it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.core.general_row import FIXED as GENERAL_FIXED
from runtime.core.general_row import PER_NEIGHBOUR as GENERAL_PER_NEIGHBOUR
from runtime.core.general_row import GeneralRows
from runtime.errors import InputError
from runtime.types import Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

OBS_NAMES = ("paper", "general", "plan")
SLOT_ROWS = ("general", "plan")
"""The specs built from the shared slot assignment (the general layout)."""
RobotIndices = Sequence[int] | IntArray
"""Which robots' rows a builder makes: indices into the team's robot axis."""
PAPER_FRAMES = 3
MAX_MEMORY_FRAMES = 16
"""The most rows a brain with memory reads (``ObservationSpec.frames``)."""


class ObservationError(InputError):
    """An observation spec that is unknown or inconsistent."""


@dataclass(frozen=True)
class ObservationSpec:
    """Which builder a brain expects, with its parameters."""

    name: str
    version: int = 1
    n_robots: int = 0  # paper: the fixed team size; general: 0 (any)
    k_neighbours: int = 6  # general and plan
    travel_weight: float = 0.0  # plan only: 0 the frame of fewest steps, 1 the centroid's
    frames: int = 1  # general and plan: the rows the brain reads, newest first (1: no memory)

    def __post_init__(self) -> None:
        if self.name not in OBS_NAMES:
            raise ObservationError(
                f"unknown observation '{self.name}' (known: {', '.join(OBS_NAMES)})"
            )
        if self.version != 1:
            raise ObservationError(f"observation '{self.name}' version {self.version} unsupported")
        if self.name == "paper" and self.n_robots < 2:
            raise ObservationError("the paper observation needs n_robots >= 2")
        if self.name in SLOT_ROWS and self.k_neighbours < 1:
            raise ObservationError(f"the {self.name} observation needs k_neighbours >= 1")
        if not (math.isfinite(self.travel_weight) and 0.0 <= self.travel_weight <= 1.0):
            raise ObservationError(f"travel_weight must be in [0, 1], got {self.travel_weight}")
        if not 1 <= self.frames <= MAX_MEMORY_FRAMES:
            raise ObservationError(f"frames must be in 1..{MAX_MEMORY_FRAMES}, got {self.frames}")
        if self.frames > 1 and self.name not in SLOT_ROWS:
            raise ObservationError(f"the {self.name} observation has no memory (frames 1)")

    @property
    def dim(self) -> int:
        """Length of one robot's observation vector."""
        if self.name == "paper":
            return PAPER_FRAMES * (self.n_robots - 1) * 2
        return GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * self.k_neighbours

    @property
    def input_dim(self) -> int:
        """What a brain reads in all: its row and its memory (``frames * dim``)."""
        return self.frames * self.dim

    @property
    def memory_dim(self) -> int:
        """Length of the memory a brain carries in and out (0: none): its older rows."""
        return (self.frames - 1) * self.dim

    @property
    def needs_slots(self) -> bool:
        """Whether the builder needs the shared slot assignment."""
        return self.name in SLOT_ROWS

    def accepts_team(self, n: int) -> bool:
        """Whether a brain with this spec can drive a team of n robots."""
        return self.name in SLOT_ROWS or n == self.n_robots

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "version": self.version}
        if self.name == "paper":
            d["n_robots"] = self.n_robots
        else:
            d["k_neighbours"] = self.k_neighbours
        if self.name == "plan":
            d["travel_weight"] = self.travel_weight
        if self.frames > 1:
            d["frames"] = self.frames
        return d

    @staticmethod
    def from_dict(d: dict[str, Any]) -> ObservationSpec:
        try:
            return ObservationSpec(
                name=str(d["name"]),
                version=int(d.get("version", 1)),
                n_robots=int(d.get("n_robots", 0)),
                k_neighbours=int(d.get("k_neighbours", 6)),
                travel_weight=float(d.get("travel_weight", 0.0)),
                frames=int(d.get("frames", 1)),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise ObservationError(f"bad observation spec {d!r}: {e}") from None


# ------------------------------------------------------------------------ paper


def paper_observation(frames: Array, robots: RobotIndices | None = None) -> Array:
    """The paper's observation for every robot, or for the selected ``robots`` only.

    ``frames``: (..., 3, n, 2) positions at t, t-1, t-2 (metres). ``robots``:
    (r,) indices of the rows to build (default all n), e.g. a robot's own.
    Returns (..., r, 3 * (n-1) * 2).
    """
    f = np.asarray(frames, dtype=np.float64)
    n = f.shape[-2]
    sel = np.arange(n) if robots is None else np.asarray(robots, dtype=np.int64).reshape(-1)
    r = len(sel)
    rel = f[..., :, None, :, :] - f[..., :, sel, None, :]  # (..., 3, r, j, 2): p_j - p_i
    dist = np.einsum("...ijk,...ijk->...ij", rel[..., 0, :, :, :], rel[..., 0, :, :, :])
    dist[..., np.arange(r), sel] = np.inf
    order = np.argsort(dist, axis=-1, kind="stable")[..., : n - 1]  # (..., r, n-1)
    idx = np.broadcast_to(order[..., None, :, :, None], (*rel.shape[:-2], n - 1, 2))
    picked = np.take_along_axis(rel, idx, axis=-2)  # (..., 3, r, n-1, 2)
    picked = np.moveaxis(picked, -4, -3)  # (..., r, 3, n-1, 2)
    out: Array = picked.reshape(*picked.shape[:-3], PAPER_FRAMES * (n - 1) * 2)
    return out


# ---------------------------------------------------------------------- general


def general_observation(
    pos: Array,
    prev_pos: Array,
    slot_pos: Array,
    k: int = 6,
    world: WorldConfig = DEFAULT_WORLD,
    robots: RobotIndices | None = None,
    steps_left: Array | float | None = None,
    dtype: type[np.floating[Any]] = np.float64,
) -> NDArray[Any]:
    """The general observation for every robot, or for the selected ``robots`` only.

    ``pos``, ``prev_pos``: (..., n, 2) positions now and one step earlier (m).
    ``robots``: (r,) indices of the rows to build (default all n). ``slot_pos``:
    (..., r, 2) the selected robots' slots in world coordinates (m; from
    :func:`runtime.decision.formation.slot_positions` of the shared assignment, or the plan's
    :func:`runtime.decision.rules.plan_targets`). ``steps_left``: the plan spec's K per team
    (...), None for the general spec. Returns (..., r, 6 + 5k) of ``dtype``, built by
    :class:`runtime.core.general_row.GeneralRows`, the rows every robot builds.
    """
    p = np.asarray(pos, dtype=np.float64)
    n = p.shape[-2]
    lead = p.shape[:-2]
    P = np.ascontiguousarray(p.reshape(-1, n, 2))
    E = P.shape[0]
    V = (P - np.asarray(prev_pos, dtype=np.float64).reshape(E, n, 2)) / world.dt_s
    s = np.asarray(slot_pos, dtype=np.float64)
    if robots is None:
        S = np.ascontiguousarray(np.broadcast_to(s.reshape(E, n, 2), (E, n, 2)))
    else:  # a few rows: their slots in place, the others unused
        sel = np.asarray(robots, dtype=np.int64).reshape(-1)
        S = np.zeros((E, n, 2))
        S[:, sel] = s.reshape(E, len(sel), 2)
    reach = world.v_max_mps * world.dt_s
    if steps_left is None:
        pace = np.zeros(E)
    else:
        pace = np.ascontiguousarray(
            np.broadcast_to(np.asarray(steps_left, dtype=np.float64) * reach, lead).reshape(E))
    builder = GeneralRows(k, reach)
    out = np.empty((E, n, builder.dim), dtype=dtype)
    builder.teams(P, V, S, pace, out)
    full = out.reshape(*lead, n, builder.dim)
    return full if robots is None else full[..., sel, :]


# ------------------------------------------------------------------ either spec


def observe(
    spec: ObservationSpec,
    frames: Array | Sequence[Array],
    slot_pos: Array | None,
    robots: RobotIndices | None = None,
    world: WorldConfig = DEFAULT_WORLD,
    steps_left: Array | float | None = None,
) -> Array:
    """The observation ``spec`` names, for every robot or the selected ``robots``.

    The batch entry point of ``eval``, the training world and the brain probes.
    ``frames``: (..., 3, n, 2) positions at t, t-1, t-2 (or, for one team,
    a sequence of the three (n, 2) arrays). ``slot_pos``: (..., r, 2)
    the selected robots' slots in world coordinates (the general and plan specs;
    None for the paper's; the plan's: :func:`runtime.decision.rules.plan_targets`).
    ``steps_left``: the plan spec's K per team (...), from the same function.
    Returns (..., r, spec.dim) float64.
    """
    if spec.name == "paper":
        return paper_observation(np.asarray(frames), robots)
    if slot_pos is None:
        raise ObservationError(f"the {spec.name} observation needs the robots' slots")
    if isinstance(frames, np.ndarray) and frames.ndim > 3:
        now, before = frames[..., 0, :, :], frames[..., 1, :, :]
    else:  # one team: (3, n, 2), or the robot's three frames as a sequence
        now, before = frames[0], frames[1]
    if spec.name == "plan" and steps_left is None:
        raise ObservationError("the plan observation needs the plan's steps left")
    pace = steps_left if spec.name == "plan" else None
    out: Array = general_observation(now, before, slot_pos, spec.k_neighbours, world, robots,
                                     pace)
    return out


def neighbours_from_general(
    obs: Array, k: int
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Unpack the neighbour block: (rel_pos (...,k,2), rel_vel (...,k,2), mask (...,k))."""
    nb = np.asarray(obs)[..., GENERAL_FIXED : GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * k]
    nb = nb.reshape(*nb.shape[:-1], k, GENERAL_PER_NEIGHBOUR)
    return nb[..., 0:2], nb[..., 2:4], nb[..., 4] > 0.5
