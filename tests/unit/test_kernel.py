"""The compiled decision kernel (``runtime/_kernel.c``) gives the Python reference's numbers.

Held equal here, on the same inputs:

* ``plan_frame`` and :class:`runtime.rules.PlanFrame`'s Python solve, step after step:
  the frame within 1e-12 m, the steps left K and the kept support exactly;
* ``row`` and :func:`runtime.observation.neighbour_order`, :func:`general_row` and the
  plan's pace: velocities, order, squared distances and float64 rows exactly, float32
  rows as the float64 ones cast;
* ``orca`` and :func:`runtime.decision._near_in_order` then
  :func:`runtime.safety.orca_velocity`: the velocity within 1e-12 m/s, ``changed`` exactly;
* ``centred_cost`` and the assignment's cost (numpy) exactly;
* :class:`runtime.controller.Controller` compiled and in Python over whole episodes.

The one known difference, C's ``hypot`` against CPython's ``math.hypot`` (a last bit,
rarely), is what the tolerances allow; on every case here the numbers are bit-equal.
Bad arrays raise, never crash; ``PATTERNRL_KERNEL=0`` turns the kernel off. Without a
built kernel these tests fail: the kernel is part of what is tested.
"""

from __future__ import annotations

import ast
import itertools
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from runtime import safety as safety_module
from runtime.brain import RuleBrain, load_brain
from runtime.controller import Controller
from runtime.decision import _near_in_order
from runtime.kernel import KERNEL, VERSION, kernel_status
from runtime.observation import frame_velocities, general_row, neighbour_order
from runtime.patterns import make_pattern
from runtime.rules import PlanFrame
from runtime.safety import OrcaParams, clamp_speed, orca_velocity
from runtime.world_config import DEFAULT_WORLD

W = DEFAULT_WORLD
REACH = W.v_max_mps * W.dt_s
ROOT = Path(__file__).resolve().parents[2]
BAD = (TypeError, ValueError, BufferError)


def kern() -> ModuleType:
    assert KERNEL is not None, kernel_status()
    return KERNEL


def test_the_kernel_is_built_and_in_use() -> None:
    assert KERNEL is not None, kernel_status()
    assert kernel_status() == "compiled"
    assert KERNEL.VERSION == VERSION
    assert Controller(RuleBrain(), compiled=True)._kernel is KERNEL
    assert PlanFrame(compiled=True)._kernel is KERNEL


# ------------------------------------------------------------------ plan_frame


def check_frame(ref: PlanFrame, fast: PlanFrame, pos: Any, pts: Any, w: float
                ) -> tuple[Any, float]:
    t, k = ref.solve(pos, pts, w, W)
    tx, ty, kk = fast.solve_floats(pos, pts, w, W)
    assert abs(tx - t[0]) <= 1e-12 and abs(ty - t[1]) <= 1e-12, (tx, ty, t)
    assert kk == k
    sup = fast._sup
    assert sup[1 : 1 + sup[0]].tolist() == ref._support
    return t, k


@pytest.mark.parametrize("w", [0.0, 0.25, 1.0])
@pytest.mark.parametrize("n", [1, 2, 3, 7, 23, 24, 50, 100])
def test_plan_frame_is_the_reference_along_the_plan_and_after_jumps(n: int, w: float) -> None:
    rng = np.random.default_rng(n * 7 + int(4 * w))
    ref, fast = PlanFrame(compiled=False), PlanFrame(compiled=True)
    pts = rng.normal(size=(n, 2)) * 0.5
    pos = pts + rng.uniform(-0.6, 0.6, (n, 2))
    steps, supports, landed = [], [], 0
    for step in range(40):
        t, k = check_frame(ref, fast, pos, pts, w)
        steps.append(k)
        supports.append(ref._support)
        pos = pos + (pts + t - pos) / k  # every robot on its plan: one step of K
        if step % 7 == 3:  # jitter below the support's slack: keeps it
            pos = pos + rng.normal(size=(n, 2)) * 2e-5
        if k == 1.0:  # landed: something moves the team off its slots
            landed += 1
            if landed % 3 == 1:  # a robot off the support jumps: breaks the support
                off = [j for j in range(n) if j not in ref._support] or [0]
                pos[rng.choice(off)] += rng.normal(size=2)
            elif landed % 3 == 2:  # a new pattern point for one robot (a new assignment)
                pts[rng.integers(n)] = rng.normal(size=2) * 0.5
    assert landed >= 2 and (n == 1 or max(steps) > 3)
    changes = sum(a != b for a, b in itertools.pairwise(supports))
    assert n < 7 or changes >= 2, changes  # the support re-solved, not only kept


