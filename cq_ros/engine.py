"""The offline engine: runs learners in a GridWorld episode after episode, with nothing in between.

`Team` is the loop body shared by the engine and the ROS nodes' tests: it asks each learner what it
needs to see, hands it exactly that, applies the joint action and feeds the outcome back. `run` plays
one (algorithm, run) for a number of episodes and returns its per-episode records; `experiment.py`
spreads runs over the cores and writes result files.

Seeds: the learner of agent i in run r draws from `learner_seed(seed, r, i)`, the world (only used
with delays: slip, start_hold) from `world_seed(seed, r)`: the same seed gives the same run, offline or over ROS.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import astuple, dataclass

import numpy as np

from .gridmap import GridMap
from .learners import LEARNERS, Learner, decode_joint_action
from .settings import Settings
from .world import GridWorld

_NOBODY: dict = {}


def learner_seed(seed: int, run: int, agent: int) -> int:
    return int(np.random.SeedSequence([seed, run, agent]).generate_state(1)[0])


def world_seed(seed: int, run: int) -> int:
    return int(np.random.SeedSequence([seed, run, 2**31]).generate_state(1)[0])


def make_learner(algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int, agent: int) -> Learner:
    """The learner of agent `agent` (0-based) in run `run`; for JSA, agent 0 is the central learner."""
    if algo not in LEARNERS:
        raise ValueError(f"unknown algorithm {algo!r}; algorithms are: {', '.join(LEARNERS)}")
    return LEARNERS[algo](agent, gridmap, settings, learner_seed(seed, run, agent))


def make_learners(algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int) -> list[Learner]:
    """The learners of one run: one per agent, or the single central learner for JSA."""
    agents = [0] if algo in LEARNERS and LEARNERS[algo].central else range(gridmap.n_agents)
    return [make_learner(algo, gridmap, settings, seed, run, i) for i in agents]


@dataclass
class Episode:
    steps: int
    collisions: int
    joint_plays: int
    states: int
    ret: float
    truncated: bool


class Team:
    """Learners acting together in one world: one joint step at a time."""

    def __init__(self, world: GridWorld, learners: list[Learner]):
        self.world = world
        self.learners = learners
        self.central = learners[0].central

    def choose(self) -> list[int | None]:
        """Each acting agent's action (None for agents at their goals)."""
        w = self.world
        if self.central:
            learner = self.learners[0]
            learner.observe(tuple(w.cells))
            joint = decode_joint_action(learner.act(_NOBODY), w.n)
            return [None if d else a for a, d in zip(joint, w.done)]
        cells, actions = w.cells, [None] * w.n
        for i, learner in enumerate(self.learners):
            if not w.done[i]:
                need = learner.observe(cells[i])
                actions[i] = learner.act({j: cells[j] for j in need} if need else _NOBODY)
        return actions

    def learn(self, actions: list[int | None], rewards: list[float]) -> None:
        w = self.world
        if self.central:
            self.learners[0].learn(sum(rewards), tuple(w.cells), w.finished)
            return
        for i, learner in enumerate(self.learners):
            if actions[i] is not None:
                learner.learn(rewards[i], w.cells[i], w.done[i])

    def episode(self) -> Episode:
        w = self.world
        w.reset_joint()
        plays = sum(learner.joint_plays for learner in self.learners)
        collisions, ret = 0, 0.0
        while not w.finished and w.t < w.step_cap:
            actions = self.choose()
            rewards = w.step_joint(actions)
            self.learn(actions, rewards)
            collisions += w.last_collisions
            ret += sum(rewards)
        for learner in self.learners:
            learner.end_episode()
        return Episode(
            steps=w.t,
            collisions=collisions,
            joint_plays=sum(learner.joint_plays for learner in self.learners) - plays,
            states=sum(learner.state_count() for learner in self.learners),
            ret=ret,
            truncated=w.truncated,
        )


def greedy_team(team: Team) -> Team:
    """A copy of the team whose learners act at epsilon 0 (the learnt policy without exploration), frozen
    unless settings.eval_learning (Learner.make_greedy), so the run itself is left exactly as it was."""
    greedy = copy.deepcopy(team)
    for learner in greedy.learners:
        learner.make_greedy()
    return greedy


def greedy_episodes(team: Team, episodes: int) -> np.ndarray:
    """What the learnt policy does without exploration: `episodes` episodes played by greedy_team(team)
    (none played, no copy made: a copy of a warehouse_32 team costs about a second)."""
    if episodes == 0:
        return np.empty((0, 6))
    greedy = greedy_team(team)
    return np.array([astuple(greedy.episode()) for _ in range(episodes)], dtype=float).reshape(episodes, 6)


@dataclass
class RunResult:
    algo: str
    run: int
    episodes: np.ndarray  # (n_episodes, 6): steps, collisions, joint_plays, states, return, truncated
    joint_states: list[tuple[int, int, int, int, float]]  # (agent, cell, peer, peer_cell, confidence)
    greedy: np.ndarray  # (eval_episodes, 6): the same columns for the greedy policy at the end


def run(algo: str, gridmap: GridMap, settings: Settings, seed: int, run_index: int, episodes: int,
        on_episode: Callable[[], None] | None = None) -> RunResult:
    """Play `episodes` episodes of one algorithm with fresh learners; the per-episode records.
    `on_episode` is called after each learning episode (progress)."""
    world = GridWorld(gridmap, settings, seed=world_seed(seed, run_index))
    team = Team(world, make_learners(algo, gridmap, settings, seed, run_index))
    rows = []
    for _ in range(episodes):
        rows.append(astuple(team.episode()))
        if on_episode is not None:
            on_episode()
    table = np.array(rows, dtype=float)
    kept = [(learner.agent, *js) for learner in team.learners for js in learner.joint_states()]
    return RunResult(algo, run_index, table, kept, greedy_episodes(team, settings.eval_episodes))
