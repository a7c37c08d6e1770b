"""The plan's frame (:mod:`runtime.core.plan_frame`) against references built here.

* the smallest enclosing circle against brute force (every point, pair and triple) and
  hand-worked cases;
* the frame and the steps left K against their definitions, the kept support against
  a fresh solve, the batch against the one-team solve;
* the source run as Python against the compiled module, bit for bit;
* bad arrays raise, a stale support is solved afresh.
"""

from __future__ import annotations

import importlib.util
import itertools
import math
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

import runtime.core.plan_frame as installed
from runtime.world_config import DEFAULT_WORLD

REACH = DEFAULT_WORLD.v_max_mps * DEFAULT_WORLD.dt_s
SOURCE = Path(installed.__file__).with_name("plan_frame.py")
COMPILED = not installed.__file__.endswith(".py")


def _as_python() -> ModuleType:
    """The module's source run as Python, whether or not a compiled one is installed."""
    spec = importlib.util.spec_from_file_location("plan_frame_as_python", SOURCE)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


PY = _as_python()


@pytest.fixture(params=["installed", "python"])
def pf(request: pytest.FixtureRequest) -> ModuleType:
    return installed if request.param == "installed" else PY


# ------------------------------------------------------------------ references


def brute_circle(p: np.ndarray) -> tuple[float, float, float]:
    """The smallest of the circles through 1, 2 (diameter) or 3 of the points that
    contains them all."""
    cands: list[tuple[float, float, float]] = [(x, y, 0.0) for x, y in p.tolist()]
    for a, b in itertools.combinations(p.tolist(), 2):
        cx, cy = (a[0] + b[0]) / 2, (a[1] + b[1]) / 2
        cands.append((cx, cy, math.dist(a, (cx, cy))))
    for a, b, c in itertools.combinations(p.tolist(), 3):
        bx, by, qx, qy = b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]
        den = 2 * (bx * qy - by * qx)
        if abs(den) < 1e-12:
            continue
        ux = (qy * (bx * bx + by * by) - by * (qx * qx + qy * qy)) / den
        uy = (bx * (qx * qx + qy * qy) - qx * (bx * bx + by * by)) / den
        cands.append((ux + a[0], uy + a[1], math.hypot(ux, uy)))
    best = None
    for cx, cy, r in cands:
        if np.hypot(p[:, 0] - cx, p[:, 1] - cy).max() <= r + 1e-9 * (1 + r):
            if best is None or r < best[2]:
                best = (cx, cy, r)
    assert best is not None
    return best


def frame_by_definition(pos: np.ndarray, pts: np.ndarray, w: float) -> tuple[float, float, float]:
    """(tx, ty, K) from the definition: brute-force circle, blend, whole steps."""
    d = pos - pts
    cx, cy, _ = brute_circle(d)
    mx, my = d.mean(axis=0)
    t = np.array([mx, my]) if w >= 1 else np.array([cx + w * (mx - cx), cy + w * (my - cy)])
    far = np.hypot(*(pts + t - pos).T).max()
    return float(t[0]), float(t[1]), float(max(1, math.ceil(far / REACH - 1e-9)))


def solve(pf: ModuleType, pos: Any, pts: Any, w: float, sup: Any = None) -> tuple[float, ...]:
    sup = np.zeros(4, dtype=np.int64) if sup is None else sup
    return tuple(pf.plan_frame(np.ascontiguousarray(pos), np.ascontiguousarray(pts),
                               np.zeros((len(pos), 2)), w, REACH, sup))


# -------------------------------------------------------------- the circle


@pytest.mark.parametrize("m", [1, 2, 3, 4, 5, 7, 10, 13])
def test_the_circle_is_the_brute_force_one(pf: ModuleType, m: int) -> None:
    rng = np.random.default_rng(m)
    for trial in range(40):
        p = rng.normal(size=(m, 2)) * rng.choice([1e-3, 1.0, 20.0])
        if trial % 4 == 1:  # a lattice: duplicates and collinear triples
            p = rng.integers(-2, 3, (m, 2)) * 0.5
        cx, cy, r = pf.min_enclosing_circle(p)
        bx, by, br = brute_circle(p)
        scale = 1.0 + br
        assert abs(r - br) <= 1e-9 * scale, (p, r, br)
        assert math.hypot(cx - bx, cy - by) <= 1e-6 * scale  # the smallest circle is unique
        assert np.hypot(p[:, 0] - cx, p[:, 1] - cy).max() <= r * (1 + 1e-12) + 1e-12


