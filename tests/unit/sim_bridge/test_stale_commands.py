"""Late commands in the world: applied while young enough, their age told, their motion guarded."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from runtime.decision.formation import collision_pairs, swept_pair_distance
from runtime.net.session import open_session
from runtime.wire import keys
from runtime.wire.messages import Command, encode_command
from runtime.world_config import DEFAULT_WORLD
from sim_bridge.launch.launch import free_port
from sim_bridge.world.phase_tally import PhaseTally
from sim_bridge.world.physics import PhysicsWorld
from sim_bridge.world.stale_guard import guard_stale
from sim_bridge.world.world_link import WorldLink

W = DEFAULT_WORLD
R = W.radius_m


def new_collisions(pos: np.ndarray, v: np.ndarray) -> list[tuple[int, int]]:
    """Pairs the step's straight motions bring below 2R that were not already below it."""
    d0 = swept_pair_distance(pos, pos)
    return [(i, j) for i, j in collision_pairs(pos, pos + v * W.dt_s, W)
            if d0[i, j] >= W.min_separation_m - 1e-6]


def test_a_stale_command_into_a_fresh_robot_is_stopped_the_fresh_one_kept() -> None:
    # robot 0 decided 2 steps ago to drive right at full speed; robot 1 now stands in its way
    pos = np.array([[1.0, 1.0], [1.0 + 2 * R + 0.05, 1.0], [3.0, 3.0]])
    v = np.array([[1.0, 0.0], [0.0, 0.3], [0.5, 0.0]])
    age = np.array([2, 0, 1])
    assert new_collisions(pos, v) == [(0, 1)]  # without the guard: a collision
    out = guard_stale(pos, v, age, W)
    assert new_collisions(pos, out.v) == []
    assert out.scaled.tolist() == [0]
    assert out.v[1].tolist() == [0.0, 0.3] and out.v[2].tolist() == [0.5, 0.0]
    assert 0.0 <= out.v[0, 0] < 1.0 and out.v[0, 1] == 0.0


def test_the_fresh_robot_gives_way_when_the_stale_one_has_stopped() -> None:
    # a fresh robot drives into a robot held still (no command within the bound)
    pos = np.array([[1.0, 1.0], [1.0 + 2 * R + 0.02, 1.0]])
    v = np.array([[0.0, 0.0], [-1.0, 0.0]])
    out = guard_stale(pos, v, np.array([-1, 0]), W)
    assert new_collisions(pos, v) and new_collisions(pos, out.v) == []
    assert out.scaled.tolist() == [1]


def test_the_guard_leaves_safe_motions_alone() -> None:
    rng = np.random.default_rng(3)
    # a grid 0.4 m apart (2R + two steps at v_max): no pair can close in below 2R
    pos = np.stack(np.meshgrid(np.arange(6), np.arange(6)), -1).reshape(-1, 2) * 0.4 + 1.0
    v = rng.uniform(-0.7, 0.7, size=pos.shape)
    out = guard_stale(pos, v, rng.integers(0, 3, len(pos)), W)
    assert new_collisions(pos, v) == []
    assert out.scaled.tolist() == [] and np.array_equal(out.v, v)


