"""One robot's decision, and the same decision for a whole batch of teams.

A decision is: shared slot assignment (with hysteresis) -> observation (the
builder the brain's spec names) -> brain -> clamp to v_max -> ORCA safety
filter -> clamp. Two entry points compute it:

:class:`Controller`
    The robot's path: one robot, one team, called once per step with the
    current poses of the live robots ordered by robot id. It keeps the last
    three frames (the paper observation and velocity estimates need them) and
    the previous assignment (hysteresis). Tuned for latency: few numpy calls,
    plain floats where arrays are tiny, the centred pattern cached.

:func:`decide_batch`
    The evaluation path (the trainer's ``eval``, the world): E teams at once,
    observations from the same builders, one ``brain.act`` on (E*n, dim), then
    the safety filter per robot (``orca_filter_batch``).

Both paths get a robot's neighbours for the safety filter from the same
helper, :func:`neighbour_rows` (over :func:`frame_velocities`): every other
robot's position relative to the robot, and every robot's velocity estimated
from two consecutive frames as (p_t - p_{t-1}) / dt. ORCA itself keeps the
``OrcaParams.max_neighbours`` nearest within ``neighbour_dist_m`` (ties broken
deterministically), so both paths filter identically. Tests check that they
agree number for number.

Frames. ``frames[0]`` is the newest (t), ``frames[1]`` is t-1 and
``frames[2]`` is t-2; at the start (or after the team size changes) the
missing earlier frames repeat frame t, so the first velocity estimate is zero.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.brain import Brain
from runtime.observation import (
    GENERAL_PER_NEIGHBOUR,
    general_observation,
    paper_observation,
)
from runtime.safety import OrcaParams, orca_filter, orca_filter_batch
from runtime.types import Array, BoolArray, IntArray
from runtime.world_config import DEFAULT_WORLD, WorldConfig

__all__ = [
    "Controller",
    "Decision",
    "clamp_speed",
    "decide_batch",
    "frame_velocities",
    "neighbour_rows",
]


#: The hysteresis margin of runtime.formation.assign_slots, repeated here so that a
#: robot process never imports scipy.optimize (half a second and tens of MB at
#: start); tests/unit/test_controller.py checks the two stay equal.
HYSTERESIS_REL = 1e-3
HYSTERESIS_ABS_M2 = 1e-6


def _load_lsap() -> Callable[..., Any]:
    """scipy's ``linear_sum_assignment`` without importing all of scipy.optimize.

    The solver is one C extension, ``scipy/optimize/_lsap``; loading it by file
    skips the package's ``__init__`` (linprog, linalg, sparse, ...). Falls back
    on the ordinary import if the file is not where it is expected.
    """
    try:
        import scipy

        base = Path(scipy.__path__[0]) / "optimize"
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = base / f"_lsap{suffix}"
            if path.is_file():
                spec = importlib.util.spec_from_file_location("scipy.optimize._lsap", path)
                if spec is None or spec.loader is None:
                    break
                mod = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(mod)
                fn: Callable[..., Any] = mod.linear_sum_assignment
                return fn
    except (ImportError, OSError, AttributeError):
        pass
    from scipy.optimize import linear_sum_assignment as lsa

    fallback: Callable[..., Any] = lsa
    return fallback


linear_sum_assignment = _load_lsap()

ERR_NONFINITE = "brain output non-finite: holding still"
ERR_TEAM = "brain cannot drive this team size: holding still"
ERR_BRAIN = "brain failed: holding still"


@dataclass(slots=True)
class Decision:
    """One robot's decision for one step."""

    velocity: tuple[float, float]
    """The command (m/s): after the safety filter, norm <= v_max."""
    brain_velocity: tuple[float, float]
    """What the brain asked for (m/s), before clamping and the filter."""
    safety_changed: bool
    """Whether the safety filter changed the (clamped) brain velocity."""
    safety_change_mps: float
    """By how much (norm of the difference, m/s)."""
    decision_us: float
    """Wall time of the whole decision (assignment, observation, brain, filter)."""
    error: str = ""
    """Empty when all went well; else why the robot holds still this step."""
    slot: int = -1
    """The pattern index this robot was assigned (-1 without an assignment)."""


def clamp_speed(vx: float, vy: float, v_max: float) -> tuple[float, float]:
    """(vx, vy) scaled down to norm <= v_max (exactly, both ways of taking the norm)."""
    sp = math.hypot(vx, vy)
    if sp > v_max:
        s = v_max / sp
        vx, vy = vx * s, vy * s
        while max(math.hypot(vx, vy), math.sqrt(vx * vx + vy * vy)) > v_max:
            vx, vy = vx * (1.0 - 1e-15), vy * (1.0 - 1e-15)
    return vx, vy


