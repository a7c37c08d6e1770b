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

``plan`` (version 1, any n, any pattern) -- the general layout in a fixed frame
    The same rows as ``general`` but for two things. The slot (columns 0:2) is
    the robot's slot in the synchronised plan's frame (:func:`runtime.rules.
    plan_targets`: the pattern placed by the ``travel_weight`` blend of the
    fewest-steps frame and the team's centroid, a frame that does not drift as
    the team moves), and columns 2:4 hold that plan's step in units of v_max:
    ``slot vector / (K v_max dt)`` with K the steps left to the team's farthest
    robot (:func:`plan_pace`). ``v_max * columns 2:4`` is the frame rule's
    velocity at the spec's ``travel_weight`` (``rule:frame-balanced`` at 0.25;
    norm <= v_max): every robot lands on its slot at the same step, exactly,
    when it is followed. A brain acts relative to it
    (``TrainConfig.residual``), so it starts at the rule and lands exactly.

Velocities are estimated from consecutive frames, as a robot's own sensing
would do; nothing here needs a message beyond positions.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from runtime.errors import InputError
from runtime.types import Array, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

OBS_NAMES = ("paper", "general", "plan")
SLOT_ROWS = ("general", "plan")
"""The specs built from the shared slot assignment (the general layout)."""
Rows = Sequence[int] | IntArray
"""Which robots' rows a builder makes: indices into the team's robot axis."""
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
    k_neighbours: int = 6  # general and plan
    travel_weight: float = 0.0  # plan only: 0 the frame of fewest steps, 1 the centroid's

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

    @property
    def dim(self) -> int:
        """Length of one robot's observation vector."""
        if self.name == "paper":
            return PAPER_FRAMES * (self.n_robots - 1) * 2
        return GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * self.k_neighbours

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
            )
        except (KeyError, TypeError, ValueError) as e:
            raise ObservationError(f"bad observation spec {d!r}: {e}") from None


# ------------------------------------------------------------------------ paper


def paper_observation(frames: Array, robots: Rows | None = None) -> Array:
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


@functools.lru_cache(maxsize=8)
def _gather_base(n: int, m: int, E: int) -> tuple[IntArray, IntArray]:
    """Flat-index offsets for gathering (i, order, e) from (N, N, E) and (order, e) from (N, E)."""
    i = np.arange(n)[:, None, None]
    e = np.arange(E)[None, None, :]
    pair = np.broadcast_to(i * (n * E) + e, (n, m, E)).copy()
    own = np.broadcast_to(e, (n, m, E)).copy()
    pair.flags.writeable = False
    own.flags.writeable = False
    return pair, own


def general_observation_env_last(
    X: Array,
    X_prev: Array,
    G: Array,
    k: int = 6,
    world: WorldConfig = DEFAULT_WORLD,
    dtype: type[np.floating[Any]] = np.float32,
) -> NDArray[Any]:
    """Every robot's general observation, (E, N, 6 + 5k) of ``dtype``: the batch kernel.

    Works on robot-major arrays (component, robot, env), as the training world
    keeps them: with the env axis innermost every numpy call runs over long
    rows, where the (E, N, 2) layout spends its time on length-2 and length-N
    inner loops (about 4x faster at E = 64, N = 10).

    ``X``, ``X_prev``: positions now and one step earlier, (2, N, E) m;
    ``G``: each robot's slot in world coordinates, (2, N, E) m. Equal to
    ``general_observation(P, P_prev, S, k, world).astype(float32)`` for the
    same values in the (E, N, 2) layout.
    """
    _, n, E = X.shape
    V = X - X_prev
    V /= world.dt_s
    S = G - X  # slot vector
    out = np.zeros((GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * k, n, E))
    out[0:2] = S
    norm = np.sqrt(S[0] * S[0] + S[1] * S[1])
    np.maximum(norm, world.v_max_mps * world.dt_s, out=norm)
    np.divide(S, norm, out=out[2:4])
    out[4:6] = V
    m = min(k, n - 1)
    if m > 0:
        dx = X[0][None, :, :] - X[0][:, None, :]  # (i, j, E): x_j - x_i
        dy = X[1][None, :, :] - X[1][:, None, :]
        dist = dx * dx + dy * dy
        dist[np.arange(n), np.arange(n)] = np.inf
        # nearest first; a stable sort breaks ties by robot index
        order = np.argsort(dist, axis=1, kind="stable")[:, :m, :]  # (i, m, E)
        pair, own = _gather_base(n, m, E)
        j = order * E
        nb = out[GENERAL_FIXED : GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * m].reshape(
            m, GENERAL_PER_NEIGHBOUR, n, E
        )
        at = (j + pair).transpose(1, 0, 2)  # (m, i, E) into (N, N, E)
        nb[:, 0] = np.take(dx, at)
        nb[:, 1] = np.take(dy, at)
        vj = (j + own).transpose(1, 0, 2)  # (m, i, E) into (N, E)
        np.subtract(np.take(V[0], vj), V[0][None], out=nb[:, 2])
        np.subtract(np.take(V[1], vj), V[1][None], out=nb[:, 3])
        nb[:, 4] = 1.0
    return out.transpose(2, 1, 0).astype(dtype, copy=dtype is not np.float64)