@pytest.mark.parametrize(("pts", "want"), [
    ([[3.0, -1.0]], (3.0, -1.0, 0.0)),  # one point
    ([[0.0, 0.0], [2.0, 0.0]], (1.0, 0.0, 1.0)),  # two points: the diameter
    ([[1.0, 1.0]] * 5, (1.0, 1.0, 0.0)),  # duplicates of one point
    ([[0.0, 0.0], [0.0, 0.0], [0.0, 4.0], [0.0, 4.0]], (0.0, 2.0, 2.0)),  # duplicated pair
    ([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [2.0, 0.0]], (1.5, 0.0, 1.5)),  # collinear
    ([[-1.0, -1.0], [0.5, 0.5], [2.0, 2.0]], (0.5, 0.5, 1.5 * math.sqrt(2))),  # diagonal
    ([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0]], (2.0, 1.5, 2.5)),  # right angle: hypotenuse
    ([[0.0, 0.0], [10.0, 0.0], [5.0, 1.0]], (5.0, 0.0, 5.0)),  # obtuse: the longest side
    ([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]], (0.0, 0.0, math.sqrt(2))),
])
def test_the_circle_of_hand_worked_cases(pf: ModuleType, pts: list[list[float]],
                                         want: tuple[float, float, float]) -> None:
    for order in (pts, pts[::-1]):
        got = pf.min_enclosing_circle(np.array(order))
        assert got == pytest.approx(want, abs=1e-12)


def test_the_circle_of_an_equilateral_triangle(pf: ModuleType) -> None:
    for angle in (0.0, 0.3, 2.0):
        c, s = math.cos(angle), math.sin(angle)
        tri = [(c * math.cos(a) - s * math.sin(a) + 0.5, s * math.cos(a) + c * math.sin(a))
               for a in (0.0, 2 * math.pi / 3, 4 * math.pi / 3)]  # unit circumradius
        cx, cy, r = pf.min_enclosing_circle(tri)
        assert (cx, cy, r) == pytest.approx((0.5, 0.0, 1.0), abs=1e-12)
        side = math.dist(tri[0], tri[1])
        assert r == pytest.approx(side / math.sqrt(3), abs=1e-12)


# -------------------------------------------------------------- the frame


@pytest.mark.parametrize("w", [0.0, 0.25, 0.6, 1.0])
@pytest.mark.parametrize("n", [1, 2, 3, 6, 11])
def test_the_frame_and_steps_left_are_their_definition(pf: ModuleType, n: int, w: float) -> None:
    rng = np.random.default_rng(10 * n + int(4 * w))
    for _ in range(25):
        pts = rng.normal(size=(n, 2))
        pos = pts + rng.uniform(-1.0, 1.0, (n, 2)) * rng.choice([1e-3, 0.05, 1.0])
        tx, ty, k = solve(pf, pos, pts, w)
        rx, ry, rk = frame_by_definition(pos, pts, w)
        assert math.hypot(tx - rx, ty - ry) <= 1e-6
        far = np.hypot(*(pts + np.array([tx, ty]) - pos).T).max()
        assert k == rk or abs(far / REACH - round(far / REACH)) < 1e-6  # a whole-step tie
        assert k >= 1 and k == int(k)
        assert far <= k * REACH * (1 + 1e-9)  # the farthest robot lands in K steps
        assert k == 1 or far > (k - 1) * REACH  # and not in fewer


def test_the_centroid_frame_is_the_mean_displacement(pf: ModuleType) -> None:
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(9, 2))
    pos = pts + rng.normal(size=(9, 2))
    tx, ty, _ = solve(pf, pos, pts, 1.0)
    mx = my = 0.0
    for x, y in (pos - pts).tolist():
        mx, my = mx + x, my + y
    assert (tx, ty) == (mx / 9, my / 9)


@pytest.mark.parametrize("w", [0.0, 0.25])
@pytest.mark.parametrize("n", [3, 8, 40])
def test_the_kept_support_gives_the_fresh_frame(pf: ModuleType, n: int, w: float) -> None:
    """Along the plan the kept support's circle is the smallest: the fresh solve's frame;
    jitter below the slack keeps it (the frame within the slack); a jump re-solves it."""
    rng = np.random.default_rng(n)
    pts = rng.normal(size=(n, 2)) * 0.5
    pos = pts + rng.uniform(-0.6, 0.6, (n, 2))
    sup, d = np.zeros(4, dtype=np.int64), np.zeros((n, 2))
    kept = resolved = 0
    jittered = False  # since the support was last solved
    for step in range(60):
        before = sup.copy()
        tx, ty, k = pf.plan_frame(pos, pts, d, w, REACH, sup)
        fx, fy, fk = solve(pf, pos, pts, w)
        if before[0] and np.array_equal(before, sup):
            kept += 1
        else:
            resolved, jittered = resolved + 1, False
        if jittered:
            assert math.hypot(tx - fx, ty - fy) <= installed.SUPPORT_SLACK_M
            assert abs(k - fk) <= 1
        else:
            assert math.hypot(tx - fx, ty - fy) <= 1e-12 and k == fk
        pos = pos + (pts + np.array([tx, ty]) - pos) / k  # every robot one step along its plan
        if step % 6 == 4:
            pos = pos + rng.normal(size=(n, 2)) * 1e-5  # jitter below the slack
            jittered = True
        if k == 1.0:  # landed: one robot jumps, the support is re-solved
            pos[rng.integers(n)] += rng.normal(size=2)
    assert kept > 20 and resolved >= 2, (kept, resolved)


