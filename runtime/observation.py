"""Observation builders: the one copy that the trainer and every robot call.

Two specs, each a pure numpy function over a batch (leading axes free):

``paper`` (version 1, fixed n) -- the paper's observation
    The other robots' positions relative to the robot, in three consecutive
    frames (t, t-1, t-2), each frame relative to the robot's own position in
    that frame. Others are listed nearest first by their distance at frame t
    (ties by robot index), and the same order is used in all three frames.
    Layout per robot: ``[frame][other][x, y]`` flattened, dim = 3 * (n-1) * 2.
    At the start of an episode the missing earlier frames repeat frame t.

``general`` (version 1, any n, any pattern) -- our extension
    Separates "which slot" (a shared rule every robot computes alike: the
    centred optimal assignment of :func:`runtime.formation.assign_slots`) from
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

Velocities are estimated from consecutive frames, as a robot's own sensing
would do; nothing here needs a message beyond positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.errors import InputError
from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

OBS_NAMES = ("paper", "general")
PAPER_FRAMES = 3
GENERAL_FIXED = 6
GENERAL_PER_NEIGHBOUR = 5


class ObservationError(InputError):
    """An observation spec that is unknown or inconsistent."""


@dataclass(frozen=True)
class ObservationSpec:
    """Which builder a brain expects, with its parameters."""

    name: str
    version: int = 1
    n_robots: int = 0  # paper: the fixed team size; general: 0 (any)
    k_neighbours: int = 6  # general only

    def __post_init__(self) -> None:
        if self.name not in OBS_NAMES:
            raise ObservationError(f"unknown observation '{self.name}' (known: paper, general)")
        if self.version != 1:
            raise ObservationError(f"observation '{self.name}' version {self.version} unsupported")
        if self.name == "paper" and self.n_robots < 2:
            raise ObservationError("the paper observation needs n_robots >= 2")
        if self.name == "general" and self.k_neighbours < 1:
            raise ObservationError("the general observation needs k_neighbours >= 1")

    @property
    def dim(self) -> int:
        """Length of one robot's observation vector."""
        if self.name == "paper":
            return PAPER_FRAMES * (self.n_robots - 1) * 2
        return GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * self.k_neighbours

    @property
    def needs_slots(self) -> bool:
        """Whether the builder needs the shared slot assignment."""
        return self.name == "general"

    def accepts_team(self, n: int) -> bool:
        """Whether a brain with this spec can drive a team of n robots."""
        return self.name == "general" or n == self.n_robots

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "version": self.version}
        if self.name == "paper":
            d["n_robots"] = self.n_robots
        else:
            d["k_neighbours"] = self.k_neighbours
        return d

    @staticmethod
    def from_dict(d: dict[str, Any]) -> ObservationSpec:
        try:
            return ObservationSpec(
                name=str(d["name"]),
                version=int(d.get("version", 1)),
                n_robots=int(d.get("n_robots", 0)),
                k_neighbours=int(d.get("k_neighbours", 6)),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise ObservationError(f"bad observation spec {d!r}: {e}") from None


# ------------------------------------------------------------------------ paper


def paper_observation(frames: Array) -> Array:
    """The paper's observation for every robot.

    ``frames``: (..., 3, n, 2) positions at t, t-1, t-2 (metres).
    Returns (..., n, 3 * (n-1) * 2).
    """
    f = np.asarray(frames, dtype=np.float64)
    n = f.shape[-2]
    rel = f[..., :, None, :, :] - f[..., :, :, None, :]  # (..., 3, i, j, 2): p_j - p_i
    dist = np.einsum("...ijk,...ijk->...ij", rel[..., 0, :, :, :], rel[..., 0, :, :, :])
    dist[..., np.arange(n), np.arange(n)] = np.inf
    order = np.argsort(dist, axis=-1, kind="stable")[..., : n - 1]  # (..., i, n-1)
    idx = np.broadcast_to(order[..., None, :, :, None], (*rel.shape[:-2], n - 1, 2))
    picked = np.take_along_axis(rel, idx, axis=-2)  # (..., 3, i, n-1, 2)
    picked = np.moveaxis(picked, -4, -3)  # (..., i, 3, n-1, 2)
    out: Array = picked.reshape(*picked.shape[:-3], PAPER_FRAMES * (n - 1) * 2)
    return out


# ---------------------------------------------------------------------- general


def _slot_features(slot_vec: Array, world: WorldConfig) -> Array:
    reach = world.v_max_mps * world.dt_s
    norm = np.linalg.norm(slot_vec, axis=-1, keepdims=True)
    return np.asarray(slot_vec / np.maximum(norm, reach), dtype=np.float64)


def general_observation(
    pos: Array,
    prev_pos: Array,
    slot_pos: Array,
    k: int = 6,
    world: WorldConfig = DEFAULT_WORLD,
) -> Array:
    """The general observation for every robot.

    ``pos``, ``prev_pos``: (..., n, 2) positions now and one step earlier.
    ``slot_pos``: (..., n, 2) each robot's slot in world coordinates (from
    :func:`runtime.formation.slot_positions` of the shared assignment).
    Returns (..., n, 6 + 5k).
    """
    p = np.asarray(pos, dtype=np.float64)
    vel = (p - np.asarray(prev_pos, dtype=np.float64)) / world.dt_s
    n = p.shape[-2]
    slot_vec = np.asarray(slot_pos, dtype=np.float64) - p
    out = np.zeros((*p.shape[:-1], GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * k))
    out[..., 0:2] = slot_vec
    out[..., 2:4] = _slot_features(slot_vec, world)
    out[..., 4:6] = vel
    m = min(k, n - 1)
    if m > 0:
        lead = p.shape[:-2]
        pf = p.reshape(-1, n, 2)
        vf = vel.reshape(-1, n, 2)
        b = pf.shape[0]
        dx = pf[:, None, :, 0] - pf[:, :, None, 0]  # (b, i, j): x_j - x_i
        dy = pf[:, None, :, 1] - pf[:, :, None, 1]
        dist = dx * dx + dy * dy
        dist[:, np.arange(n), np.arange(n)] = np.inf
        # nearest first; a stable sort breaks ties by robot index
        order = np.argsort(dist, axis=-1, kind="stable")[:, :, :m]  # (b, i, m)
        rows = np.arange(b)[:, None, None]
        nb = np.empty((b, n, m, GENERAL_PER_NEIGHBOUR))
        nb[..., 0:2] = pf[rows, order] - pf[:, :, None, :]
        nb[..., 2:4] = vf[rows, order] - vf[:, :, None, :]
        nb[..., 4] = 1.0
        out[..., GENERAL_FIXED : GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * m] = nb.reshape(
            *lead, n, GENERAL_PER_NEIGHBOUR * m
        )
    return out


def general_observation_one(
    i: int,
    pos: Array,
    prev_pos: Array,
    slot_pos_i: Array,
    k: int = 6,
    world: WorldConfig = DEFAULT_WORLD,
) -> Array:
    """Robot ``i``'s general observation alone, (6 + 5k,): the robot's fast path.

    Same numbers as ``general_observation(...)[i]``; costs O(n) instead of O(n^2).
    """
    p = np.asarray(pos, dtype=np.float64)
    vel = (p - np.asarray(prev_pos, dtype=np.float64)) / world.dt_s
    n = p.shape[0]
    out = np.zeros(GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * k)
    sv = np.asarray(slot_pos_i, dtype=np.float64) - p[i]
    out[0:2] = sv
    out[2:4] = _slot_features(sv, world)
    out[4:6] = vel[i]
    m = min(k, n - 1)
    if m > 0:
        rel = p - p[i]
        dist = np.einsum("jk,jk->j", rel, rel)
        dist[i] = np.inf
        order = np.lexsort((np.arange(n), dist))[:m]
        nb = np.empty((m, GENERAL_PER_NEIGHBOUR))
        nb[:, 0:2] = rel[order]
        nb[:, 2:4] = vel[order] - vel[i]
        nb[:, 4] = 1.0
        out[GENERAL_FIXED : GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * m] = nb.reshape(-1)
    return out


def neighbours_from_general(
    obs: Array, k: int
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Unpack the neighbour block: (rel_pos (...,k,2), rel_vel (...,k,2), mask (...,k))."""
    nb = np.asarray(obs)[..., GENERAL_FIXED : GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * k]
    nb = nb.reshape(*nb.shape[:-1], k, GENERAL_PER_NEIGHBOUR)
    return nb[..., 0:2], nb[..., 2:4], nb[..., 4] > 0.5