@pytest.mark.parametrize("seed", range(4))
def test_no_mix_of_stale_fresh_and_held_commands_collides_after_the_guard(seed: int) -> None:
    """Crowds in a small box, velocities at random up to v_max, ages at random: without the
    guard many steps collide; with it none does, and the physics agrees."""
    rng = np.random.default_rng(seed)
    collided_without = 0
    for _ in range(60):
        n = 25
        pos = np.empty((n, 2))
        k = 0
        while k < n:  # uniform starts 2R apart in a 2.5 m box
            c = rng.uniform(R, 2.5 - R, 2)
            if k == 0 or np.min(np.linalg.norm(pos[:k] - c, axis=1)) >= 2 * R:
                pos[k] = c
                k += 1
        ang = rng.uniform(0, 2 * np.pi, n)
        v = rng.uniform(0, W.v_max_mps, n)[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)
        v = np.clip(v, (R - pos) / W.dt_s, (2.5 - R - pos) / W.dt_s)  # none into a wall
        age = rng.integers(-1, 4, n)
        v[age < 0] = 0.0
        collided_without += bool(new_collisions(pos, v))
        out = guard_stale(pos, v, age, W, arena_m=2.5)
        assert new_collisions(pos, out.v) == []
        # only robots of colliding pairs were touched, and only ever slowed, same heading
        sp0, sp1 = np.linalg.norm(v, axis=1), np.linalg.norm(out.v, axis=1)
        assert (sp1 <= sp0 + 1e-12).all()
        moved = sp1 > 0
        cos = np.einsum("ij,ij->i", v[moved], out.v[moved]) / (sp0[moved] * sp1[moved])
        assert np.allclose(cos, 1.0)
        phys = PhysicsWorld(2.5, W)
        for rid, (x, y) in enumerate(pos.tolist()):
            phys.add_robot(rid, x, y)
        res = phys.step(out.v)
        tally = PhaseTally()
        m = tally.step(list(range(n)), pos, res.positions, pos, res.new_contacts, [], W)
        assert m.new_collisions == [] and tally.collisions == 0
    assert collided_without >= 30  # the inputs do collide without the guard


@pytest.mark.timeout(60)
def test_world_link_applies_a_late_command_until_it_is_too_old() -> None:
    swarm, port = "unit-stale", free_port()
    world = open_session("peer", connect=[], listen=[f"tcp/127.0.0.1:{port}"])
    robot = open_session("peer", connect=[f"tcp/127.0.0.1:{port}"], listen=[])
    link = WorldLink(world, swarm, lockstep=False, recorder=None,
                     event=lambda kind, **f: None, max_age_steps=2)
    stop = threading.Event()
    pos = np.array([[1.0, 2.0]])

    def wait_until(cond: Any, what: str) -> None:
        deadline = time.monotonic() + 30.0  # delivery is asynchronous: wait, bounded
        while not cond():
            assert time.monotonic() < deadline, what
            time.sleep(0.01)

    try:
        with link:
            token = robot.liveliness().declare_token(keys.alive_key(swarm, 1))
            assert link.roster.wait_for(1, 20.0, stop) == 1
            link.add_robot(1, 0.5, 0.5)
            v, missed, age = link.exchange(0, W.dt_s, [1], pos, 0.02, stop)
            assert missed == [1] and age.tolist() == [-1] and v.tolist() == [[0.0, 0.0]]
            # the answer to step 0 comes after step 0's deadline: late, kept
            robot.put(keys.cmd_key(swarm, 1), encode_command(
                Command(1, 0, 0.25, -0.5, "rule:assign", False, 0.0, 12.0)))
            wait_until(lambda: link.late >= 1, "the late command")
            v, missed, age = link.exchange(1, W.dt_s, [1], pos, 0.02, stop)  # applied, stale
            assert missed == [1] and age.tolist() == [1] and v.tolist() == [[0.25, -0.5]]
            v, missed, age = link.exchange(2, W.dt_s, [1], pos, 0.02, stop)  # not twice
            assert missed == [1] and age.tolist() == [-1] and v.tolist() == [[0.0, 0.0]]
            robot.put(keys.cmd_key(swarm, 1), encode_command(
                Command(1, 1, 0.5, 0.0, "rule:assign", False, 0.0, 12.0)))
            wait_until(lambda: link.late >= 2, "the second late command")
            v, missed, age = link.exchange(4, W.dt_s, [1], pos, 0.02, stop)  # 3 steps: too old
            assert missed == [1] and age.tolist() == [-1] and v.tolist() == [[0.0, 0.0]]
            # a command for an older step than the newest kept does not replace it
            robot.put(keys.cmd_key(swarm, 1), encode_command(
                Command(1, 4, 0.1, 0.0, "rule:assign", False, 0.0, 12.0)))
            robot.put(keys.cmd_key(swarm, 1), encode_command(
                Command(1, 3, 0.9, 0.0, "rule:assign", False, 0.0, 12.0)))
            wait_until(lambda: link.late >= 4, "two late commands")
            v, missed, age = link.exchange(6, W.dt_s, [1], pos, 0.02, stop)
            assert age.tolist() == [2] and v.tolist() == [[0.1, 0.0]]
            token.undeclare()
    finally:
        robot.close()  # type: ignore[no-untyped-call]
        world.close()  # type: ignore[no-untyped-call]