def test_a_stale_or_corrupt_support_is_solved_afresh(pf: ModuleType) -> None:
    rng = np.random.default_rng(0)
    pos, pts = rng.normal(size=(5, 2)), rng.normal(size=(5, 2))
    want = solve(pf, pos, pts, 0.25)
    for junk in ([3, 0, 1, 999], [2, -1, 0, 0], [9, 0, 1, 2], [-4, 0, 0, 0], [0, 7, 7, 7]):
        sup = np.array(junk, dtype=np.int64)
        assert solve(pf, pos, pts, 0.25, sup) == want
        assert 1 <= sup[0] <= 3 and all(0 <= j < 5 for j in sup[1 : 1 + sup[0]])


@pytest.mark.parametrize("w", [0.0, 0.25, 1.0])
def test_the_batch_is_the_one_team_solve_team_by_team(pf: ModuleType, w: float) -> None:
    rng = np.random.default_rng(5)
    for n in (1, 2, 7, 30):
        E = 6
        pts = rng.normal(size=(E, n, 2))
        pos = pts + rng.normal(size=(E, n, 2))
        t, k = np.full((E, 2), np.nan), np.full(E, np.nan)
        pf.plan_frames(pos, pts, w, REACH, t, k)
        for e in range(E):
            assert (t[e, 0], t[e, 1], k[e]) == solve(pf, pos[e], pts[e], w)


def test_bad_arrays_raise(pf: ModuleType) -> None:
    n, rng = 5, np.random.default_rng(0)
    pos, pts, d = rng.normal(size=(n, 2)), rng.normal(size=(n, 2)), np.zeros((n, 2))
    sup = np.zeros(4, dtype=np.int64)
    ro = np.zeros((n, 2))
    ro.flags.writeable = False

    def plan(p: Any = pos, q: Any = pts, dd: Any = d, w: Any = 0.0, r: Any = REACH,
             s: Any = sup) -> Any:
        return pf.plan_frame(p, q, dd, w, r, s)

    t, k = np.zeros((3, 2)), np.zeros(3)
    good3 = rng.normal(size=(3, n, 2))
    bad: list[Callable[[], Any]] = [
        lambda: plan(p=pos.astype(np.float32)), lambda: plan(q=pts[:-1]),
        lambda: plan(dd=d[:-1]), lambda: plan(s=sup.astype(np.int32)), lambda: plan(s=sup[:3]),
        lambda: plan(dd=ro), lambda: plan(p=np.zeros((n, 4))[:, ::2]), lambda: plan(w="w"),
        lambda: plan(p=np.zeros((0, 2)), q=np.zeros((0, 2))), lambda: plan(r=0.0),
        lambda: plan(p=[[0.0, 0.0]]), lambda: pf.min_enclosing_circle(np.zeros((0, 2))),
        lambda: pf.min_enclosing_circle(np.zeros((3, 3))),
        lambda: pf.plan_frames(good3, good3[:, :-1], 0.0, REACH, t, k),
        lambda: pf.plan_frames(good3, good3, 0.0, REACH, t[:2], k),
        lambda: pf.plan_frames(good3, good3, 0.0, REACH, t, k.astype(np.float32)),
        lambda: pf.plan_frames(good3, good3, 0.0, -1.0, t, k),
    ]
    for j, call in enumerate(bad):
        with pytest.raises((TypeError, ValueError, BufferError)):
            call()
            pytest.fail(f"bad call {j} did not raise")
    plan(dd=np.zeros((n + 3, 2)), s=np.zeros(6, dtype=np.int64))  # larger scratch: fine


# -------------------------------------------------------- compiled = Python


@pytest.mark.skipif(not COMPILED, reason="the module is not compiled (it runs as Python)")
def test_the_source_run_as_python_gives_the_compiled_numbers() -> None:
    rng = np.random.default_rng(11)
    for n in (1, 2, 3, 5, 9, 24, 60):
        for w in (0.0, 0.25, 1.0):
            pts: Any = rng.normal(size=(n, 2)) * 0.5
            if n > 3 and w == 0.25:
                pts = rng.integers(-2, 3, (n, 2)) * 0.25  # duplicates, collinear triples
            pos = pts + rng.uniform(-0.7, 0.7, (n, 2))
            sc, sp = np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64)
            for _ in range(30):
                a = installed.plan_frame(pos, pts, np.zeros((n, 2)), w, REACH, sc)
                b = PY.plan_frame(pos, pts, np.zeros((n, 2)), w, REACH, sp)
                assert a == b and np.array_equal(sc, sp)
                assert installed.min_enclosing_circle(pos - pts) == PY.min_enclosing_circle(
                    pos - pts)
                pos = pos + (pts + a[:2] - pos) / a[2] + rng.normal(size=(n, 2)) * 1e-3
            E = 4
            P, Q = pts + rng.normal(size=(E, n, 2)), np.broadcast_to(pts, (E, n, 2))
            ta, ka, tb, kb = np.zeros((E, 2)), np.zeros(E), np.zeros((E, 2)), np.zeros(E)
            installed.plan_frames(P, Q, w, REACH, ta, ka)
            PY.plan_frames(P, Q, w, REACH, tb, kb)
            assert np.array_equal(ta, tb) and np.array_equal(ka, kb)