def frame_velocities(L: list[list[float]], Lp: list[list[float]], dt: float) -> list[list[float]]:
    """Every robot's velocity estimated from two frames: (p_t - p_{t-1}) / dt, plain floats.

    The same IEEE operations as the observation builders' numpy ``(p - prev) / dt``.
    """
    return [[(a[0] - b[0]) / dt, (a[1] - b[1]) / dt] for a, b in zip(L, Lp, strict=True)]


def neighbour_rows(
    i: int, L: list[list[float]], V: list[list[float]]
) -> tuple[list[float], list[list[float]], list[list[float]]]:
    """Robot i's view of its neighbours for the safety filter (the one helper both paths use).

    ``L``: positions at t, ``V``: :func:`frame_velocities`, both in robot-id
    order. Returns (own velocity, every other robot's position relative to
    robot i, those robots' absolute velocities), others in id order with i left
    out. ORCA itself keeps the ``max_neighbours`` nearest within
    ``neighbour_dist_m``, with deterministic ties.
    """
    px, py = L[i]
    rel = [[q[0] - px, q[1] - py] for q in L]
    del rel[i]
    return V[i], rel, V[:i] + V[i + 1 :]


class Controller:
    """One robot's decision maker: brain + assignment + observation + safety filter.

    Not thread-safe: call :meth:`decide`, :meth:`set_brain` and :meth:`reset`
    from one thread (the control loop); swapping a brain between two decisions
    is then atomic by construction.
    """

    def __init__(
        self,
        brain: Brain,
        world: WorldConfig = DEFAULT_WORLD,
        safety: OrcaParams | None = OrcaParams(),  # noqa: B008 - frozen, immutable default
    ) -> None:
        self.world = world
        self.safety = safety
        self._brain = brain
        self._v_max = world.v_max_mps
        self._dt = world.dt_s
        self._reach = world.v_max_mps * world.dt_s
        self._pattern_obj: object = None
        self._cc: Array = np.zeros((0, 2))
        self._cc_list: list[list[float]] = []
        self._cc3: Array = np.zeros((1, 0, 2))
        self.reset()

    # ---------------------------------------------------------------- state

    @property
    def brain(self) -> Brain:
        return self._brain

    def set_brain(self, brain: Brain) -> None:
        """Use ``brain`` from the next decision on (frames and slots are kept)."""
        self._brain = brain

    def reset(self) -> None:
        """Forget the history: frames, previous assignment, cached index tables."""
        self._n = -1
        self._frames: list[Array] = []
        self._last_step: int | None = None
        self._lists: list[list[list[float]]] = []
        self._prev_slots: IntArray | None = None
        self._prev_list: list[int] | None = None

    @property
    def previous_slots(self) -> IntArray | None:
        return self._prev_slots

    def _set_pattern(self, pattern: Array) -> None:
        c = np.asarray(pattern, dtype=np.float64)
        if c.ndim != 2 or c.shape[-1] != 2:
            raise ValueError(f"pattern must have shape (n, 2), got {c.shape}")
        self._cc = c - c.mean(axis=0, keepdims=True)
        self._cc_list = self._cc.tolist()
        self._cc3 = self._cc[None, :, :]
        self._pattern_obj = pattern
        self._prev_slots = None
        self._prev_list = None

    def _push(self, pos: Array, step: int | None) -> None:
        n = pos.shape[0]
        lst: list[list[float]] = pos.tolist()
        if n != self._n:
            self._n = n
            self._frames = [pos, pos, pos]
            self._lists = [lst, lst]
            self._prev_slots = None
            self._prev_list = None
        elif step is not None and step == self._last_step:
            self._frames[0] = pos  # the same step again (realtime): refresh, do not shift
            self._lists[0] = lst
        else:
            f = self._frames
            self._frames = [pos, f[0], f[1]]
            self._lists = [lst, self._lists[0]]
        self._last_step = step

    # ----------------------------------------------------------- assignment

    def _assign(self, p: Array) -> tuple[IntArray, Array]:
        """Shared assignment with hysteresis; returns (slots, team centroid).

        The very arithmetic of ``formation.assign_slots`` (centred squared
        distances, the same hysteresis test), so the robot and the batch path
        agree even on ties; only the pattern's centring is cached.
        """
        n = p.shape[0]
        cen = np.add.reduce(p, 0) / n  # == p.mean(0), without mean's Python overhead
        d = np.subtract((p - cen)[:, None, :], self._cc3)
        d *= d
        cost = d[..., 0] + d[..., 1]  # == formation's einsum: two squares, one addition
        _, cols = linear_sum_assignment(cost)
        prev = self._prev_slots
        if prev is not None and self._prev_list != cols.tolist():
            rows = np.arange(n)
            new, old = cost[rows, cols].sum(), cost[rows, prev].sum()
            if not new < old - (HYSTERESIS_REL * old + HYSTERESIS_ABS_M2):
                cols = prev
        slots: IntArray = cols
        self._prev_slots = slots
        self._prev_list = slots.tolist()
        return slots, cen

    # -------------------------------------------------------------- decide

    def decide(
        self,
        robot_index: int,
        positions: Array,
        pattern: Array,
        step: int | None = None,
    ) -> Decision:
        """Decide robot ``robot_index``'s velocity for this step.

        ``positions``: (n, 2) current poses of the live robots, ordered by robot
        id; ``robot_index`` is this robot's row. ``pattern``: (n, 2) target
        pattern (pass the same array object while it does not change: its
        centred copy is cached). ``step``: the world step these poses belong
        to; a repeated step refreshes the newest frame instead of shifting the
        history (realtime mode deciding faster than the world steps).
        A non-finite brain output, a brain that cannot drive n robots or a
        brain that raises makes the robot hold still, with ``error`` set.
        """
        t0 = time.perf_counter_ns()
        pos = np.asarray(positions, dtype=np.float64)
        if pattern is not self._pattern_obj:
            same = (
                isinstance(self._pattern_obj, np.ndarray)
                and self._pattern_obj.shape == np.shape(pattern)
                and np.array_equal(self._pattern_obj, pattern)
            )
            if same:
                self._pattern_obj = pattern
            else:
                self._set_pattern(pattern)
        self._push(pos, step)
        n = pos.shape[0]
        i = robot_index
        brain = self._brain
        spec = brain.spec
        slot = -1
        error = ""
        obs: Array | None = None
        L, Lp = self._lists[0], self._lists[1]
        dt = self._dt
        V = frame_velocities(L, Lp, dt)
        if not spec.accepts_team(n) or self._cc.shape[0] != n:
            error = ERR_TEAM
        elif spec.name == "general":
            slots, cen = self._assign(pos)
            slot = int(slots[i])
            obs = self._general_one(i, L, V, slot, spec.k_neighbours, cen)
        else:
            slot = int(self._assign(pos)[0][i])
            obs = _paper_one(i, self._frames)
        bvx = bvy = 0.0
        if obs is not None:
            try:
                a = brain.act(obs)
                bvx, bvy = float(a[0, 0]), float(a[0, 1])
            except Exception:  # a brain must never take the loop down
                error = ERR_BRAIN
            if not error and not (math.isfinite(bvx) and math.isfinite(bvy)):
                error = ERR_NONFINITE
        if error:
            us = (time.perf_counter_ns() - t0) / 1000.0
            return Decision((0.0, 0.0), (bvx, bvy), False, 0.0, us, error, int(slot))
        vx, vy = clamp_speed(bvx, bvy, self._v_max)
        changed = False
        change = 0.0
        if self.safety is not None and n >= 2:
            own, rel, nbv = neighbour_rows(i, L, V)
            res = orca_filter((vx, vy), own, rel, nbv, world=self.world, params=self.safety)
            vx, vy = clamp_speed(res.velocity[0], res.velocity[1], self._v_max)
            changed, change = res.changed, res.change_mps
        us = (time.perf_counter_ns() - t0) / 1000.0
        return Decision((vx, vy), (bvx, bvy), changed, change, us, "", int(slot))

    def _general_one(
        self,
        i: int,
        L: list[list[float]],
        V: list[list[float]],
        slot: int,
        k: int,
        cen: Array | None = None,
    ) -> Array:
        """Robot i's general observation, (1, 6 + 5k), in plain floats.

        The same numbers as ``runtime.observation.general_observation_one``
        (tests check it), written without numpy: at n ~ 10 a dozen numpy calls
        cost more than the arithmetic.
        """
        n = len(L)
        if cen is not None:
            cx, cy = cen.tolist()
        else:
            cx = cy = 0.0
            for q in L:  # sequential sums, as numpy reduces along the robot axis
                cx += q[0]
                cy += q[1]
            cx /= n
            cy /= n
        px, py = L[i]
        ccx, ccy = self._cc_list[slot]
        svx = (ccx + cx) - px
        svy = (ccy + cy) - py
        reach = self._reach
        norm = math.sqrt(svx * svx + svy * svy)
        d = norm if norm > reach else reach
        vix, viy = V[i]
        out = [svx, svy, svx / d, svy / d, vix, viy]
        m = min(k, n - 1)
        if m > 0:
            rel = [(q[0] - px, q[1] - py) for q in L]
            d2 = [x * x + y * y for x, y in rel]
            d2[i] = math.inf
            # nearest first, ties by index: a stable sort of the ids by distance
            for j in sorted(range(n), key=d2.__getitem__)[:m]:
                v = V[j]
                out += (*rel[j], v[0] - vix, v[1] - viy, 1.0)
        if m < k:
            out += [0.0] * (GENERAL_PER_NEIGHBOUR * (k - m))
        return np.array([out])


