"""Pattern formation as a PettingZoo ``ParallelEnv``: one world, N robots acting at once.

``from trainer.world.env import parallel_env``;
``env = parallel_env(pattern="heart", n_robots=10)``.
A thin view of a single-env :class:`trainer.world.training_world.BatchWorld` (E = 1), so the
dynamics, contacts, reward and termination are exactly those of the training
world; its module docstring documents them.

==================== ===========================================================
Agents               ``robot_0`` ... ``robot_{n-1}``, all acting every step
Action space         ``Box(-v_max, v_max, (2,), float32)``: velocity (m/s); a
                     faster action is scaled down to v_max, a non-finite one is
                     treated as 0; an agent missing from the dict holds still
Observation space    ``Box(-inf, inf, (D,), float32)``; ``obs="general"``:
                     D = 6 + 5k (k = ``k_neighbours``, default 6: D = 36);
                     ``obs="paper"``: D = 6 (n - 1) (n = 10: D = 54).
                     Layouts in :mod:`runtime.decision.observation`
Rewards              per agent, paper eq. 6 plus the documented extras
                     (:class:`trainer.world.reward.RewardConfig`)
Terminations         all agents at once when the pattern is formed (every robot
                     within ``formed_tol`` of its slot)
Truncations          all agents at once at the step limit (default 400)
Infos                per agent: ``collisions`` (this robot, this step),
                     ``formation_error`` (m, the team's), ``formed`` (bool)
Render               ``render_mode="rgb_array"``: ``render()`` returns the scene
                     as an (H, W, 3) uint8 frame (480 x 480): robots as discs of
                     radius R in their colours, a dashed line to each one's
                     slot, the pattern's slots as grey crosses, the arena
                     dotted; ``"human"``: the same in a matplotlib window,
                     redrawn every step (needs a display); ``None``: nothing
State                ``state()``: every robot's position (m), flattened;
                     ``state_space`` ``Box(-inf, inf, (2N,), float32)``
Metadata             ``name`` pattern_formation_v0, ``render_fps`` 10 (1 / dt)
==================== ===========================================================

Arguments of :func:`parallel_env`

==================== ===========================================================
pattern              a built-in name, a pattern file path, ``"random"``, or a
                     sequence of these (one drawn per episode); default "heart"
n_robots             team size N (default 10)
seed                 seed of the first episode when ``reset()`` gets none; a
                     ``reset(seed=s)`` re-seeds (same s, same episodes)
obs                  ``"general"`` (default) or ``"paper"``
k_neighbours         neighbours in the general observation (default 6)
world                :class:`runtime.world_config.WorldConfig` (default the project's)
reward               :class:`trainer.world.reward.RewardConfig` (default documented)
step_limit           steps before truncation (default ``world.step_limit``)
render_mode          ``None`` (default), ``"rgb_array"`` or ``"human"``
==================== ===========================================================

Example: a random policy (any MARL library that speaks PettingZoo's parallel API
takes ``env`` as it is; ``pettingzoo.utils.parallel_to_aec(env)`` gives the AEC
form)::

    env = parallel_env(pattern="circle", n_robots=6, seed=0, render_mode="rgb_array")
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
    frame = env.render()  # (480, 480, 3) uint8: where the episode ended

Episodes: after termination or truncation ``agents`` is empty until
``reset()``. Without a seed, ``reset()`` continues the env's own generator, so
the episode sequence of one ``parallel_env(seed=s)`` is reproducible.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from pettingzoo import ParallelEnv

from runtime.decision.formation import assign_slots_batch
from runtime.decision.observation import ObservationSpec
from runtime.decision.patterns import pattern_label
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from trainer.world.reward import DEFAULT_REWARD, RewardConfig
from trainer.world.training_world import BatchWorld

ObsDict = dict[str, NDArray[np.float32]]
RENDER_MODES = ("rgb_array", "human")
FRAME_PX = 480
"""Side of a rendered frame in pixels."""


class Scene(NamedTuple):
    """What a frame shows. Arrays in metres: ``positions`` and ``goals`` (N, 2), each
    robot and its slot; ``slots`` (N, 2) the pattern placed on the team's centroid."""

    positions: NDArray[np.float64]
    goals: NDArray[np.float64]
    slots: NDArray[np.float64]
    pattern: str
    step: int
    formation_error_m: float
    formed: bool