@pytest.mark.parametrize("n", [2, 3, 7, 24, 50])
def test_plan_frame_on_collinear_and_duplicate_displacements(n: int) -> None:
    rng = np.random.default_rng(n)
    pts = rng.normal(size=(n, 2))
    s = rng.uniform(-2.0, 2.0, (n, 1))
    cases = [
        pts + 0.3 + s * [0.6, 0.8],  # collinear displacements
        pts + s * [1.0, 0.0],  # collinear on an axis
        pts + s.round(0) * [0.0, 0.5],  # collinear and repeated
        pts + np.array([0.5, -0.25]),  # all the same displacement: radius 0
        pts + rng.normal(size=(3, 2))[rng.integers(0, 3, n)],  # three, repeated
        pts + rng.integers(-2, 3, (n, 2)) * 0.5,  # a lattice: duplicates, collinear triples
    ]
    for w in (0.0, 0.25, 1.0):
        ref, fast = PlanFrame(compiled=False), PlanFrame(compiled=True)
        for pos in cases + cases[::-1]:  # the support carried from case to case too
            check_frame(ref, fast, np.ascontiguousarray(pos), pts, w)


# --------------------------------------------------------------------- row


@pytest.mark.parametrize("n", [1, 2, 12, 33, 100])
def test_row_is_neighbour_order_general_row_and_plan_pace(n: int) -> None:
    K = kern()
    rng = np.random.default_rng(100 + n)
    vel, order, d2 = np.zeros((n, 2)), np.zeros(n, dtype=np.int64), np.zeros(n)
    keys = np.zeros((n, 2))
    for trial in range(3):
        # trial 1 a lattice: many equal distances, ties broken by id
        pos: Any = rng.integers(0, 5, (n, 2)) * 0.3 if trial == 1 else rng.normal(size=(n, 2))
        if trial == 2 and n > 2:
            pos[-1] = pos[0]  # coincident robots: d2 = 0
        prev = pos - rng.normal(size=(n, 2)) * 0.05
        L = pos.tolist()
        V = frame_velocities(L, prev.tolist(), W.dt_s)
        for i in range(n):
            k = (6, n + 2, 1)[(i + trial) % 3]  # k > n - 1: zero padding
            sx, sy = (pos[i] + rng.normal(size=2) * (0.05, 2.0)[i % 2]).tolist()
            steps_left = float((i + trial) % 4)  # 0: the general row, else the plan's pace
            pace = steps_left * REACH
            o_ref, d2_ref = neighbour_order(i, L, pos)
            want = general_row(i, L, V, (sx, sy), k, W, order=o_ref)
            if steps_left:
                den = steps_left * (W.v_max_mps * W.dt_s)
                want[2], want[3] = want[0] / den, want[1] / den
            out = np.full(6 + 5 * k, np.nan)
            K.row(pos, prev, i, sx, sy, k, REACH, W.dt_s, pace, vel, order, d2, keys, out)
            assert vel.tolist() == V
            assert order.tolist() == o_ref
            assert d2.tolist() == d2_ref
            assert out.tolist() == want
            out32 = np.full(6 + 5 * k, np.nan, dtype=np.float32)
            K.row(pos, prev, i, sx, sy, k, REACH, W.dt_s, pace, vel, order, d2, keys, out32)
            assert out32.tolist() == np.array(want).astype(np.float32).tolist()


# -------------------------------------------------------------------- orca


