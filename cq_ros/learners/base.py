"""What every learner offers the engine and the agent node, and the two rules they all share:
epsilon-greedy action selection and the Q-learning update (the paper's Equation 3).

A step, as `cq_ros.engine.step_outcome` and `step_act` drive it (the engine's Team and the agent node's drivers
call those two, so this order is written once):

    peers = learner.observe(cell)           # my cell; which peers must I see to choose? (ids, 0-based)
    action = learner.act({j: cell_j ...})   # those peers' cells at this step; my action
    learner.learn(reward, next_cell, done)  # the outcome of that action
    ...
    learner.end_episode()

Splitting "what do I need to see" from "act" is what lets an agent node subscribe to a peer's position
only when its learner asks for it. Every random choice comes from the learner's own `random.Random`.
"""

from __future__ import annotations

import random
from typing import Hashable, Mapping

from ..gridmap import GridMap
from ..settings import Settings

N_MOVES = 4  # NORTH, EAST, SOUTH, WEST


def greedy(row: list[float], rng: random.Random) -> int:
    """The index of the largest value, ties broken at random."""
    best = max(row)
    if row.count(best) == 1:
        return row.index(best)
    return rng.choice([a for a, q in enumerate(row) if q == best])


def epsilon_greedy(row: list[float], epsilon: float, rng: random.Random) -> int:
    if rng.random() < epsilon:
        return int(rng.random() * len(row))
    return greedy(row, rng)


def q_update(row: list[float], action: int, target: float, alpha: float) -> None:
    """Q(s, a) <- (1 - alpha) Q(s, a) + alpha * target."""
    row[action] += alpha * (target - row[action])


class Learner:
    """One agent's learner (or, for JSA, the whole team's). Subclasses set `name` and the four steps."""

    name = "base"
    central = False  # True: one learner moves every agent (its cell is the tuple of all cells)
    joint_state = False  # True: every state is a joint state (no local table; sees every peer every step)
    learning = True  # False: frozen (a greedy copy under eval_learning=0): it acts, and nothing it keeps changes

    def __init__(self, agent: int, gridmap: GridMap, settings: Settings, seed: int):
        self.agent = agent
        self.map = gridmap
        n_agents = self.n_agents = gridmap.n_agents
        self.n_cells = gridmap.n_cells
        self.settings = settings
        self.alpha = settings.alpha
        self.gamma = settings.gamma
        self.epsilon = settings.epsilon
        self.rng = random.Random(seed)
        self.peers = tuple(j for j in range(n_agents) if j != agent)
        self.joint_plays = 0  # times this learner acted on information about its peers
        self.heard = 0  # peer positions its decisions took in (the communication cost)
        self.episodes_played = 0

    def observe(self, cell: Hashable) -> tuple[int, ...]:
        raise NotImplementedError

    def act(self, peer_cells: Mapping[int, int]) -> int:
        raise NotImplementedError

    def learn(self, reward: float, next_cell: Hashable, done: bool) -> None:
        raise NotImplementedError

    def end_episode(self) -> None:
        """Forget what only made sense inside the episode (subclasses add theirs) and lower epsilon on its
        schedule (settings.epsilon_decay_episodes). Epsilon never rises: a greedy copy stays at 0."""
        self.episodes_played += 1
        decay = self.settings.epsilon_decay_episodes
        if decay:
            self.epsilon = min(self.epsilon, self.settings.epsilon * max(0.0, 1.0 - self.episodes_played / decay))

    def make_greedy(self, learning: bool | None = None) -> None:
        """Make this learner (a copy: the trained one is left as it is) the greedy evaluator: epsilon 0, and
        frozen unless `learning` (None: settings.eval_learning). The engine and the agent driver both switch
        through here, so their greedy episodes stay the same."""
        self.epsilon = 0.0
        self.learning = bool(self.settings.eval_learning if learning is None else learning)

    def state_count(self) -> int:
        """The size of the state space this learner conditions on now (local plus joint)."""
        raise NotImplementedError

    def joint_states(self) -> list[tuple[int, int, int, float]]:
        """(own cell, peer, peer cell, confidence) of every joint state kept (CQ only)."""
        return []
