"""The offline engine: runs learners in a GridWorld episode after episode, with nothing in between.

`Team` is the loop body shared by the engine and the ROS nodes' tests: it asks each learner what it
needs to see, hands it exactly that, applies the joint action and feeds the outcome back. `run` plays
one (algorithm, run) for a number of episodes and returns its per-episode records (cq_ros.episode: their
columns); the lab (cq_ros.lab) spreads runs over the cores and writes result files.

Seeds: the learner of agent i in run r draws from `learner_seed(seed, r, i)`, the world (only used
with delays: slip, start_hold) from `world_seed(seed, r)`: the same seed gives the same run, offline or over ROS.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import episode as record
from .episode import Episode
from .gridmap import GridMap
from .learners import LEARNERS, Learner, algorithm, decode_joint_action
from .settings import Settings
from .world import GridWorld

_NOBODY: dict = {}


def learner_seed(seed: int, run: int, agent: int) -> int:
    return int(np.random.SeedSequence([seed, run, agent]).generate_state(1)[0])


def world_seed(seed: int, run: int) -> int:
    return int(np.random.SeedSequence([seed, run, 2**31]).generate_state(1)[0])


def make_learner(algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int, agent: int) -> Learner:
    """The learner of agent `agent` (0-based) in run `run`; for JSA, agent 0 is the central learner."""
    return algorithm(algo).learner(agent, gridmap, settings, learner_seed(seed, run, agent))


def make_learners(algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int) -> list[Learner]:
    """The learners of one run: one per agent, or the single central learner for JSA."""
    agents = [0] if algo in LEARNERS and LEARNERS[algo].central else range(gridmap.n_agents)
    return [make_learner(algo, gridmap, settings, seed, run, i) for i in agents]


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
        return record.table(())
    greedy = greedy_team(team)
    return record.table(greedy.episode() for _ in range(episodes))


@dataclass
class RunResult:
    algo: str
    run: int
    episodes: np.ndarray  # one element per episode, cq_ros.episode's named columns (episodes["collisions"])
    joint_states: list[tuple[int, int, int, int, float]]  # (agent, cell, peer, peer_cell, confidence)
    greedy: np.ndarray  # the same for each greedy episode played at the end


def run(algo: str, gridmap: GridMap, settings: Settings, seed: int, run_index: int, episodes: int,
        on_episode: Callable[[], None] | None = None) -> RunResult:
    """Play `episodes` episodes of one algorithm with fresh learners; the per-episode records.
    `on_episode` is called after each learning episode (progress)."""
    world = GridWorld(gridmap, settings, seed=world_seed(seed, run_index))
    team = Team(world, make_learners(algo, gridmap, settings, seed, run_index))
    rows = []
    for _ in range(episodes):
        rows.append(team.episode())
        if on_episode is not None:
            on_episode()
    table = record.table(rows)
    kept = [(learner.agent, *js) for learner in team.learners for js in learner.joint_states()]
    return RunResult(algo, run_index, table, kept, greedy_episodes(team, settings.eval_episodes))