def crowds(rng: np.random.Generator) -> list[tuple[str, Any, Any, Any]]:
    """(name, positions, velocities, preferred velocities) of crowds meant to reach every
    branch: collisions, coincident robots, out of range, ties, NaN, infeasible LPs."""
    out = []
    n = 14
    pos: Any = rng.uniform(0.0, 3.0, (n, 2))
    out.append(("random", pos, rng.normal(size=(n, 2)) * 0.6, rng.normal(size=(n, 2))))
    pos = rng.uniform(0.0, 1.0, (n, 2))  # most pairs closer than 2R: the collision branch
    out.append(("overlap", pos, rng.normal(size=(n, 2)) * 0.6, rng.normal(size=(n, 2)) * 2))
    pos = rng.uniform(0.0, 1.5, (8, 2))
    pos[1] = pos[0]  # two coincident robots ...
    vel = rng.normal(size=(8, 2)) * 0.5
    vel[1] = vel[0]  # ... with the same velocity: w = 0, the arbitrary axis
    out.append(("coincident", pos, vel, rng.normal(size=(8, 2))))
    pos = rng.uniform(0.0, 9.0, (n, 2))  # most neighbours beyond 2 m ...
    pos[:3] = [[1.0, 1.0], [3.0, 1.0], [1.0, 3.0]]  # ... two at exactly 2 m: out of range
    out.append(("sparse", pos, rng.normal(size=(n, 2)), rng.normal(size=(n, 2))))
    pos = rng.integers(0, 4, (16, 2)) * 0.3  # a lattice: exact distance ties
    pos = pos[np.unique(pos, axis=0, return_index=True)[1]]
    m = len(pos)
    out.append(("lattice", pos, rng.normal(size=(m, 2)) * 0.5, rng.normal(size=(m, 2))))
    vel = rng.normal(size=(n, 2)) * 0.6
    vel[0] = np.nan  # a NaN own velocity (robot 0) and NaN / inf neighbour velocities
    vel[3, 1], vel[5, 0] = np.nan, np.inf
    out.append(("nan", rng.uniform(0.0, 1.5, (n, 2)), vel, rng.normal(size=(n, 2))))
    # dense rings all heading inward at v_max: infeasible LPs (lp3), the first one
    # overlapping (the collision branch), the second 2R apart (the cone's legs)
    for name, m, r in (("ring-overlap", 20, 0.45), ("ring", 16, 0.65)):
        a = np.arange(m) * (2 * np.pi / m)
        ring = np.stack([np.cos(a), np.sin(a)], axis=1) * r
        out.append((name, ring, -ring / r * W.v_max_mps, -ring / r * 1.3))
    return out


