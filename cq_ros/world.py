"""The gridworld's joint-step dynamics: simultaneous moves, wall bumps, collisions and absorbing goals.

`GridWorld` has a PettingZoo-style parallel API (`reset()`, `step({agent: action})` returning per-agent
observations, rewards, terminations, truncations and infos) and underneath it `step_joint(actions)`,
the list-based step the offline engine and the world node call. Rules:

- A move through a wall, off the grid or into a '#' cell is a wall bump: the agent stays.
- A collision: two agents would end in one cell that is not a goal of both, or two agents swap cells.
  Colliding agents stay where they were; this can make another agent's move end in a cell whose owner
  now stays, which is a collision too, so collisions are resolved until nothing changes.
- An agent that reaches its goal stays there for good and stops acting. The paper pays the goal reward
  "only when all agents reached their goal"; with tabular learners and an absorbing goal, paying each
  agent its goal reward on its own arrival step is the same learning problem and keeps the per-agent
  learners independent of each other's progress, so that is what we do. JSA learns from the sum.
- The episode ends when every agent is at its goal, or is truncated after `step_cap` steps.

Delays (docs/warehouses.md, "Delays"; deterministic unless a setting asks): real AGVs are held up by a slow pick, a
person in the aisle, a wheel slipping. A delayed AGV's move fails: it stays in its cell, as an AGV parked
there, and gets `reward_step` (it lost a step; it bumped nothing). Anyone moving into its cell collides with
it, and both get the collision penalty, as every collision is paid by both. Two kinds, both drawn from the
world's own `random.Random` (seeded by `cq_ros.engine.world_seed`, so a run over ROS, whose world node owns
the same GridWorld, draws exactly the offline run's delays):
- `start_hold` H: at each reset every agent, in index order, draws a hold of 0..H steps (uniform): its first
  moves of the episode fail that many times (its load is still being put on at the dock).
- `slip` p: at every step, every acting agent not on hold, in index order, draws once: with probability p
  its move fails.
The draws do not depend on the actions, so a step whose action never came (`None` for an acting agent,
the world node's step timeout: it stays like a delayed agent) draws what the offline step draws.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

from .gridmap import GridMap
from .settings import Settings

N_ACTIONS = 4
# Two agents can collide at a step only if at most this many cells apart (Manhattan): each moves one cell. The
# range LoC perceives in and near watches.
COLLISION_REACH = 2


@dataclass(frozen=True)
class Rewards:
    step: float = 0.0
    wall: float = -1.0
    collision: float = -10.0
    goal: float = 10.0

    @classmethod
    def from_settings(cls, s: Settings) -> "Rewards":
        return cls(s.reward_step, s.reward_wall, s.reward_collision, s.reward_goal)

    def of_move(self, cell: int, to: int, goal: int) -> float:
        """What a move from `cell` to `to` earns when it collides with no one: a wall bump (it stays), the
        agent's goal, or a step. A move that fails (a delay) or never came earns `step`."""
        return self.wall if to == cell else self.goal if to == goal else self.step


def rewards_alone(gridmap: GridMap, settings: Settings, agent: int, cell: int, action: int, n: int) -> list[float]:
    """n rewards of `agent`'s move `action` from `cell` with nobody else on the map, as `GridWorld.step_joint`
    pays them: a share `slip` of them delayed (the expected share, first, not drawn), the rest the move's own."""
    r = Rewards.from_settings(settings)
    alone = r.of_move(cell, gridmap.neighbours[cell][action], gridmap.goals[agent])
    delayed = round(n * settings.slip)
    return [r.step if k < delayed else alone for k in range(n)]


