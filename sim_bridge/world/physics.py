"""The pymunk world: N velocity-controlled discs of radius R inside the arena's walls.

One :class:`PhysicsWorld` per run, one ``pymunk.Space(threaded=False)`` inside it.
Robots are dynamic discs (mass 1, infinite moment: they never spin, friction and
elasticity 0) keyed by their robot id; the arena is a square of side ``arena_m``
with its lower-left corner at the origin, closed by thick static walls.

A step (``dt`` seconds) takes one velocity per robot (m/s, clamped to v_max):

1. **Speculative step.** Velocities are set once through ``pymunk.batch`` and the
   space is stepped by the whole ``dt``. Without contacts that is exact:
   ``p(t+1) = p(t) + dt * a`` (the paper's dynamics), and it costs one space step.
2. **Contact step.** If any disc ends that step overlapping another disc or a wall,
   the step is undone (positions restored) and redone in ``contact_substeps``
   sub-steps with the velocities set only once: the contact solver removes the
   approaching part of a velocity and the correction carries to the next sub-step,
   so a disc driven into another stops (or slides, or pushes it) instead of
   sinking in. Penetration stays below ``2 * v_max * dt / contact_substeps``
   (5 mm at the defaults) plus the solver's slop.

Because ``v_max * dt = R``, nothing crosses a disc or a wall within one speculative
step: any overlap it could cause shows at its end. A graze that overlaps only in
the middle of a step (at most 2R - sqrt(3)R ~ 0.27 R deep for two robots passing
at full speed) is not seen by the physics; the world's per-step metrics catch it
with the swept check of :func:`runtime.decision.formation.collision_pairs`.

**Contacts** are counted per pair (robot-robot or robot-wall) when a pair starts
touching (centres closer than 2R, or a centre closer than R to a wall) while not
already in contact; a contact lasts until the pair is ``release_gap_m`` apart.

Shapes: positions and velocities are (n, 2) float64 arrays in the order of
:attr:`PhysicsWorld.ids` (ascending robot id); metres and metres per second.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pymunk
import pymunk.batch as pb
from numpy.typing import NDArray

from runtime.types import Array
from runtime.world_config import DEFAULT_WORLD, WorldConfig

WALL_THICKNESS_M = 1.0
"""Walls are segments this thick, outside the arena: nothing tunnels through them."""


class PhysicsError(ValueError):
    """A request the world cannot honour (unknown or duplicate robot, no room to place)."""


def arena_for_patterns(patterns: list[Array], world: WorldConfig = DEFAULT_WORLD) -> float:
    """Side of a square arena that holds every pattern with room around it (metres).

    At least ``world.arena_m``; otherwise three times the largest pattern extent plus
    four diameters, so a pattern centred anywhere in the middle third still fits.
    """
    extent = max((float(np.ptp(p, axis=0).max()) for p in patterns if len(p)), default=0.0)
    return max(world.arena_m, 3.0 * extent + 8.0 * world.radius_m)


def sample_starts(
    n: int,
    arena_m: float,
    rng: np.random.Generator,
    world: WorldConfig = DEFAULT_WORLD,
    avoid: Array | None = None,
    max_draws_per_robot: int = 200,
) -> Array:
    """``n`` start positions uniform in the arena, pairwise >= ``world.start_separation_m``.

    Also keeps a radius clear of the walls and ``start_separation_m`` clear of every
    point of ``avoid`` (the robots already there, for a robot that joins later).
    Sequential rejection sampling (each candidate uniform, kept if clear of all
    kept so far), so the result is the training world's "uniform with separation".
    Raises :class:`PhysicsError` when the arena is too crowded: up front when the
    discs of diameter ``start_separation_m`` would cover more than 40 % of it (random
    sequential packing jams near 55 %), or after ``max_draws_per_robot`` draws each.
    """
    lo, hi = world.radius_m, arena_m - world.radius_m
    sep = world.start_separation_m
    kept = np.empty((0, 2)) if avoid is None else np.asarray(avoid, np.float64).reshape(-1, 2)
    n_avoid = len(kept)
    cover = (n + n_avoid) * math.pi * (sep / 2) ** 2 / max(hi - lo, 1e-9) ** 2
    if cover > 0.4:
        raise PhysicsError(
            f"cannot place {n} robots {sep} m apart in a {arena_m:g} m arena: too crowded"
        )
    pts = np.empty((n_avoid + n, 2))
    pts[:n_avoid] = kept
    count, draws, sep2 = n_avoid, 0, sep * sep
    while count < n_avoid + n:
        if draws > max_draws_per_robot * n:
            raise PhysicsError(f"cannot place {n} robots {sep} m apart in a {arena_m:g} m arena")
        for c in rng.uniform(lo, hi, size=(64, 2)):
            draws += 1
            d = pts[:count] - c
            if count and (np.einsum("ij,ij->i", d, d) < sep2).any():
                continue
            pts[count] = c
            count += 1
            if count == n_avoid + n:
                break
    return pts[n_avoid:].copy()


@dataclass
class StepResult:
    """What one physics step did."""

    positions: Array
    """(n, 2) positions after the step, in :attr:`PhysicsWorld.ids` order (m); do not modify."""
    new_contacts: list[tuple[int | str, int | str]] = field(default_factory=list)
    """Pairs that started touching this step: (id, id) or (id, "wall"), ids ascending."""
    substepped: bool = False
    """Whether the step was redone in sub-steps because of a contact."""


class PhysicsWorld:
    """A pymunk space of velocity-controlled discs, stepped by ``world.dt_s``."""

    def __init__(
        self,
        arena_m: float | None = None,
        world: WorldConfig = DEFAULT_WORLD,
        contact_substeps: int = 40,
        release_gap_m: float | None = None,
    ) -> None:
        self.world = world
        self.arena_m = float(arena_m if arena_m is not None else world.arena_m)
        self.contact_substeps = int(contact_substeps)
        # Half a radius: a pushing pair that the solver nudges apart by a hair, or a
        # pile whose members jostle, stays one contact.
        self.release_gap_m = 0.5 * world.radius_m if release_gap_m is None else release_gap_m
        self.space = pymunk.Space(threaded=False)
        self.space.gravity = (0.0, 0.0)
        self.space.damping = 1.0
        # Default slop is 0.1 (units): a whole radius here. Allow 0.1 mm of overlap.
        self.space.collision_slop = 1e-4
        # Fraction of an overlap left after one second (default 0.0018): push apart faster.
        self.space.collision_bias = 1e-6
        self.space.iterations = 20
        self._add_walls()
        # Chipmunk calls this for every pair in contact during a space step; without
        # contacts it costs nothing, so the arbiters are only read after steps with one.
        self._touch_seen = False
        self.space.on_collision(pre_solve=self._on_touch)
        self._bodies: dict[int, pymunk.Body] = {}
        self.ids: list[int] = []
        self.contacts_total = 0
        self.substeps_total = 0
        self._touching: set[tuple[int | str, int | str]] = set()
        self._get = pb.Buffer()
        self._setv = pb.Buffer()
        self._setp = pb.Buffer()
        self._arb = pb.Buffer()
        self._order: NDArray[np.intp] = np.zeros(0, dtype=np.intp)
        self._reindex()

    # ------------------------------------------------------------------ members

    def _on_touch(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: object) -> None:
        self._touch_seen = True

    def _add_walls(self) -> None:
        a, w = self.arena_m, WALL_THICKNESS_M
        body = self.space.static_body
        # Each wall's inner face is on the arena's edge: its centre line lies w outside.
        ends = [((-w, -w), (a + w, -w)), ((a + w, -w), (a + w, a + w)),
                ((a + w, a + w), (-w, a + w)), ((-w, a + w), (-w, -w))]
        for p, q in ends:
            seg = pymunk.Segment(body, p, q, w)
            seg.friction = 0.0
            seg.elasticity = 0.0
            self.space.add(seg)

    def add_robot(self, robot_id: int, x: float, y: float) -> None:
        """Place a disc for ``robot_id`` at (x, y) metres, at rest."""
        if robot_id in self._bodies:
            raise PhysicsError(f"robot {robot_id} is already in the world")
        r = self.world.radius_m
        if not (r <= x <= self.arena_m - r and r <= y <= self.arena_m - r):
            raise PhysicsError(f"robot {robot_id} at ({x:.3f}, {y:.3f}) is outside the arena")
        body = pymunk.Body(1.0, math.inf)
        body.position = (float(x), float(y))
        shape = pymunk.Circle(body, r)
        shape.friction = 0.0
        shape.elasticity = 0.0
        self.space.add(body, shape)
        self._bodies[robot_id] = body
        self._reindex()

    def remove_robot(self, robot_id: int) -> None:
        """Take ``robot_id``'s disc out of the world."""
        body = self._bodies.pop(robot_id, None)
        if body is None:
            raise PhysicsError(f"robot {robot_id} is not in the world")
        self.space.remove(body, *body.shapes)
        self._touching = {p for p in self._touching if robot_id not in p}
        self._reindex()

    def _reindex(self) -> None:
        """Map pymunk's body iteration order to ascending robot ids (after add/remove)."""
        self.ids = sorted(self._bodies)
        by_body = {b.id: rid for rid, b in self._bodies.items()}
        self._get.clear()
        pb.get_space_bodies(self.space, pb.BodyFields.BODY_ID, self._get)
        body_ids = np.frombuffer(self._get.int_buf(), dtype=np.uintp).tolist()
        self._row_of = {rid: k for k, rid in enumerate(self.ids)}
        # order[k] = row (in ids order) of the k-th body pymunk iterates; -1 for others
        self._order = np.array(
            [self._row_of[by_body[b]] if b in by_body else -1 for b in body_ids], dtype=np.intp
        )
        n = len(self.ids)
        self._n_bodies = len(body_ids)
        self._mine = self._order >= 0
        self._rows = self._order[self._mine]
        # Robots added in id order and none removed: pymunk iterates them in id order,
        # first, then the static body. Then rows map one to one, no gather needed.
        self._identity = bool(
            np.array_equal(self._order[:n], np.arange(n)) and not self._mine[n:].any()
        )
        self._body_row = {b.id: self._row_of[rid] for rid, b in self._bodies.items()}
        # Input buffers bound once to pymunk.batch buffers: a step only fills them.
        self._vbuf = np.zeros((self._n_bodies, 2))  # statics keep velocity 0
        self._pbuf = np.zeros((self._n_bodies, 2))
        self._pbuf[~self._mine] = tuple(self.space.static_body.position)
        self._setv.set_float_buf(self._vbuf.reshape(-1))
        self._setp.set_float_buf(self._pbuf.reshape(-1))
        self._pos = self._read_positions()

    # ------------------------------------------------------------------ state

    def _read_positions(self) -> Array:
        self._get.clear()
        pb.get_space_bodies(self.space, pb.BodyFields.POSITION, self._get)
        raw = np.frombuffer(self._get.float_buf(), dtype=np.float64).reshape(-1, 2)
        if self._identity:
            return raw[: len(self.ids)].copy()
        out = np.empty((len(self.ids), 2))
        out[self._rows] = raw[self._mine]
        return out

    def positions(self) -> Array:
        """(n, 2) positions in :attr:`ids` order (a copy, metres)."""
        return self._pos.copy()

    def _write_velocities(self, v: Array) -> None:
        self._fill(self._vbuf, v)
        pb.set_space_bodies(self.space, pb.BodyFields.VELOCITY, self._setv)

    def _write_positions(self, p: Array) -> None:
        self._fill(self._pbuf, p)
        pb.set_space_bodies(self.space, pb.BodyFields.POSITION, self._setp)

    def _fill(self, buf: Array, rows: Array) -> None:
        """Robots' rows of a bound buffer, in pymunk's order (statics' rows stay as set)."""
        if self._identity:
            buf[: len(rows)] = rows
        else:
            buf[self._mine] = rows[self._rows]

    def _contact_candidates(self) -> set[tuple[int, int]]:
        """Body-id pairs of pymunk's cached arbiters (a superset of the touching pairs)."""
        self._arb.clear()
        pb.get_space_arbiters(
            self.space, pb.ArbiterFields.BODY_A_ID | pb.ArbiterFields.BODY_B_ID, self._arb
        )
        raw = self._arb.int_buf()
        if not len(raw):  # the usual case: nothing near anything
            return set()
        ids = np.frombuffer(raw, dtype=np.uintp).reshape(-1, 2).tolist()
        return {(a, b) for a, b in ids}

    def _pair_gap(self, pair: tuple[int | str, int | str], pos: Array) -> float:
        """Gap (m) between the discs of a pair, or a disc and the nearest wall; < 0 overlaps."""
        r, a = self.world.radius_m, self.arena_m
        row = self._row_of
        i, j = pair
        if j == "wall":
            x, y = pos[row[int(i)]]
            return float(min(x, y, a - x, a - y) - r)
        return math.dist(pos[row[int(i)]], pos[row[int(j)]]) - 2 * r

    def _touching_pairs(
        self, pos: Array, candidates: set[tuple[int, int]], gap_m: float
    ) -> set[tuple[int | str, int | str]]:
        """Pairs whose gap at ``pos`` is below ``gap_m``, among pymunk's arbiter candidates."""
        r, a = self.world.radius_m, self.arena_m
        out: set[tuple[int | str, int | str]] = set()
        for ba, bb in candidates:
            ra, rb = self._body_row.get(ba), self._body_row.get(bb)
            if ra is not None and rb is not None:
                if math.dist(pos[ra], pos[rb]) < 2 * r + gap_m:
                    i, j = sorted((self.ids[ra], self.ids[rb]))
                    out.add((i, j))
            else:
                row = ra if ra is not None else rb
                if row is None:
                    continue
                x, y = pos[row]
                if min(x, y, a - x, a - y) < r + gap_m:
                    out.add((self.ids[row], "wall"))
        return out

    # ------------------------------------------------------------------ step

    def step(self, velocities: Array) -> StepResult:
        """Advance by ``world.dt_s`` with one velocity per robot ((n, 2), m/s, ids order)."""
        n = len(self.ids)
        v = np.asarray(velocities, dtype=np.float64).reshape(n, 2)
        vmax = self.world.v_max_mps
        speed2 = np.einsum("ij,ij->i", v, v)
        top = float(speed2.max()) if n else 0.0
        if not top <= vmax * vmax:  # too fast, or not finite (nan fails every comparison)
            v = np.where(np.isfinite(v), v, 0.0)
            speed = np.hypot(v[:, 0], v[:, 1])
            v = v * np.minimum(1.0, vmax / np.maximum(speed, 1e-300))[:, None]
        dt = self.world.dt_s
        before = self._pos
        self._write_velocities(v)
        self._touch_seen = False
        self.space.step(dt)
        pos = self._read_positions()
        cands = self._contact_candidates() if self._touch_seen else set()
        substepped = False
        # Redo the step in sub-steps when it ends with an overlap beyond 10x the slop.
        if cands and self._touching_pairs(pos, cands, -10 * self.space.collision_slop):
            substepped = True
            self.substeps_total += 1
            self._write_positions(before)
            self._write_velocities(v)
            sub = dt / self.contact_substeps
            for _ in range(self.contact_substeps):
                self.space.step(sub)
            pos = self._read_positions()
            cands = self._contact_candidates()  # the state after the sub-steps
        new: list[tuple[int | str, int | str]] = []
        if cands or self._touching:
            # A contact begins when a pair touches that was not in contact; it ends only
            # once the pair is release_gap_m apart (hysteresis).
            touching = self._touching_pairs(pos, cands, 1e-6)
            new = sorted(touching - self._touching, key=str)
            kept = {p for p in self._touching if self._pair_gap(p, pos) < self.release_gap_m}
            self._touching = touching | kept
            self.contacts_total += len(new)
        self._pos = pos
        return StepResult(positions=pos, new_contacts=new, substepped=substepped)