@pytest.mark.parametrize("tau", [0.75, 0.1])
@pytest.mark.parametrize("keep_right", [0.0, 0.2])
def test_orca_is_near_in_order_then_orca_velocity(
    keep_right: float, tau: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    K = kern()
    lp3_in: set[str] = set()  # the crowds where the reference reached lp3
    real_lp3, crowd = safety_module._lp3, [""]

    def counting_lp3(*args: Any) -> tuple[float, float]:
        lp3_in.add(crowd[0])
        return real_lp3(*args)

    monkeypatch.setattr(safety_module, "_lp3", counting_lp3)
    rng = np.random.default_rng(int(tau * 100 + keep_right * 10))
    collided = cases = 0
    for keep in (1, 3, 10):
        params = OrcaParams(time_horizon_s=tau, max_neighbours=keep, keep_right_rad=keep_right)
        range_sq = params.neighbour_dist_m * params.neighbour_dist_m
        combined = 2.0 * (W.radius_m + params.radius_margin_m)
        for crowd[0], pos, vel, pref in crowds(rng):
            L, V = pos.tolist(), vel.tolist()
            for i in range(len(L)):
                bvx, bvy = pref[i].tolist()
                vx, vy = clamp_speed(bvx, bvy, W.v_max_mps)
                order, d2 = neighbour_order(i, L, pos)
                near = _near_in_order(i, L, order, d2, params)
                ox, oy = V[i] if math.isfinite(V[i][0]) and math.isfinite(V[i][1]) else (0, 0)
                want = orca_velocity(vx, vy, ox, oy, near, [V[k[3]] for k in near], W, params)
                got = K.orca(vx, vy, pos, vel, i, np.array(order), np.array(d2), keep,
                             range_sq, combined, tau, W.dt_s, keep_right, W.v_max_mps)
                assert got[2] == want[2], (i, keep, got, want)
                np.testing.assert_allclose(got[:2] + got[3:], want[:2] + want[3:], 0, 1e-12)
                collided += any(nb[0] <= combined * combined for nb in near)
                cases += 1
    assert {"overlap", "ring-overlap"} <= lp3_in, lp3_in  # the infeasible LP (lp3) ...
    assert tau < 0.5 or "ring" in lp3_in, lp3_in  # ... also without a collision
    assert collided > cases // 10, "too few cases in the collision branch"


@pytest.mark.parametrize("n", [2, 10, 64])
def test_centred_cost_is_the_assignments_numpy_cost(n: int) -> None:
    rng = np.random.default_rng(n)
    pos = rng.normal(size=(n, 2)) * 2.0
    cc = make_pattern("heart", n)
    cc = cc - cc.mean(axis=0, keepdims=True)
    cost = np.empty((n, n))
    cx, cy = kern().centred_cost(pos, cc[:, 0].copy(), cc[:, 1].copy(), cost)
    cen = np.add.reduce(pos, 0) / n
    assert [cx, cy] == cen.tolist()
    Pc = pos - cen
    want = (Pc[:, 0:1] - cc[:, 0]) ** 2 + (Pc[:, 1:2] - cc[:, 1]) ** 2
    assert cost.tolist() == want.tolist()


# ------------------------------------------------------------- whole episodes


def starts(n: int, rng: np.random.Generator) -> Any:
    """n positions at least the world's start separation apart."""
    side = 0.6 * math.sqrt(n) + 1.0
    pts: list[Any] = []
    while len(pts) < n:
        p = rng.uniform(0.0, side, 2)
        if all(np.hypot(*(p - q)) >= W.start_separation_m for q in pts):
            pts.append(p)
    return np.array(pts)


def plan_brain(n: int) -> Any:
    brain = load_brain(str(ROOT / "exports" / "circle-10-general.onnx"))
    if not brain.spec.accepts_team(n):
        brain = load_brain(str(ROOT / "exports" / "general.onnx"))
    assert brain.spec.name == "plan" and brain.spec.accepts_team(n)
    return brain


@pytest.mark.parametrize("safety", [OrcaParams(), None], ids=["orca", "no-filter"])
@pytest.mark.parametrize("brain", ["plan", "rule"])
@pytest.mark.parametrize("n", [10, 30])
def test_controller_compiled_decides_as_the_reference_over_episodes(
    n: int, brain: str, safety: OrcaParams | None
) -> None:
    rng = np.random.default_rng(n + (brain == "plan"))
    C = make_pattern("circle", n)
    pos = starts(n, rng)
    make = (lambda: plan_brain(n)) if brain == "plan" else RuleBrain
    b_fast, b_slow = make(), make()
    fast = [Controller(b_fast, W, safety, compiled=True) for _ in range(n)]
    slow = [Controller(b_slow, W, safety, compiled=False) for _ in range(n)]
    same_changed = changed = total = 0
    for t in range(60):
        got = [fast[i].decide(i, pos, C, t) for i in range(n)]
        want = [slow[i].decide(i, pos, C, t) for i in range(n)]
        for g, r in zip(got, want, strict=True):
            assert g.error == r.error == ""
            assert g.slot == r.slot
            np.testing.assert_allclose(g.brain_velocity, r.brain_velocity, rtol=0, atol=1e-9)
            np.testing.assert_allclose(g.velocity, r.velocity, rtol=0, atol=1e-9)
            same_changed += g.safety_changed == r.safety_changed
            changed += r.safety_changed
            total += 1
        pos = pos + W.dt_s * np.array([d.velocity for d in want])
    assert same_changed >= 0.999 * total, (same_changed, total)
    assert (changed > 0) == (safety is not None)  # the filter acted, when there is one


def test_a_numpy_integer_robot_index_decides_as_a_python_int() -> None:
    pos = np.random.default_rng(0).uniform(0.0, 3.0, (5, 2))
    C = make_pattern("circle", 5)
    want = Controller(RuleBrain(), compiled=False).decide(np.int64(2), pos, C, 0)  # type: ignore[arg-type]
    got = Controller(RuleBrain(), compiled=True).decide(np.int64(2), pos, C, 0)  # type: ignore[arg-type]
    assert got.velocity == want.velocity


def test_bad_input_raises_and_never_crashes() -> None:
    """Wrong dtypes, sizes, indices, read-only or non-contiguous arrays: an exception."""
    K, n, rng = kern(), 5, np.random.default_rng(0)
    pos, pts, d, cc, cost = rng.normal(size=(n, 2)), rng.normal(size=(n, 2)), *[
        np.zeros(s) for s in ((n, 2), n, (n, n))]
    sup, order = np.zeros(4, dtype=np.int64), np.zeros(n, dtype=np.int64)
    vel, d2, keys, out = np.zeros((n, 2)), np.zeros(n), np.zeros((n, 2)), np.zeros(36)
    f32, strided, ro = pos.astype(np.float32), np.zeros((n, 4))[:, ::2], np.zeros(36)
    ro.flags.writeable = False

    def plan(p: Any = pos, q: Any = pts, dd: Any = d, w: Any = 0.0, s: Any = sup) -> Any:
        return K.plan_frame(p, q, dd, w, REACH, s)

    def cost_of(p: Any = pos, x: Any = cc, c: Any = cost) -> Any:
        return K.centred_cost(p, x, cc, c)

    def row(p: Any = pos, prev: Any = pos, i: Any = 0, k: Any = 6, v: Any = vel,
            o: Any = order, dd: Any = d2, ks: Any = keys, ou: Any = out) -> Any:
        return K.row(p, prev, i, 0.5, 0.5, k, REACH, W.dt_s, 0.0, v, o, dd, ks, ou)

    def orca(p: Any = pos, v: Any = vel, i: Any = 0, o: Any = order, dd: Any = d2,
             keep: Any = 10) -> Any:
        return K.orca(0.5, 0.0, p, v, i, o, dd, keep, 4.0, 0.24, 0.75, W.dt_s, 0.2, 1.0)

    row()  # valid: fills order and d2 for orca
    calls: list[Callable[[], Any]] = [
        lambda: plan(p=f32), lambda: plan(q=pts[:-1]), lambda: plan(dd=d[:-1]),
        lambda: plan(s=sup.astype(np.int32)), lambda: plan(s=sup[:3]), lambda: plan(s=ro[:4]),
        lambda: plan(p=strided), lambda: plan(w="w"), lambda: K.plan_frame(pos, pts, d),
        lambda: plan(p=np.zeros((0, 2)), q=np.zeros((0, 2))), lambda: plan(dd=ro[:10]),
        lambda: cost_of(p=f32), lambda: cost_of(x=cc[:-1]), lambda: cost_of(c=cost[:-1]),
        lambda: cost_of(c=np.zeros((n, 2 * n))[:, ::2]), lambda: cost_of(c=ro[:25]),
        lambda: cost_of(c=cost.astype(np.float32)),
        lambda: row(p=f32), lambda: row(prev=pos[:-1]), lambda: row(i=n), lambda: row(i=-1),
        lambda: row(i=1.0), lambda: row(k=-1), lambda: row(ou=out[:30]), lambda: row(ou=ro),
        lambda: row(ou=out.astype(np.int64)), lambda: row(o=order.astype(np.int32)),
        lambda: row(v=strided), lambda: row(ks=keys[:-1]), lambda: row(dd=d2[:-1]),
        lambda: orca(p=f32), lambda: orca(p=strided), lambda: orca(v=vel[:-1]),
        lambda: orca(i=n), lambda: orca(i=-1), lambda: orca(o=np.array([0, 1, 2, 3, n])),
        lambda: orca(o=np.array([0, 1, -1, 3, 4])), lambda: orca(o=order.astype(np.int32)),
        lambda: orca(o=np.zeros(2 * n, dtype=np.int64)[::2]), lambda: orca(dd=d2[:-1]),
        lambda: orca(keep=65), lambda: orca(keep=-1), lambda: orca(v=vel.astype(np.float32)),
    ]
    for j, call in enumerate(calls):
        try:
            call()
        except BAD:
            continue
        pytest.fail(f"bad call {j} did not raise")
    # a stale or corrupt support is not trusted: solved afresh, as the reference would
    for junk in ([3, 0, 1, 999], [2, -1, 0, 0], [9, 0, 1, 2], [-4, 0, 0, 0]):
        sup = np.array(junk, dtype=np.int64)
        tx, ty, k = plan(w=0.25, s=sup)
        t, kk = PlanFrame(compiled=False).solve(pos, pts, 0.25, W)
        assert abs(tx - t[0]) <= 1e-12 and abs(ty - t[1]) <= 1e-12 and k == kk
        assert 1 <= sup[0] <= 3 and all(0 <= j < n for j in sup[1 : 1 + sup[0]])


def test_kernel_off_in_the_environment_runs_the_reference() -> None:
    code = """if True:
        import numpy as np, pytest
        from runtime.brain import RuleBrain
        from runtime.controller import Controller
        from runtime.kernel import KERNEL, kernel_status
        from runtime.patterns import make_pattern
        assert KERNEL is None and "off" in kernel_status(), kernel_status()
        pos = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3], [1.0, 1.0]])
        d = Controller(RuleBrain()).decide(1, pos, make_pattern("circle", 4), 0)
        assert not d.error and d.slot >= 0, d
        with pytest.raises(RuntimeError, match="not available"):
            Controller(RuleBrain(), compiled=True)
        print(repr(d.velocity))
    """
    env = dict(os.environ, PATTERNRL_KERNEL="0")
    run = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    pos = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3], [1.0, 1.0]])
    d = Controller(RuleBrain(), compiled=True).decide(1, pos, make_pattern("circle", 4), 0)
    np.testing.assert_allclose(ast.literal_eval(run.stdout.strip()), d.velocity, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 5, 10, 33, 100])