def resolve_moves(cells: list[int], targets: list[int], goals: tuple[int, ...]) -> tuple[list[int], set]:
    """Where every agent ends, and the colliding pairs (i, j), i < j.

    `targets` is where each agent would go (its own cell if it stays). Agents in a colliding pair go
    back to their cells, all of a round's at once, and the rules are checked again, until no colliding
    agent is left away from its cell. Going back can only make a new same-cell clash in the cell gone
    back to (a swap needs both agents to move), so each round looks only there: every agent goes back at
    most once and a step costs time linear in the agents (plus the pairs found), where checking every
    pair each round cost the square of the fleet. tests/test_world.py pins it to that pairwise resolver.
    """
    final = list(targets)
    n = len(final)
    edges = {(c, t) for c, t in zip(cells, final) if c != t}
    # Some move's reverse is also a move: a swap. A set operation, not any() over a generator: this runs at
    # every joint step.
    swap = not edges.isdisjoint([(t, c) for c, t in edges])
    if not swap and len(set(final)) == n:
        return final, set()  # the common step: every move ends in its own cell, nobody swaps
    pairs: set[tuple[int, int]] = set()
    at: dict[int, list[int]] = {}  # cell -> the agents whose move ends there, in index order
    for i, c in enumerate(final):
        at.setdefault(c, []).append(i)
    for c, group in at.items():
        if len(group) > 1:
            for k, i in enumerate(group):
                for j in group[k + 1:]:
                    if not goals[i] == goals[j] == c:
                        pairs.add((i, j))
    if swap:
        movers: dict[tuple[int, int], list[int]] = {}
        for i, (c, t) in enumerate(zip(cells, final)):
            if c != t:
                movers.setdefault((c, t), []).append(i)
        for (c, t), forth in movers.items():
            for i in forth:
                for j in movers.get((t, c), ()):
                    if i < j:
                        pairs.add((i, j))
    back = {i for pair in pairs for i in pair if final[i] != cells[i]}
    while back:
        for i in back:
            at[final[i]].remove(i)
            final[i] = cells[i]
            at.setdefault(final[i], []).append(i)
        found = set()
        for r in back:
            c = cells[r]
            for o in at[c]:
                if o != r and not goals[o] == goals[r] == c:
                    found.add((o, r) if o < r else (r, o))
        pairs |= found
        back = {i for pair in found for i in pair if final[i] != cells[i]}
    return final, pairs


def checked_seed(seed):
    """`seed` if it is None or a whole number of at least 0, as every seed of a run is (numpy's SeedSequence, which
    the engine seeds learners with, takes no other); ValueError naming it otherwise (random.Random would take a
    string, a float or a negative number and play another run than the same seed elsewhere)."""
    if seed is None or (isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0):
        return seed
    if hasattr(seed, "__index__") and not isinstance(seed, bool) and seed.__index__() >= 0:  # numpy's integers
        return seed.__index__()
    raise ValueError(f"a seed is a whole number of at least 0, got {seed!r}")


