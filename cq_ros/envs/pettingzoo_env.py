"""The gridworld as a PettingZoo `ParallelEnv`, so any PettingZoo-based MARL library can train on our maps.

    env = GridWorldEnv("tunnel_to_goal_3")            # observations: each agent's own cell
    env = GridWorldEnv("isr", observation="joint")    # or every agent's cell
    obs, infos = env.reset(seed=0)
    obs, rewards, terminations, truncations, infos = env.step({a: env.action_space(a).sample() for a in env.agents})

Observations are numpy values of the declared spaces: a cell index (an `int64` array of shape (), in
`Discrete(n_cells)`) for "local" (a 0-d array: PettingZoo wants arrays), every agent's cell (an `int64` array, in
`MultiDiscrete([n_cells] * n_agents)`) for "joint". `state()` is the joint cells too, in `state_space`, for a
centralised critic. Cells are numbered row by row over the map's free cells (`env.world.map.cells[i]` is cell i's
(row, col)).

Actions, `Discrete(4)`: 0 NORTH, 1 EAST, 2 SOUTH, 3 WEST (`cq_ros.gridmap.ACTIONS`); a move into a wall
leaves the agent where it is. An agent at its goal leaves `env.agents`; the episode is truncated after the
settings' `step_cap` steps.

`render_mode=None` draws nothing (`render()` returns None); "ansi" returns the map as text, each agent drawn
as its number.

The dynamics are cq_ros.world.GridWorld's; this class only adds spaces and PettingZoo's bookkeeping.
"""

from __future__ import annotations

import functools

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from ..gridmap import GridMap, load_map
from ..settings import Settings, run_settings
from ..world import N_ACTIONS, GridWorld


class GridWorldEnv(ParallelEnv):
    metadata = {"name": "cq_ros_gridworld_v0", "render_modes": ["ansi"]}

    def __init__(self, gridmap: GridMap | str, settings: Settings | None = None, observation: str = "local",
                 render_mode: str | None = None):
        """Without `settings`, the map's (`cq_ros.settings.run_settings`)."""
        if observation not in ("local", "joint"):
            raise ValueError(f"observation must be 'local' or 'joint', got {observation!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        gridmap = load_map(gridmap) if isinstance(gridmap, str) else gridmap
        self.world = GridWorld(gridmap, run_settings(gridmap) if settings is None else settings)
        self.observation = observation
        self.render_mode = render_mode
        self.possible_agents = list(self.world.agents)
        self.agents: list[str] = []
        self.state_space = spaces.MultiDiscrete([self.world.map.n_cells] * self.world.n)

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Space:
        if self.observation == "joint":
            return self.state_space
        return spaces.Discrete(self.world.map.n_cells)

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Space:
        return spaces.Discrete(N_ACTIONS)

    def state(self) -> np.ndarray:
        """Every agent's cell, those at their goal included: a value of `state_space`."""
        return np.array(self.world.cells, dtype=np.int64)

    def _observe(self, own: dict) -> dict:
        if self.observation == "local":
            return {a: np.array(cell, dtype=np.int64) for a, cell in own.items()}
        return {a: self.state() for a in own}

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, infos = self.world.reset(seed=seed)
        self.agents = list(obs)
        return self._observe(obs), infos

    def step(self, actions: dict):
        for agent, action in actions.items():
            if not self.action_space(agent).contains(action):
                raise ValueError(f"action {action!r} of {agent} is not in {self.action_space(agent)}")
        obs, rewards, terminations, truncations, infos = self.world.step({a: int(x) for a, x in actions.items()})
        self.agents = [a for a in obs if not (terminations[a] or truncations[a])]
        return self._observe(obs), rewards, terminations, truncations, infos

    def render(self) -> str | None:
        if self.render_mode is None:
            return None
        marks = {cell: str(i + 1) for i, cell in enumerate(self.world.cells)}
        return self.world.map.draw(marks)