def _paper_one(i: int, frames: list[Array]) -> Array:
    """Robot i's paper observation alone: same numbers as ``paper_observation(f)[i]``."""
    f = np.stack(frames)  # (3, n, 2)
    n = f.shape[1]
    rel = f - f[:, i : i + 1, :]
    r0 = rel[0]
    dist = np.einsum("jk,jk->j", r0, r0)
    dist[i] = np.inf
    order = np.argsort(dist, kind="stable")[: n - 1]
    out: Array = rel[:, order, :].reshape(1, -1)
    return out


def decide_batch(
    brain: Brain,
    frames: Array,
    pattern: Array,
    prev_slots: IntArray | None = None,
    safety: OrcaParams | None = OrcaParams(),  # noqa: B008 - frozen, immutable default
    world: WorldConfig = DEFAULT_WORLD,
) -> tuple[Array, IntArray, BoolArray]:
    """Every robot's decision in E teams at once: the evaluation path.

    ``frames``: (E, 3, n, 2) positions at [t, t-1, t-2]. ``pattern``: (n, 2),
    (1, n, 2) or (E, n, 2). ``prev_slots``: (E, n) assignment of the last step
    (hysteresis) or None. Returns (velocities (E, n, 2) m/s, slots (E, n),
    safety_changed (E, n)). Same numbers as :meth:`Controller.decide` robot
    by robot; a non-finite brain output holds that robot still.
    """
    from runtime.formation import assign_slots_batch, slot_positions  # scipy.optimize: eval only

    f = np.asarray(frames, dtype=np.float64)
    E, _, n, _ = f.shape
    pos, prev = f[:, 0], f[:, 1]
    c = np.asarray(pattern, dtype=np.float64)
    if c.ndim == 2:
        c = c[None]
    C = np.broadcast_to(c, pos.shape)
    spec = brain.spec
    if not spec.accepts_team(n):
        raise ValueError(f"brain spec '{spec.name}' ({spec.n_robots} robots) cannot drive {n}")
    slots = assign_slots_batch(pos, C, prev_slots)
    if spec.name == "general":
        obs = general_observation(
            pos, prev, slot_positions(pos, C, slots), spec.k_neighbours, world
        )
    else:
        obs = paper_observation(f)
    act = np.asarray(brain.act(obs.reshape(E * n, spec.dim)), dtype=np.float64).reshape(E, n, 2)
    ok: BoolArray = np.asarray(np.isfinite(act).all(axis=-1))
    act = np.where(ok[..., None], act, 0.0)
    sp = np.hypot(act[..., 0], act[..., 1])
    v_max = world.v_max_mps
    over = sp > v_max
    if over.any():
        for e, i in zip(*np.nonzero(over), strict=True):
            act[e, i] = clamp_speed(float(act[e, i, 0]), float(act[e, i, 1]), v_max)
    changed = np.zeros((E, n), dtype=bool)
    if safety is not None and n >= 2:
        own_l: list[list[float]] = []
        rel_l: list[list[list[float]]] = []
        nbv_l: list[list[list[float]]] = []
        for e in range(E):
            L = pos[e].tolist()
            V = frame_velocities(L, prev[e].tolist(), world.dt_s)
            for i in range(n):
                own_i, rel_i, nbv_i = neighbour_rows(i, L, V)
                own_l.append(own_i)
                rel_l.append(rel_i)
                nbv_l.append(nbv_i)
        safe, ch = orca_filter_batch(
            act.reshape(E * n, 2),
            np.array(own_l),
            np.array(rel_l),
            np.array(nbv_l),
            np.ones((E * n, n - 1), dtype=bool),
            world=world,
            params=safety,
        )
        safe = safe.reshape(E, n, 2)
        changed = ch.reshape(E, n)
        # robots whose brain failed hold still, whatever the filter says
        act = np.where(ok[..., None], safe, 0.0)
        changed &= ok
    vel: Array = act
    return vel, slots, changed
