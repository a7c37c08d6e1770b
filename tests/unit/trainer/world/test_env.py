"""The PettingZoo ParallelEnv (trainer/world/env.py): conformance and behaviour."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test
from pettingzoo.utils import parallel_to_aec

from runtime.world_config import DEFAULT_WORLD
from trainer.world.env import PatternFormationEnv, parallel_env


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"obs": "paper", "n_robots": 6, "pattern": "circle"},
        {"pattern": ["line", "cross", "random"], "n_robots": 7, "step_limit": 30},
        {"n_robots": 5, "step_limit": 20, "render_mode": "rgb_array"},
    ],
)
def test_pettingzoo_parallel_api(kw: dict[str, object]) -> None:
    parallel_api_test(parallel_env(**kw), num_cycles=500)  # type: ignore[arg-type]


def test_pettingzoo_seed() -> None:
    parallel_seed_test(lambda: parallel_env(seed=3), num_cycles=100)
    parallel_seed_test(lambda: parallel_env(obs="paper", n_robots=5), num_cycles=100)


def test_spaces_and_agents() -> None:
    env = parallel_env(n_robots=4)
    assert env.possible_agents == ["robot_0", "robot_1", "robot_2", "robot_3"]
    obs, infos = env.reset(seed=1)
    assert env.agents == env.possible_agents and set(infos) == set(env.agents)
    space = env.observation_space("robot_0")
    assert space.shape == (36,) and space.dtype == np.float32
    assert all(space.contains(o) for o in obs.values())
    act = env.action_space("robot_2")
    assert act.shape == (2,)
    np.testing.assert_array_equal(act.high, [DEFAULT_WORLD.v_max_mps] * 2)
    assert env.render_mode is None and env.render() is None
    with pytest.raises(ValueError, match="render_mode 'ansi' unsupported"):
        PatternFormationEnv(render_mode="ansi")


def test_reset_seed_reproduces_and_continues() -> None:
    env = parallel_env(seed=0)
    first, _ = env.reset()
    again, _ = parallel_env(seed=0).reset(seed=0)
    for a in first:
        np.testing.assert_array_equal(first[a], again[a])
    second, _ = env.reset()  # no seed: the next episode of the same sequence
    assert not np.allclose(first["robot_0"], second["robot_0"])
    seeded, _ = env.reset(seed=0)
    np.testing.assert_array_equal(seeded["robot_0"], first["robot_0"])


def test_forming_terminates_every_agent() -> None:
    env = parallel_env(pattern="circle", n_robots=6)
    env.reset(seed=2)
    world = env.world
    for _ in range(300):
        g = world.goals[0] - world.positions[0]
        step = g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 0.1)
        actions = {a: step[i] for i, a in enumerate(env.agents)}
        obs, rew, term, trunc, info = env.step(actions)
        if not env.agents:
            break
    assert all(term.values()) and not any(trunc.values())
    assert set(obs) == set(rew) == set(info) == set(env.possible_agents)
    assert all(i["formed"] for i in info.values())
    assert info["robot_0"]["formation_error"] <= DEFAULT_WORLD.formed_tol_m
    with pytest.raises(RuntimeError):
        env.step({})


def test_truncation_and_missing_actions_hold_still() -> None:
    env = parallel_env(step_limit=3)
    env.reset(seed=0)
    start = env.state().copy()
    obs, rew, term, trunc, _ = env.step({})  # nobody acts: everybody holds still
    np.testing.assert_array_equal(env.state(), start)
    for _ in range(2):
        obs, rew, term, trunc, _ = env.step({})
    assert all(np.all(o[4:6] == 0.0) for o in obs.values())  # the last obs: no velocity
    np.testing.assert_array_equal(env.state(), start)  # where the episode ended
    assert all(trunc.values()) and not any(term.values())
    assert env.agents == []
    assert all(r == pytest.approx(env.world.reward_config.step_penalty) for r in rew.values())


# ---------------------------------------------------------------------- render


def _pixel(env, xy) -> np.ndarray:
    """The frame's pixel under the world point ``xy`` (m)."""
    frame = env.render()
    x, y = env._figure.axes[0].transData.transform(xy)
    return frame[frame.shape[0] - 1 - round(y), round(x)]


