"""The offline engine: runs learners in a GridWorld episode after episode, with nothing in between.

One learner's step is `step_outcome` (learn from the outcome of its last action, then end the episode or
observe and name the peers it must see) and `step_act` (act on those peers' cells), with one adapter for the
central JSA learner (`central_outcome`, `central_act`, `central_looks`): `Team` steps its learners through
them, and so do the agent node's drivers, so the order of a learner's calls is written once. `Team` asks
each learner what it needs to see, hands it exactly that, applies the joint action and feeds the outcome
back; its per-step hook lets a caller watch an episode (the renderer films one). `run` plays one
(algorithm, run) for a number of episodes and returns its per-episode records (cq_ros.episode: their
columns); the lab (cq_ros.lab) spreads runs over the cores and writes result files.

Seeds: the learner of agent i in run r draws from `learner_seed(seed, r, i)`, the world (only used
with delays: slip, start_hold) from `world_seed(seed, r)`: the same seed gives the same run, offline or over ROS.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

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


# -- one learner's step ------------------------------------------------------------------------------
#
# The order of a learner's calls lives here, and only here: the engine's Team, the agent node's drivers and
# (through Team's per-step hook) the renderer all step a learner through these functions. A step is cut where
# an agent node waits: for the world's outcome of its action (then `step_outcome`: learn from it, then end the
# episode or observe the new cell), and for the positions of the peers its learner asked for (then `step_act`).

def step_outcome(learner: Learner, cell: Any, reward: float | None = None, done: bool = False,
                 over: bool = False) -> tuple[int, ...] | None:
    """The world has moved the agent to `cell`: learn from the outcome of its action (`reward`, `done`; None: no
    outcome to learn from, as at an episode's first step, or when the world did not apply the action); then, if
    the episode is `over` for the agent (at its goal, or truncated), end it and return None, else observe
    `cell` and return the peers (0-based) whose cells the learner must see to choose its move. `cell` is not
    read when the episode is over and there is nothing to learn (an episode ended without a last outcome)."""
    if reward is not None:
        learner.learn(reward, cell, done)
    if over:
        learner.end_episode()
        return None
    return learner.observe(cell)


def step_act(learner: Learner, seen: Mapping[int, Any]) -> int:
    """The cells of the peers `step_outcome` named (peer -> cell, 0-based) are in: the learner's action."""
    return learner.act(seen)


# The central (JSA) learner steps through the same two functions as one agent whose cell is the tuple of every
# agent's cell, whose reward is the sum of the agents' rewards (0 for those at their goals, as
# GridWorld.step_joint gives them), whose episode is done when every agent is, who never asks for a peer (it
# sees every cell) and whose action encodes every agent's move (decode_joint_action). These three functions
# are that adapter, used by Team and by the central agent node alike.

def central_outcome(learner: Learner, cells: Sequence[int], rewards: Sequence[float] | None, finished: bool,
                    over: bool) -> tuple[int, ...] | None:
    """step_outcome for the central learner: `rewards` every agent's (None: no outcome to learn from),
    `finished` every agent at its goal, `over` the episode ended (finished or truncated)."""
    return step_outcome(learner, tuple(cells), None if rewards is None else sum(rewards), finished, over)


def central_act(learner: Learner, n: int) -> list[int]:
    """step_act for the central learner: the move of each of the `n` agents (those at their goals ignore it)."""
    return decode_joint_action(step_act(learner, _NOBODY), n)


def central_looks(done: Sequence[bool]) -> list[tuple[int, ...] | None]:
    """Whom each agent looks at when the central learner chooses: every other acting agent (it chooses on the
    joint state); None for an agent at its goal."""
    acting = [i for i, d in enumerate(done) if not d]
    return [None if d else tuple(j for j in acting if j != i) for i, d in enumerate(done)]


StepHook = Callable[[GridWorld, list, list], Any]


class Team:
    """Learners acting together in one world: one joint step at a time, each learner stepped by
    step_outcome/step_act (the central learner by its adapter, central_outcome/central_act).

    `needs[i]` is what agent i's learner asked to see at the current step (the peers, 0-based; None for an
    agent whose episode is over); `start` fills it at an episode's first step, `learn` at every later one."""

    def __init__(self, world: GridWorld, learners: list[Learner]):
        self.world = world
        self.learners = learners
        self.central = learners[0].central
        self.needs: list[tuple[int, ...] | None] = []

    def start(self) -> bool:
        """The episode's first step (the world just reset): every learner observes where its agent starts;
        one that starts at its goal ends its episode here (it never acts). Whether the episode is over."""
        w = self.world
        finished, over = w.finished, w.over
        if self.central:
            self.needs = [central_outcome(self.learners[0], w.cells, None, finished, over)]
        else:
            cells, done = w.cells, w.done
            self.needs = [step_outcome(learner, cells[i], None, False, over or done[i])
                          for i, learner in enumerate(self.learners)]
        return over

    def choose(self) -> list[int | None]:
        """Each acting agent's action (None for agents at their goals), each learner given the cells of the
        peers it asked for."""
        w = self.world
        if self.central:
            joint = central_act(self.learners[0], w.n)
            return [None if d else a for a, d in zip(joint, w.done)]
        # Plain loops, not comprehensions, here and in learn: on Python 3.11 a comprehension is one more call
        # per joint step, which the engine's speed feels.
        cells, actions = w.cells, []
        for learner, need in zip(self.learners, self.needs):
            if need is None:
                actions.append(None)
            else:
                actions.append(step_act(learner, {j: cells[j] for j in need} if need else _NOBODY))
        return actions

    def learn(self, actions: list[int | None], rewards: list[float]) -> bool:
        """After the world applied `actions`: every agent that acted learns from its outcome, then ends its
        episode (at its goal, or the episode truncated) or observes its next step. Whether the episode is
        over."""
        w = self.world
        finished, over = w.finished, w.over
        if self.central:
            self.needs = [central_outcome(self.learners[0], w.cells, rewards, finished, over)]
            return over
        cells, done, needs, learners = w.cells, w.done, self.needs, self.learners
        for i, a in enumerate(actions):
            if a is not None:  # an agent that did not act has nothing to learn and stays over
                d = done[i]
                needs[i] = step_outcome(learners[i], cells[i], rewards[i], d, over or d)
        return over

    def episode(self, on_step: StepHook | None = None) -> Episode:
        """Play one episode. `on_step(world, actions, looks)`, if given, is called at every joint step after
        the learners chose `actions` and before the world applies them; `looks[i]` is whom agent i looked at
        (the peers, 0-based; for the central learner central_looks; None for an agent at its goal)."""
        w = self.world
        w.reset_joint()
        plays = sum(learner.joint_plays for learner in self.learners)
        heard = sum(learner.heard for learner in self.learners)
        collisions, ret = 0, 0.0
        over = self.start()
        choose, learn, step_joint = self.choose, self.learn, w.step_joint  # bound once: the loop is hot
        while not over:
            actions = choose()
            if on_step is not None:
                on_step(w, actions, central_looks(w.done) if self.central else self.needs)
            rewards = step_joint(actions)
            over = learn(actions, rewards)
            collisions += w.last_collisions
            ret += sum(rewards)
        return Episode(
            steps=w.t,
            collisions=collisions,
            joint_plays=sum(learner.joint_plays for learner in self.learners) - plays,
            states=sum(learner.state_count() for learner in self.learners),
            ret=ret,
            truncated=w.truncated,
            heard=sum(learner.heard for learner in self.learners) - heard,
        )


def greedy_team(team: Team, learning: bool | None = None, keep: bool = True) -> Team:
    """The team with its learners at epsilon 0 (the learnt policy without exploration), frozen unless
    `learning` (None: settings.eval_learning; Learner.make_greedy): a copy, so the run itself is left exactly
    as it was, or (`keep` False, for a caller done with the run) the team itself, which costs no memory where
    a copy holds every learner's tables and CQ's reward windows again."""
    greedy = copy.deepcopy(team) if keep else team
    for learner in greedy.learners:
        learner.make_greedy(learning)
    return greedy


def greedy_episodes(team: Team, episodes: int, keep: bool = True) -> np.ndarray:
    """What the learnt policy does without exploration: `episodes` episodes played by greedy_team(team, keep=keep)
    (none played, no copy made: a copy of a warehouse_32 team costs about a second)."""
    if episodes == 0:
        return record.table(())
    greedy = greedy_team(team, keep=keep)
    return record.table(greedy.episode() for _ in range(episodes))


@dataclass
class RunResult:
    algo: str
    run: int
    episodes: np.ndarray  # one element per episode, cq_ros.episode's named columns (episodes["collisions"])
    joint_states: list[tuple[int, int, int, int, float]]  # (agent, cell, peer, peer_cell, confidence)
    greedy: np.ndarray  # the same for each greedy episode played at the end
    engine: str = "reference"  # which engine played it (cq_ros.compiled.ENGINES): the same result on either


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
    return RunResult(algo, run_index, table, kept, greedy_episodes(team, settings.eval_episodes, keep=False))