class PatternFormationEnv(ParallelEnv[str, NDArray[np.float32], NDArray[np.float32]]):  # type: ignore[misc]
    """N disc robots forming a pattern together; see the module docstring."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "pattern_formation_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": round(1.0 / DEFAULT_WORLD.dt_s),
        "is_parallelizable": True,
    }

    def __init__(
        self,
        pattern: Sequence[str | Path] | str | Path = "heart",
        n_robots: int = 10,
        seed: int = 0,
        obs: str = "general",
        *,
        k_neighbours: int = 6,
        world: WorldConfig = DEFAULT_WORLD,
        reward: RewardConfig = DEFAULT_REWARD,
        step_limit: int | None = None,
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(
                f"render_mode {render_mode!r} unsupported (None, {', '.join(RENDER_MODES)})"
            )
        if render_mode == "human":
            _check_display()
        self.render_mode = render_mode
        self._figure: Any = None  # the figure render() draws into, made on first use
        self._ended: Scene | None = None  # the last scene of an ended episode
        spec = (
            ObservationSpec("paper", n_robots=n_robots)
            if obs == "paper"
            else ObservationSpec(obs, k_neighbours=k_neighbours)
        )
        patterns = (str(pattern),) if isinstance(pattern, str | Path) else tuple(pattern)
        self.world = BatchWorld(
            1,
            n_robots,
            patterns,
            spec,
            world=world,
            reward=reward,
            seed=seed,
            step_limit=step_limit,
        )
        self.possible_agents: list[str] = [f"robot_{i}" for i in range(n_robots)]
        self.agents: list[str] = []
        v = np.float32(world.v_max_mps)
        self._obs_spaces = {
            a: spaces.Box(-np.inf, np.inf, (self.world.obs_dim,), np.float32)
            for a in self.possible_agents
        }
        self._act_spaces = {a: spaces.Box(-v, v, (2,), np.float32) for a in self.possible_agents}
        self.state_space = spaces.Box(-np.inf, np.inf, (2 * n_robots,), np.float32)
        self._fresh = True  # the world holds a new episode nobody has seen yet
        self._final_positions: NDArray[np.float64] | None = None  # of an ended episode

    # The same space object on every call (PettingZoo seeds spaces through them).
    def observation_space(self, agent: str) -> spaces.Box:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self._act_spaces[agent]

    def _obs_dict(self, obs: NDArray[np.float32]) -> ObsDict:
        return {a: obs[i] for i, a in enumerate(self.possible_agents)}

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsDict, dict[str, dict[str, Any]]]:
        if seed is not None:
            obs = self.world.reset(seed=seed)[0]
        elif self._fresh:
            obs = self.world.observe()[0]
        else:
            obs = self.world.reset()[0]
        self._fresh = False
        self._final_positions = None
        self._ended = None
        self.agents = list(self.possible_agents)
        if self.render_mode == "human":
            self.render()
        return self._obs_dict(obs), {a: {} for a in self.agents}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        ObsDict,
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        if not self.agents:
            raise RuntimeError("the episode is over: call reset()")
        n = len(self.possible_agents)
        a = np.zeros((1, n, 2), dtype=np.float64)
        for i, agent in enumerate(self.possible_agents):
            if agent in actions and actions[agent] is not None:
                a[0, i] = np.asarray(actions[agent], dtype=np.float64).reshape(2)
        error_before_reset = None
        pattern = self.world.pattern[0].copy() if self.render_mode else None
        res = self.world.step(a)
        if res.episode is not None:  # the world reset itself: report the episode's end
            obs = res.episode.final_obs[0]
            error_before_reset = float(res.episode.final_error[0])
            self._final_positions = res.episode.final_positions[0]
            self._fresh = True
            if pattern is not None:
                self._ended = self._ended_scene(res.episode, pattern)
        else:
            obs = res.obs[0]
        error = error_before_reset if error_before_reset is not None else float(self.world.error[0])
        hits = self.world.last_robot_collisions[0]
        agents = self.agents
        rewards = {ag: float(res.reward[0, i]) for i, ag in enumerate(agents)}
        formed = bool(res.formed[0])
        term = dict.fromkeys(agents, formed)
        trunc = dict.fromkeys(agents, bool(res.truncated[0]))
        infos = {
            ag: {"collisions": int(hits[i]), "formation_error": error, "formed": formed}
            for i, ag in enumerate(agents)
        }
        obs_d = self._obs_dict(obs)
        if res.done[0]:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs_d, rewards, term, trunc, infos

    # ------------------------------------------------------------------ render

    def scene(self) -> Scene:
        """What the world looks like now; after the episode's last step, where it ended."""
        if self._ended is not None:
            return self._ended
        w = self.world
        P = w.positions[0]
        return Scene(
            positions=P.copy(),
            goals=w.goals[0].copy(),
            slots=w.pattern[0] + P.mean(axis=0),
            pattern=self._pattern_name(int(w.pattern_ids[0])),
            step=int(w.steps[0]),
            formation_error_m=float(w.error[0]),
            formed=False,
        )

    def _pattern_name(self, k: int) -> str:
        return pattern_label(self.world.patterns[k])

    def _ended_scene(self, ep: Any, pattern: NDArray[np.float64]) -> Scene:
        P = np.asarray(ep.final_positions[0], dtype=np.float64)
        slots = pattern + P.mean(axis=0)
        order = assign_slots_batch(P[None], pattern[None])[0]
        return Scene(P.copy(), slots[order], slots, self._pattern_name(int(ep.pattern_ids[0])),
                     int(ep.steps[0]), float(ep.final_error[0]), bool(ep.formed[0]))

    def render(self) -> NDArray[np.uint8] | None:
        """``rgb_array``: the scene as an (H, W, 3) uint8 frame; ``human``: draw it in a
        window (returns None); ``None``: nothing."""
        if self.render_mode is None:
            return None
        if self._figure is None:
            self._figure = _new_figure(self.render_mode == "human")
        fig = self._figure
        ax = fig.axes[0]
        ax.clear()
        draw_scene(ax, self.scene(), self.world.world)
        if self.render_mode == "human":
            import matplotlib.pyplot as plt

            fig.canvas.draw_idle()
            plt.pause(self.world.world.dt_s)  # real time
            return None
        fig.canvas.draw()
        frame: NDArray[np.uint8] = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        return frame

    def close(self) -> None:
        if self._figure is not None and self.render_mode == "human":
            import matplotlib.pyplot as plt

            plt.close(self._figure)
        self._figure = None

    def state(self) -> NDArray[np.float32]:
        """Global state: every robot's position (m), flattened, (2N,); after the
        episode's last step, where it ended."""
        P = self.world.positions[0] if self._final_positions is None else self._final_positions
        out: NDArray[np.float32] = P.reshape(-1).astype(np.float32)
        return out


