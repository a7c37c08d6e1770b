"""Pattern formation as a PettingZoo ``ParallelEnv``: one world, N robots acting at once.

``from trainer.env import parallel_env``; ``env = parallel_env(pattern="heart", n_robots=10)``.
A thin view of a single-env :class:`trainer.training_world.BatchWorld` (E = 1), so the
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
                     Layouts in :mod:`runtime.observation`
Rewards              per agent, paper eq. 6 plus the documented extras
                     (:class:`trainer.reward.RewardConfig`)
Terminations         all agents at once when the pattern is formed (every robot
                     within ``formed_tol`` of its slot)
Truncations          all agents at once at the step limit (default 400)
Infos                per agent: ``collisions`` (this robot, this step),
                     ``formation_error`` (m, the team's), ``formed`` (bool)
Render               none (``render_mode=None``); draw with the CLI or sim_bridge
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
reward               :class:`trainer.reward.RewardConfig` (default documented)
step_limit           steps before truncation (default ``world.step_limit``)
render_mode          only ``None``
==================== ===========================================================

Episodes: after termination or truncation ``agents`` is empty until
``reset()``. Without a seed, ``reset()`` continues the env's own generator, so
the episode sequence of one ``parallel_env(seed=s)`` is reproducible.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray
from pettingzoo import ParallelEnv

from runtime.observation import ObservationSpec
from runtime.world_config import DEFAULT_WORLD, WorldConfig
from trainer.reward import DEFAULT_REWARD, RewardConfig
from trainer.training_world import BatchWorld

ObsDict = dict[str, NDArray[np.float32]]


class PatternFormationEnv(ParallelEnv[str, NDArray[np.float32], NDArray[np.float32]]):  # type: ignore[misc]
    """N disc robots forming a pattern together; see the module docstring."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "pattern_formation_v0",
        "render_modes": [],
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
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} unsupported (only None)")
        self.render_mode = render_mode
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
        self.agents = list(self.possible_agents)
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
        res = self.world.step(a)
        if res.episode is not None:  # the world reset itself: report the episode's end
            obs = res.episode.final_obs[0]
            error_before_reset = float(res.episode.final_error[0])
            self._final_positions = res.episode.final_positions[0]
            self._fresh = True
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
        return obs_d, rewards, term, trunc, infos

    def render(self) -> None:
        return None

    def close(self) -> None:
        return None

    def state(self) -> NDArray[np.float32]:
        """Global state: every robot's position (m), flattened, (2N,); after the
        episode's last step, where it ended."""
        P = self.world.positions[0] if self._final_positions is None else self._final_positions
        out: NDArray[np.float32] = P.reshape(-1).astype(np.float32)
        return out


def parallel_env(
    pattern: Sequence[str | Path] | str | Path = "heart",
    n_robots: int = 10,
    seed: int = 0,
    obs: str = "general",
    **kw: Any,
) -> PatternFormationEnv:
    """The pattern-formation ParallelEnv (arguments in the module docstring)."""
    return PatternFormationEnv(pattern, n_robots, seed, obs, **kw)


__all__ = ["PatternFormationEnv", "parallel_env"]