def general_observation(
    pos: Array,
    prev_pos: Array,
    slot_pos: Array,
    k: int = 6,
    world: WorldConfig = DEFAULT_WORLD,
    robots: Rows | None = None,
) -> Array:
    """The general observation for every robot, or for the selected ``robots`` only.

    ``pos``, ``prev_pos``: (..., n, 2) positions now and one step earlier.
    ``robots``: (r,) indices of the rows to build (default all n); selecting
    a robot's own row costs O(n) instead of O(n^2). ``slot_pos``: (..., r, 2)
    the selected robots' slots in world coordinates (from
    :func:`runtime.formation.slot_positions` of the shared assignment).
    Returns (..., r, 6 + 5k).
    """
    p = np.asarray(pos, dtype=np.float64)
    q = np.asarray(prev_pos, dtype=np.float64)
    s = np.asarray(slot_pos, dtype=np.float64)
    if robots is not None and p.ndim == 2 and len(robots) == 1:
        L = p.tolist()
        V = frame_velocities(L, q.tolist(), world.dt_s)
        sx, sy = s.reshape(2).tolist()
        return np.array([general_row(int(robots[0]), L, V, (sx, sy), k, world)])
    n = p.shape[-2]
    lead = p.shape[:-2]
    if robots is None:
        slots = s
    else:  # a few rows of a batch: build them all, keep the selected ones
        sel = np.asarray(robots, dtype=np.int64).reshape(-1)
        slots = np.zeros_like(p)
        slots[..., sel, :] = s

    def env_last(a: Array) -> Array:  # (..., n, 2) -> (2, n, E)
        return np.ascontiguousarray(a.reshape(-1, n, 2).transpose(2, 1, 0))

    full = general_observation_env_last(
        env_last(p), env_last(q), env_last(slots), k, world, np.float64
    ).reshape(*lead, n, -1)
    out: Array = full if robots is None else full[..., sel, :]
    return out


NUMPY_NEIGHBOURS_FROM = 24
"""Team size from which :func:`general_row` sorts distances with numpy (below it, a
dozen numpy calls cost more than the Python loop)."""


def frame_velocities(L: list[list[float]], Lp: list[list[float]], dt: float) -> list[list[float]]:
    """Every robot's velocity estimated from two frames, (p_t - p_{t-1}) / dt, plain floats.

    ``L``, ``Lp``: positions at t and t-1, [[x, y], ...] (m). The same IEEE
    operations as the batch builder's ``(p - prev) / dt``.
    """
    return [[(a[0] - b[0]) / dt, (a[1] - b[1]) / dt] for a, b in zip(L, Lp, strict=True)]


def neighbour_order(
    i: int, L: list[list[float]], P: Array | None = None
) -> tuple[list[int], list[float]]:
    """Robot i's team nearest first, and every robot's squared distance to it.

    ``L``: positions at t in robot-id order, [[x, y], ...] (m). Returns (robot
    ids sorted by squared distance, ties by id, with i itself last; ``d2`` with
    ``d2[j] = |p_j - p_i|^2`` (m^2) and ``d2[i] = inf``), plain Python values.
    ``P``: the same positions as an (n, 2) array, if the caller has it: above
    :data:`NUMPY_NEIGHBOURS_FROM` robots the distances are then found with numpy
    (the same subtractions, squares and sums, a stable sort: the same order).
    """
    n = len(L)
    px, py = L[i]
    if P is not None and n >= NUMPY_NEIGHBOURS_FROM:
        rx = P[:, 0] - px
        ry = P[:, 1] - py
        rx *= rx
        ry *= ry
        rx += ry
        rx[i] = math.inf
        order: list[int] = np.argsort(rx, kind="stable").tolist()
        d2: list[float] = rx.tolist()
        return order, d2
    d2 = []
    for q in L:
        x = q[0] - px
        y = q[1] - py
        d2.append(x * x + y * y)
    d2[i] = math.inf
    # nearest first, ties by index: a stable sort of the ids by distance
    return sorted(range(n), key=d2.__getitem__), d2