def test_rgb_array_frames_show_the_robots_and_follow_them() -> None:
    env = parallel_env(pattern="circle", n_robots=6, render_mode="rgb_array")
    env.reset(seed=4)
    first = env.render()
    assert first.shape == (480, 480, 3) and first.dtype == np.uint8
    np.testing.assert_array_equal(env.render(), first)  # the same scene, the same frame
    p0 = env.state().reshape(-1, 2)[0].copy()
    assert not np.all(_pixel(env, p0) == 255)  # a disc where robot_0 stands
    # only robot_0 moves, 0.5 m to the right in 5 steps
    for _ in range(5):
        env.step({"robot_0": np.array([1.0, 0.0], np.float32)})
    p1 = env.state().reshape(-1, 2)[0]
    assert p1[0] == pytest.approx(p0[0] + 0.5) and p1[1] == pytest.approx(p0[1])
    moved = env.render()
    assert moved.shape == first.shape and not np.array_equal(moved, first)
    assert not np.all(_pixel(env, p1) == 255)
    scene = env.scene()
    assert scene.step == 5 and not scene.formed and scene.pattern == "circle"
    np.testing.assert_allclose(scene.slots.mean(axis=0), scene.positions.mean(axis=0))
    env.close()


def test_render_after_the_end_shows_the_formed_pattern() -> None:
    env = parallel_env(pattern="cross", n_robots=5, render_mode="rgb_array")
    env.reset(seed=1)
    world = env.world
    while env.agents:
        g = world.goals[0] - world.positions[0]
        step = g / np.maximum(np.linalg.norm(g, axis=-1, keepdims=True), 0.1)
        env.step({a: step[i] for i, a in enumerate(env.agents)})
    end = env.scene()
    assert end.formed and end.pattern == "cross" and end.step > 0
    np.testing.assert_allclose(end.positions, env.state().reshape(-1, 2))
    assert np.abs(end.goals - end.positions).max() <= DEFAULT_WORLD.formed_tol_m + 1e-9
    frame = env.render()
    env.reset()
    assert env.scene().step == 0 and not np.array_equal(env.render(), frame)


def test_render_through_pettingzoos_aec_wrapper() -> None:
    aec = parallel_to_aec(parallel_env(n_robots=3, render_mode="rgb_array"))
    aec.reset(seed=0)
    assert aec.render().shape == (480, 480, 3)


def test_human_mode_without_a_display_is_a_clear_error(monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(RuntimeError, match=r"needs a display.*rgb_array"):
        parallel_env(render_mode="human")


def test_human_mode_draws_every_step_and_returns_none(monkeypatch) -> None:
    import matplotlib.pyplot as plt

    # the window code with the Agg backend: no window opens, the drawing runs the same
    monkeypatch.setattr("trainer.world.env._check_display", lambda: None)
    monkeypatch.setattr(plt, "pause", lambda interval: None)
    was_interactive = plt.isinteractive()
    try:
        env = parallel_env(n_robots=3, step_limit=2, render_mode="human")
        env.reset(seed=0)
        fig = env._figure
        assert fig is not None and plt.fignum_exists(fig.number)
        title = fig.axes[0].get_title()
        env.step({})
        assert env.render() is None
        assert fig.axes[0].get_title() != title  # redrawn at the step
        env.close()
        assert not plt.fignum_exists(fig.number)
    finally:
        plt.interactive(was_interactive)


def test_state_has_its_space_for_centralised_critics() -> None:
    env = parallel_env(n_robots=4, step_limit=3)
    env.reset(seed=2)
    assert env.state_space is not None
    assert env.state_space.shape == (8,) and env.state_space.dtype == np.float32
    assert env.state_space.contains(env.state())
    while env.agents:  # and where the episode ended
        env.step({a: env.action_space(a).sample() for a in env.agents})
    assert env.state_space.contains(env.state())


def test_the_readmes_pettingzoo_example_runs_as_written() -> None:
    """The README's random-policy example, exactly as the README shows it."""
    from support import ROOT

    readme = (ROOT / "README.md").read_text()
    start = readme.index("```python\nfrom trainer.world.env import parallel_env")
    block = readme[start + len("```python\n"):readme.index("```", start + 10)]
    assert "env.step(actions)" in block and "render_mode" in block
    code = compile(block, "README.md", "exec")
    scope: dict[str, object] = {}
    exec(code, scope)  # the README's own example
    frames = scope["frames"]
    assert isinstance(frames, list) and len(frames) >= 2
    assert frames[0].shape == (480, 480, 3)
    assert not scope["env"].agents  # the episode ended