# ---------------------------------------------------------------------- drawing


def _check_display() -> None:
    """Raise a one-line RuntimeError when no window can be opened."""
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise RuntimeError(
            "render_mode='human' needs a display (DISPLAY and WAYLAND_DISPLAY are unset); "
            "use render_mode='rgb_array' and save the frames"
        )
    import matplotlib.pyplot as plt

    backend = plt.get_backend().lower()
    if backend in ("agg", "pdf", "ps", "svg", "pgf", "cairo", "template"):
        raise RuntimeError(
            f"render_mode='human' needs an interactive matplotlib backend, not {backend!r} "
            "(set MPLBACKEND, e.g. TkAgg or QtAgg); or use render_mode='rgb_array'"
        )


def _new_figure(window: bool) -> Any:
    """A square figure of FRAME_PX pixels: a pyplot window, or an off-screen Agg canvas
    (which leaves pyplot's backend alone)."""
    size_in, dpi = FRAME_PX / 100, 100
    if window:
        import matplotlib.pyplot as plt

        plt.ion()
        fig = plt.figure(figsize=(size_in, size_in), dpi=dpi)
    else:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(size_in, size_in), dpi=dpi)
        FigureCanvasAgg(fig)
    fig.add_subplot(1, 1, 1)
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.1, top=0.93)
    return fig


def draw_scene(ax: Any, scene: Scene, world: WorldConfig = DEFAULT_WORLD) -> None:
    """Draw ``scene`` on a matplotlib axes, in the style of the trajectory figures
    (``patternrl replay --plot``): discs of radius R in tab10 colours, slots as grey
    crosses, the arena's start square dotted. The view is the arena (and a margin),
    widened to keep every robot and slot in sight."""
    import matplotlib
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Circle, Rectangle

    cmap = matplotlib.colormaps["tab10"]
    r, side = world.radius_m, world.arena_m
    ax.add_patch(Rectangle((0.0, 0.0), side, side, fill=False, ls=":", lw=0.8, ec="0.6"))
    if len(scene.slots):
        ax.plot(scene.slots[:, 0], scene.slots[:, 1], "x", ms=4, mew=1.0, color="0.35", zorder=3)
    colours = [cmap(i % 10) for i in range(len(scene.positions))]
    links = np.stack([scene.positions, scene.goals], axis=1)
    ax.add_collection(LineCollection(list(links), colors=colours, linewidths=0.6,
                                     linestyles="--", alpha=0.5, zorder=2))
    for p, c in zip(scene.positions, colours, strict=True):
        ax.add_patch(Circle((float(p[0]), float(p[1])), r, facecolor=(*c[:3], 0.35),
                            edgecolor=c, linewidth=1.2, zorder=4))
    pts = np.vstack([scene.positions, scene.slots, [[0.0, 0.0], [side, side]]])
    lo, hi = pts.min(axis=0) - 4 * r, pts.max(axis=0) + 4 * r
    mid, half = (lo + hi) / 2, float((hi - lo).max()) / 2
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_aspect("equal")
    state = "formed" if scene.formed else f"error {scene.formation_error_m:.2f} m"
    ax.set_title(f"{scene.pattern}: step {scene.step}, {state}", fontsize=10)
    ax.tick_params(labelsize=7)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.grid(alpha=0.15)


def parallel_env(
    pattern: Sequence[str | Path] | str | Path = "heart",
    n_robots: int = 10,
    seed: int = 0,
    obs: str = "general",
    **kw: Any,
) -> PatternFormationEnv:
    """The pattern-formation ParallelEnv (arguments in the module docstring)."""
    return PatternFormationEnv(pattern, n_robots, seed, obs, **kw)


__all__ = ["PatternFormationEnv", "Scene", "draw_scene", "parallel_env"]