def general_row(
    i: int,
    L: list[list[float]],
    V: list[list[float]],
    slot: tuple[float, float],
    k: int,
    world: WorldConfig = DEFAULT_WORLD,
    P: Array | None = None,
    order: list[int] | None = None,
) -> list[float]:
    """Robot i's general observation, 6 + 5k plain floats: the one-robot kernel.

    ``L``: positions at t, ``V``: :func:`frame_velocities`, both in robot-id
    order (``V`` needs only the rows of i and of its k nearest: any sequence
    indexable by robot id); ``slot``: robot i's slot in world coordinates (m).
    What :func:`general_observation` builds for a single robot of a single team,
    and what the robot calls with the lists it keeps anyway: at n ~ 10 a dozen
    numpy calls cost more than the arithmetic. The same IEEE operations, in the
    same order, as the batch code (tests hold every row of the two equal).
    ``P``: the same positions as an (n, 2) array, for :func:`neighbour_order`;
    ``order``: that order, if the caller has it already (the robot's safety
    filter reads the same one).
    """
    n = len(L)
    px, py = L[i]
    svx, svy = slot[0] - px, slot[1] - py
    reach = world.v_max_mps * world.dt_s
    norm = math.sqrt(svx * svx + svy * svy)
    d = norm if norm > reach else reach
    vix, viy = V[i]
    out = [svx, svy, svx / d, svy / d, vix, viy]
    m = min(k, n - 1)
    if m > 0:
        if order is None:
            order = neighbour_order(i, L, P)[0]
        for j in order[:m]:
            q = L[j]
            v = V[j]
            out += (q[0] - px, q[1] - py, v[0] - vix, v[1] - viy, 1.0)
    if m < k:
        out += [0.0] * (GENERAL_PER_NEIGHBOUR * (k - m))
    return out


# ------------------------------------------------------------------ either spec


def observe(
    spec: ObservationSpec,
    frames: Array | Sequence[Array],
    slot_pos: Array | None,
    robots: Rows | None = None,
    world: WorldConfig = DEFAULT_WORLD,
    steps_left: Array | float | None = None,
) -> Array:
    """The observation ``spec`` names, for every robot or the selected ``robots``.

    The one entry point the robot, ``eval`` and the training world share.
    ``frames``: (..., 3, n, 2) positions at t, t-1, t-2 (or, for one team,
    a sequence of the three (n, 2) arrays). ``slot_pos``: (..., r, 2)
    the selected robots' slots in world coordinates (the general and plan specs;
    None for the paper's; the plan's: :func:`runtime.rules.plan_targets`).
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
    out = general_observation(now, before, slot_pos, spec.k_neighbours, world, robots)
    if spec.name == "plan":
        if steps_left is None:
            raise ObservationError("the plan observation needs the plan's steps left")
        plan_pace(out, steps_left, world)
    return out


def plan_pace(obs: NDArray[Any], steps_left: Array | float, world: WorldConfig = DEFAULT_WORLD
              ) -> NDArray[Any]:
    """Turn general rows built on the plan's slots into plan rows, in place.

    ``obs`` (..., r, 6 + 5k) whose columns 0:2 are the slot vectors in the plan's
    frame; ``steps_left`` (...) or a number: K per team. Columns 2:4 become
    ``slot vector / (K v_max dt)``. Returns ``obs``.
    """
    den = np.asarray(steps_left, dtype=np.float64) * (world.v_max_mps * world.dt_s)
    obs[..., 2:4] = obs[..., 0:2] / np.asarray(den)[..., None, None]
    return obs


def neighbours_from_general(
    obs: Array, k: int
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Unpack the neighbour block: (rel_pos (...,k,2), rel_vel (...,k,2), mask (...,k))."""
    nb = np.asarray(obs)[..., GENERAL_FIXED : GENERAL_FIXED + GENERAL_PER_NEIGHBOUR * k]
    nb = nb.reshape(*nb.shape[:-1], k, GENERAL_PER_NEIGHBOUR)
    return nb[..., 0:2], nb[..., 2:4], nb[..., 4] > 0.5