def test_lockstep_applies_no_stale_command_by_default() -> None:
    from sim_bridge.world.sim_world import SimConfig
    assert SimConfig(mode="lockstep").max_age_steps == 0
    assert SimConfig(mode="realtime").max_age_steps >= 1
    assert SimConfig(mode="realtime", max_command_age_steps=0).max_age_steps == 0


def test_a_realtime_world_slows_down_while_its_robots_cannot_keep_up() -> None:
    from sim_bridge.world.sim_world import SimConfig, SimWorld

    world = SimWorld(SimConfig(mode="realtime", robots=4, patterns=["circle"]), None)  # type: ignore[arg-type]
    assert world.period_s == pytest.approx(0.1)
    for _ in range(5):
        world._adapt_rate(0.3)  # some robots held: the rate stays
    assert world.period_s == pytest.approx(0.1)
    periods = []
    for _ in range(60):  # most robots held: slower, down to a quarter of the rate
        world._adapt_rate(1.0)
        periods.append(world.period_s)
    assert periods == sorted(periods) and periods[-1] == pytest.approx(0.4)
    for _ in range(200):  # they caught up: back to the rate
        world._adapt_rate(0.0)
    assert world.period_s == pytest.approx(0.1)
    fixed = SimWorld(SimConfig(mode="realtime", robots=4, patterns=["circle"],
                               min_rate_hz=10.0), None)  # type: ignore[arg-type]
    for _ in range(60):
        fixed._adapt_rate(1.0)
    assert fixed.period_s == pytest.approx(0.1)


def test_a_realtime_schedule_slips_rather_than_squeeze_a_step_and_news_restarts_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On schedule, a step's window is what is left of its period; poses that go out late
    (the machine stalled the world) slip the schedule so the robots keep
    MIN_WINDOW_SHARE of a period; a step that brings news waits up to the first-step
    deadline and the schedule starts again after it. The clock is the test's."""
    from sim_bridge.world import sim_world
    from sim_bridge.world.sim_world import MIN_WINDOW_SHARE, SimConfig, SimWorld

    clock = [100.0]
    monkeypatch.setattr(sim_world.time, "monotonic", lambda: clock[0])
    world = SimWorld(SimConfig(mode="realtime", robots=4, patterns=["circle"],
                               first_step_deadline_ms=5000.0), None)  # type: ignore[arg-type]
    assert world._deadline_s(True) == pytest.approx(5.0)  # news: wait for everyone
    clock[0] += 0.3  # the news step took what it took
    assert world._deadline_s(False) == pytest.approx(0.1)  # the schedule starts again here
    clock[0] += 0.105  # 5 ms of the world's own work after the tick
    assert world._deadline_s(False) == pytest.approx(0.095)  # taken out of the next period
    assert world.slipped_s == 0.0
    clock[0] += 0.095 + 0.04  # a 40 ms stall after the tick
    assert world._deadline_s(False) == pytest.approx(MIN_WINDOW_SHARE * 0.1)
    assert world.slipped_s == pytest.approx(0.04 - (1 - MIN_WINDOW_SHARE) * 0.1)
    clock[0] += MIN_WINDOW_SHARE * 0.1 + 0.002  # back on the slipped schedule
    assert world._deadline_s(False) == pytest.approx(0.098)
    assert world.overruns == 0
