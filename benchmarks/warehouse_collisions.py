"""Why learners still collide late in learning: each colliding pair of the last 10% of episodes, classified by
whether either agent's move was an exploratory one (epsilon-greedy's random branch) or both were greedy,
and whether one of them stood parked at its goal. A floor that exploration sets cannot be learnt away.

    python benchmarks/warehouse_collisions.py [--map warehouse_8] [--algos indep,cq] [--runs 3] [--episodes 2000]
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

from tqdm import tqdm

import cq_ros.learners.base as base
from cq_ros.engine import Team, make_learners, world_seed
from cq_ros.gridmap import load_map
from cq_ros.learners import LEARNERS
from cq_ros.settings import run_settings
from cq_ros.world import GridWorld, resolve_moves

explored: set[int] = set()  # ids of the rngs that took the random branch this step


def epsilon_greedy_told(row, epsilon, rng):
    """base.epsilon_greedy, drawing the same numbers, that also says when it explored."""
    if rng.random() < epsilon:
        explored.add(id(rng))
        return int(rng.random() * len(row))
    return base.greedy(row, rng)


def classify(map_name: str, algo: str, runs: int, episodes: int) -> Counter:
    # every learner module imported epsilon_greedy by name: point them all at the telling twin
    for cls in LEARNERS.values():
        sys.modules[cls.__module__].epsilon_greedy = epsilon_greedy_told
    gridmap = load_map(map_name)
    settings = run_settings(gridmap)
    kinds: Counter = Counter()
    for run in tqdm(range(runs), desc=f"{map_name} {algo}", file=sys.stderr):
        world = GridWorld(gridmap, settings, seed=world_seed(0, run))
        team = Team(world, make_learners(algo, gridmap, settings, 0, run))
        for episode in range(episodes):
            late = episode >= 0.9 * episodes
            world.reset_joint()
            while not world.finished and world.t < world.step_cap:
                explored.clear()
                before = list(world.cells)
                actions = team.choose()
                rngs = [id(learner.rng) in explored for learner in team.learners]
                rewards = world.step_joint(actions)
                if late and world.last_collisions:
                    targets = [c if a is None else gridmap.neighbours[c][a] for c, a in zip(before, actions)]
                    for i, j in resolve_moves(before, targets, gridmap.goals)[1]:
                        kind = "both explored" if rngs[i] and rngs[j] else "one explored" if rngs[i] or rngs[j] \
                            else "both greedy"
                        kinds[kind + (", one parked" if None in (actions[i], actions[j]) else "")] += 1
                team.learn(actions, rewards)
            for learner in team.learners:
                learner.end_episode()
    return kinds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="warehouse_8")
    parser.add_argument("--algos", default="indep,cq")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=2000)
    args = parser.parse_args()
    late_episodes = args.runs * (args.episodes - int(0.9 * args.episodes))
    for algo in args.algos.split(","):
        kinds = classify(args.map, algo, args.runs, args.episodes)
        total = sum(kinds.values())
        print(f"{args.map} {algo}: {total / late_episodes:.2f} collisions per episode over the last 10%; "
              + ", ".join(f"{k}: {n} ({n / total:.0%})" for k, n in sorted(kinds.items())))


if __name__ == "__main__":
    main()