def test_assign_is_scipys_solver_cold_and_optimal_warm(n: int) -> None:
    """Cold: scipy's assignment, ties included (integer costs); warm from the last slots and
    potentials: an optimal one, scipy's own on untied costs; bad input raises."""
    K, rng = kern(), np.random.default_rng(n)
    rows = np.arange(n)
    for trial in range(60):
        tied = trial % 3 == 0
        cost = rng.integers(0, 4, (n, n)).astype(float) if tied else rng.random((n, n)) * 9
        want = linear_sum_assignment(cost)[1]
        v, got = np.zeros(n), np.empty(n, dtype=np.int64)
        assert K.assign(cost, got, v, False, got) == n
        assert got.tolist() == want.tolist()
        moved = cost + rng.random((n, n)) * (0.0 if tied else 0.05)  # the next step
        warm = np.empty(n, dtype=np.int64)
        assert 0 <= K.assign(moved, got, v, True, warm) <= n
        best = linear_sum_assignment(moved)[1]
        assert moved[rows, warm].sum() <= moved[rows, best].sum() + 1e-9
        if not tied:
            assert warm.tolist() == best.tolist()
    v, out = np.zeros(n), np.empty(n, dtype=np.int64)
    for bad in (np.full((n, n), np.nan), np.zeros((n, n + 1)), np.zeros((n, n), np.float32)):
        with pytest.raises(BAD):
            K.assign(bad, out, v, False, out)
    with pytest.raises(BAD):
        K.assign(np.zeros((n, n)), np.zeros(n, np.int32), v, True, out)
    far = np.full(n, n + 5, dtype=np.int64)  # a previous assignment out of range: solved cold
    assert K.assign(np.eye(n), far, np.zeros(n), True, out) == n
    assert out.tolist() == linear_sum_assignment(np.eye(n))[1].tolist()
