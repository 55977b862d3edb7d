"""Why learners still collide late in learning: each colliding pair of the last 10% of episodes, classified by
whether either agent's move was an exploratory one (epsilon-greedy's random branch) or both were greedy,
whether either saw the other when it chose (a peer it was given by `observe`), and by the pair's geometry:
a swap, a merge into one cell, a rear-end (one moves into the cell of one that stays: waiting by bumping a
wall, or parked at its goal) or a chain (sent back by another collision). A floor that exploration sets
cannot be learnt away; greedy collisions between agents that saw each other are coordination CQ failed at.

    python benchmarks/warehouse_collisions.py [--map warehouse_8] [--algos indep,cq] [--runs 3] [--episodes 2000]
        [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

from tqdm import tqdm

import cq_ros.learners.base as base
from cq_ros.engine import Team, make_learners, world_seed
from cq_ros.gridmap import GridMap, load_map
from cq_ros.learners import LEARNERS
from cq_ros.settings import Settings, SettingsError, run_settings
from cq_ros.world import GridWorld, resolve_moves

explored: set[int] = set()  # ids of the rngs that took the random branch this step
seen: dict[int, set[int]] = {}  # agent -> the peers it was given to choose this step


def epsilon_greedy_told(row, epsilon, rng):
    """base.epsilon_greedy, drawing the same numbers, that also says when it explored."""
    if rng.random() < epsilon:
        explored.add(id(rng))
        return int(rng.random() * len(row))
    return base.greedy(row, rng)


def telling_act(act, agent):
    """A learner's act that also records which peers it was given."""
    def told(peer_cells):
        seen[agent] = set(peer_cells)
        return act(peer_cells)
    return told


def geometry(before, targets, actions, i, j) -> str:
    if targets[i] == before[j] and targets[j] == before[i]:
        return "swap"
    for mover, stayer in ((i, j), (j, i)):
        if targets[mover] == before[stayer] == targets[stayer]:
            return "rear-end, " + ("parked" if actions[stayer] is None else "waiting")
    return "merge" if targets[i] == targets[j] else "chain"


def classify(gridmap: GridMap, settings: Settings, algo: str, runs: int, episodes: int) -> Counter:
    # every learner module imported epsilon_greedy by name: point them all at the telling twin
    for cls in LEARNERS.values():
        sys.modules[cls.__module__].epsilon_greedy = epsilon_greedy_told
    kinds: Counter = Counter()
    for run in tqdm(range(runs), desc=f"{gridmap.name} {algo}", file=sys.stderr):
        world = GridWorld(gridmap, settings, seed=world_seed(0, run))
        team = Team(world, make_learners(algo, gridmap, settings, 0, run))
        for i, learner in enumerate(team.learners):
            learner.act = telling_act(learner.act, i)
        for episode in range(episodes):
            late = episode >= 0.9 * episodes
            world.reset_joint()
            over = team.start()  # Team.episode's loop, watched (learn ends the learners' episodes)
            while not over:
                explored.clear()
                seen.clear()
                before = list(world.cells)
                actions = team.choose()
                rngs = [id(learner.rng) in explored for learner in team.learners]
                rewards = world.step_joint(actions)
                if late and world.last_collisions:
                    targets = [c if a is None else gridmap.neighbours[c][a] for c, a in zip(before, actions)]
                    for i, j in resolve_moves(before, targets, gridmap.goals)[1]:
                        kind = "both explored" if rngs[i] and rngs[j] else "one explored" if rngs[i] or rngs[j] \
                            else "both greedy"
                        saw = "saw" if j in seen.get(i, ()) or i in seen.get(j, ()) else "unseen"
                        kinds[(kind, saw, geometry(before, targets, actions, i, j))] += 1
                over = team.learn(actions, rewards)
    return kinds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="warehouse_8")
    parser.add_argument("--algos", default="indep,cq")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="change a setting over the map's own (repeatable), as in cq-ros experiment")
    args = parser.parse_args()
    gridmap = load_map(args.map)
    try:
        settings = run_settings(gridmap, args.overrides)
    except SettingsError as e:
        parser.error(str(e))
    late_episodes = args.runs * (args.episodes - int(0.9 * args.episodes))
    for algo in args.algos.split(","):
        kinds = classify(gridmap, settings, algo, args.runs, args.episodes)
        total = sum(kinds.values())
        print(f"{args.map} {algo}: {total / late_episodes:.2f} colliding pairs per episode over the last 10% "
              f"({total} pairs in {late_episodes} episodes)")
        for group in (0, 1, 2):
            sums = Counter()
            for key, n in kinds.items():
                sums[key[group]] += n
            print("  " + ", ".join(f"{k} {n / late_episodes:.2f} ({n / total:.0%})" for k, n in sums.most_common()))
        print("  " + "; ".join(f"{', '.join(k)} {n / late_episodes:.2f}" for k, n in kinds.most_common(6)))


if __name__ == "__main__":
    main()