class GridWorld:
    """A GridMap with agents on it, stepped jointly; agents are indexed 0..n-1 (named agv1..agvN)."""

    def __init__(self, gridmap: GridMap, settings: Settings = Settings(), seed: int | None = None):
        self.map = gridmap
        self.rewards = Rewards.from_settings(settings)
        self.step_cap = settings.step_cap
        self.slip = settings.slip
        self.start_hold = settings.start_hold
        self.n = gridmap.n_agents
        self.agents = [f"agv{i + 1}" for i in range(self.n)]
        self._rng = random.Random(checked_seed(seed))
        self.cells: list[int] = []
        self.done: list[bool] = []
        self.t = 0
        self.last_collisions = 0
        self.last_bumps = 0
        self.reset()

    # -- the fast, list-based step -------------------------------------------------------------------

    def reset_joint(self) -> list[int]:
        self.cells = list(self.map.starts)
        self.done = [c == g for c, g in zip(self.cells, self.map.goals)]
        # steps of each agent's start hold left (drawn for every agent, at its goal or not, so the stream
        # does not depend on the map's starts)
        self.hold = [self._rng.randint(0, self.start_hold) for _ in range(self.n)] if self.start_hold else [0] * self.n
        self.arrival = [0 if d else None for d in self.done]  # the step each agent reached its goal
        self.t = 0
        self.last_collisions = 0
        self.last_bumps = 0
        self.last_delays = 0
        self.delayed = [False] * self.n
        return self.cells

    def _delayed(self) -> list[bool]:
        """Whose move fails this step: an agent on its start hold, or one the slip draw stops."""
        done, hold, slip, rng = self.done, self.hold, self.slip, self._rng
        delayed = [False] * self.n
        for i in range(self.n):
            if done[i]:
                continue
            if hold[i]:
                hold[i] -= 1
                delayed[i] = True
            elif slip:
                delayed[i] = rng.random() < slip
        return delayed

    def step_joint(self, actions: list[int | None]) -> list[float]:
        """Apply one joint action (None for agents at their goals, and for an acting agent that stays this
        step without an action); return each agent's reward.

        Afterwards `cells`, `done`, `arrival` (the step each agent reached its goal, None before), `t`,
        `last_collisions` (colliding pairs), `last_bumps`, `delayed` (whose move failed) and `last_delays`
        (how many) describe the new state; an agent already at its goal gets reward 0, one delayed or without an
        action reward_step.
        """
        cells, done, nbr, r, goals = self.cells, self.done, self.map.neighbours, self.rewards, self.map.goals
        targets = list(cells)
        bumped = [False] * self.n
        delayed = self._delayed() if self.slip or self.start_hold else [False] * self.n
        for i, a in enumerate(actions):
            if done[i] or a is None or delayed[i]:
                continue
            c = cells[i]
            targets[i] = t = nbr[c][a]
            bumped[i] = t == c
        final, pairs = resolve_moves(cells, targets, goals)
        collided = [False] * self.n
        for i, j in pairs:
            collided[i] = collided[j] = True
        rewards = [0.0] * self.n
        bumps = 0  # walls hit (a bump that collided counts as a collision)
        for i in range(self.n):
            if done[i]:
                continue
            if collided[i]:
                rewards[i] = r.collision
            elif targets[i] == cells[i] and not bumped[i]:  # delayed, or no action: stayed, a step lost
                rewards[i] = r.step
            else:  # a move nobody was in the way of: it ends at `targets[i]`, its own cell after a bump
                rewards[i] = r.of_move(cells[i], targets[i], goals[i])
                bumps += bumped[i]
                if targets[i] == goals[i]:
                    done[i] = True
                    self.arrival[i] = self.t + 1
        self.cells = final
        self.t += 1
        self.last_collisions = len(pairs)
        self.last_bumps = bumps
        self.delayed = delayed
        self.last_delays = sum(delayed)
        return rewards

    @property
    def finished(self) -> bool:
        return all(self.done)

    @property
    def capped(self) -> bool:
        """`step_cap` steps played: the episode ends here, whoever is not at their goal truncated."""
        return self.t >= self.step_cap

    @property
    def truncated(self) -> bool:
        return self.capped and not self.finished

    @property
    def over(self) -> bool:
        """The episode-over rule, its one home: every agent at its goal, or `step_cap` steps played. The engine,
        the world node's lockstep, the PettingZoo env and the plan executor ask it; the compiled engine
        (cq_ros/compiled/episode.py, numba) keeps a twin that tests/test_compiled.py's byte-identical runs
        hold to it."""
        return self.finished or self.capped

    # -- the PettingZoo-style parallel API -----------------------------------------------------------

    def reset(self, seed: int | None = None) -> tuple[dict, dict]:
        """Observations (each agent's own cell index) and infos, for the agents still acting."""
        if seed is not None:
            self._rng.seed(checked_seed(seed))
        self.reset_joint()
        live = self.live_agents()
        return {a: self.cells[i] for a, i in live}, {a: {} for a, _ in live}

    def live_agents(self) -> list[tuple[str, int]]:
        return [(name, i) for i, name in enumerate(self.agents) if not self.done[i]]

    def step(self, actions: dict[str, int]):
        """One joint step from {agent: action}; returns (obs, rewards, terminations, truncations, infos)
        for the agents that were acting, as PettingZoo's ParallelEnv does."""
        live = self.live_agents()
        for name in actions:
            if name not in self.agents:
                raise KeyError(f"unknown agent {name!r}; agents are {self.agents}")
        missing = [name for name, _ in live if name not in actions]
        if missing:
            raise KeyError(f"no action for acting agent(s) {missing}")
        joint = [actions.get(name) if not self.done[i] else None for i, name in enumerate(self.agents)]
        rewards = self.step_joint(joint)
        truncated = self.truncated
        obs = {a: self.cells[i] for a, i in live}
        rew = {a: rewards[i] for a, i in live}
        term = {a: self.done[i] for a, i in live}
        trunc = {a: truncated and not self.done[i] for a, i in live}
        infos = {a: {"collisions": self.last_collisions} for a, _ in live}
        return obs, rew, term, trunc, infos
