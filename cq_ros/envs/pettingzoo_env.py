"""The gridworld as a PettingZoo `ParallelEnv`, so any PettingZoo-based MARL library can train on our maps.

    env = GridWorldEnv("tunnel_to_goal_3")            # observations: each agent's own cell
    env = GridWorldEnv("isr", observation="joint")    # or every agent's cell
    obs, infos = env.reset(seed=0)
    obs, rewards, terminations, truncations, infos = env.step({a: env.action_space(a).sample() for a in env.agents})

What an agent sees: its own cell (`observation="local"`) or every agent's (`"joint"`), as `encoding` says:
- "index" (the default): a cell index, an `int64` array of shape () in `Discrete(n_cells)` (a 0-d array:
  PettingZoo wants arrays), or every agent's, an `int64` array in `MultiDiscrete([n_cells] * n_agents)`;
- "onehot": a `float32` `Box(0, 1)` of shape (n_cells,), 1 at the cell, or (n_agents, n_cells) for "joint";
- "coords": a `float32` `Box(0, 1)` of shape (2,), the cell's (row, col) divided by (height - 1, width - 1), or
  (n_agents, 2) for "joint".
The `Box` forms are what wrapper chains built for images and vectors take (SuperSuit's `dtype_v0`,
`flatten_v0`, `black_death_v3`, its vector envs). `state()` is every agent's cell index, in `state_space`
(`MultiDiscrete`), for a centralised critic. Cells are numbered row by row over the map's free cells
(`env.world.map.cells[i]` is cell i's (row, col)).

Actions, `Discrete(4)`: 0 NORTH, 1 EAST, 2 SOUTH, 3 WEST (`cq_ros.gridmap.ACTIONS`); a move into a wall
leaves the agent where it is. By default an agent at its goal leaves `env.agents` (terminated); with
`agents_stay=True` it stays in `env.agents` until the episode ends, its actions ignored (a no-op, reward 0,
`infos[agent]["at_goal"]` True), and every agent is terminated (at its goal) or truncated when the episode
ends: the fixed agent list a vector env needs. The episode is truncated after the settings' `step_cap` steps;
`step()` after it ended (or before `reset()`) raises a RuntimeError saying so.

`render_mode=None` draws nothing (`render()` returns None); "ansi" returns the map as text, each agent drawn
where it is as the map files draw it (1-9, then a-z, '*' past 35; a legend line names them from the 10th
agent on); "rgb_array" returns an (H, W, 3) uint8 picture, the one `cq-ros render` animates
(`cq_ros.lab.render.Picture`).

The dynamics are cq_ros.world.GridWorld's; this class only adds spaces and PettingZoo's bookkeeping.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from ..gridmap import GridMap, agent_glyph, lattice, load_map
from ..settings import Settings, run_settings
from ..world import N_ACTIONS, GridWorld

ENCODINGS = ("index", "onehot", "coords")


class GridWorldEnv(ParallelEnv):
    metadata = {"name": "cq_ros_gridworld_v0", "render_modes": ["ansi", "rgb_array"]}

    def __init__(self, gridmap: GridMap | str, settings: Settings | None = None, observation: str = "local",
                 render_mode: str | None = None, encoding: str = "index", agents_stay: bool = False):
        """`settings`: a Settings, or None for the map's (`cq_ros.settings.run_settings`), or overrides of those
        (["alpha=0.2"] or {"alpha": 0.2}), checked as `--set` is."""
        if observation not in ("local", "joint"):
            raise ValueError(f"observation must be 'local' or 'joint', got {observation!r}")
        if encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {ENCODINGS}, got {encoding!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        if isinstance(gridmap, (str, os.PathLike)):
            gridmap = load_map(gridmap)
        if not isinstance(gridmap, GridMap):
            raise TypeError(f"GridWorldEnv takes a map (a name, a path or a GridMap), got {gridmap!r}")
        if not isinstance(settings, Settings):  # None, or overrides: ["alpha=0.2"] or {"alpha": 0.2}, checked
            settings = run_settings(gridmap, settings or ())
        self.world = GridWorld(gridmap, settings)
        self.observation = observation
        self.encoding = encoding
        self.agents_stay = agents_stay
        self.render_mode = render_mode
        self.possible_agents = list(self.world.agents)
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        self.state_space = spaces.MultiDiscrete([self.world.map.n_cells] * self.world.n)
        self._ended = "reset() was never called"
        self._episode = -1
        self._picture = None
        m = gridmap
        # each cell's value in the "coords" form: its (row, col) over the map's last row and column
        self._coords = (np.array(m.cells) / np.maximum([m.height - 1, m.width - 1], 1)).astype(np.float32)

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Space:
        n_cells, n = self.world.map.n_cells, self.world.n
        if self.encoding == "index":
            return self.state_space if self.observation == "joint" else spaces.Discrete(n_cells)
        shape = (n_cells,) if self.encoding == "onehot" else (2,)
        return spaces.Box(0.0, 1.0, shape if self.observation == "local" else (n, *shape), dtype=np.float32)

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Space:
        return spaces.Discrete(N_ACTIONS)

    def state(self) -> np.ndarray:
        """Every agent's cell, those at their goal included: a value of `state_space`."""
        return np.array(self.world.cells, dtype=np.int64)

    def _encode(self, cells: list[int]) -> np.ndarray:
        if self.encoding == "index":
            return np.array(cells[0] if self.observation == "local" else cells, dtype=np.int64)
        if self.encoding == "coords":
            return self._coords[cells[0] if self.observation == "local" else cells]
        onehot = np.zeros((len(cells), self.world.map.n_cells), dtype=np.float32)
        onehot[np.arange(len(cells)), cells] = 1.0
        return onehot[0] if self.observation == "local" else onehot

    def _observe(self, names: list[str]) -> dict:
        cells = self.world.cells
        if self.observation == "joint":
            joint = self._encode(cells)
            return {a: joint.copy() for a in names}
        return {a: self._encode([cells[self._index[a]]]) for a in names}

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, infos = self.world.reset(seed=seed)
        self._episode += 1
        self._ended = None
        self.agents = list(self.possible_agents if self.agents_stay else obs)
        if self.agents_stay:
            infos = {a: {"at_goal": self.world.done[i]} for i, a in enumerate(self.possible_agents)}
        return self._observe(self.agents), infos

    def step(self, actions: dict):
        if not isinstance(actions, Mapping):
            raise TypeError(f"step() takes a dict of actions {{agent: action}}, got {actions!r}")
        if self._ended is not None:
            raise RuntimeError(f"step() after the episode ended ({self._ended}): call reset() first")
        for agent, action in actions.items():
            if not self.action_space(agent).contains(action):
                raise ValueError(f"action {action!r} of {agent} is not in {self.action_space(agent)}")
        if not self.agents_stay:
            obs, rewards, terminations, truncations, infos = self.world.step({a: int(x) for a, x in actions.items()})
            self.agents = [a for a in obs if not (terminations[a] or truncations[a])]
            self._end_if(not self.agents)
            return self._observe(list(obs)), rewards, terminations, truncations, infos
        world, names = self.world, self.possible_agents
        # an agent at its goal stays with a no-op: its action is dropped, as GridWorld drops a parked one's
        _, acting_rewards, *_ = world.step({a: int(x) for a, x in actions.items()
                                            if a not in self._index or not world.done[self._index[a]]})
        over = world.over
        rewards = {a: acting_rewards.get(a, 0.0) for a in names}
        terminations = {a: over and world.done[i] for i, a in enumerate(names)}
        truncations = {a: over and not world.done[i] for i, a in enumerate(names)}
        infos = {a: {"collisions": world.last_collisions, "at_goal": world.done[i]} for i, a in enumerate(names)}
        obs = self._observe(names)
        self.agents = [] if over else list(names)
        self._end_if(over)
        return obs, rewards, terminations, truncations, infos

    def _end_if(self, over: bool) -> None:
        if over:
            w = self.world
            self._ended = ("every agent reached its goal" if w.finished
                           else f"truncated after step_cap={w.step_cap} steps")

    def render(self):
        if self.render_mode is None:
            return None
        if self.render_mode == "rgb_array":
            return self._rgb()
        m, n = self.world.map, self.world.n
        marks = {start: "." for start in m.starts}  # the drawing's starts would read as agents still there
        marks.update({cell: agent_glyph(i) for i, cell in enumerate(self.world.cells)})
        text = m.draw(marks)
        if n > 9:
            last = min(n, 35)
            named = ["1-9 agv1-agv9, " + ("a agv10" if last == 10 else f"a-{agent_glyph(last - 1)} agv10-agv{last}")]
            named += [f"* agv{i + 1} at {m.cells[c]}" for i, c in enumerate(self.world.cells) if i >= 35]
            text += "\nagents: " + "; ".join(named)
        return text

    def _rgb(self) -> np.ndarray:
        # the lab's renderer, imported only here: the env itself runs on the science alone
        from ..lab.render import Frame, Picture

        m = self.world.map
        if self._picture is None:
            self._picture = Picture(lattice(m), tuple(m.cells[g] for g in m.goals), title=m.name)
        self._picture.show(Frame(max(self._episode, 0), self.world.t, tuple(m.cells[c] for c in self.world.cells)))
        return self._picture.rgb()
