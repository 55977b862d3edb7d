#!/usr/bin/env python3
"""Why a learnt greedy policy leaves AGVs short of their goals: after learning as `cq-ros experiment`'s run 0
does, play greedy episodes and print, for each AGV not home at the step cap, where it spent its last steps,
what it did there and its Q-values in that cell, beside the waiting floor: the value of bumping a wall for
ever, reward_wall / (1 - gamma). An AGV whose every action there is worth the floor has no value of home left
to follow.

    python benchmarks/stuck_agents.py --map warehouse_16_delayed --algo indep --episodes 2000 [--seed 0]
                                      [--greedy 2] [--set KEY=VALUE ...]

Learning shows progress on stderr every 100 episodes; 2,000 episodes of warehouse_16_delayed take about 20
minutes of one core here, most of its episodes running to the step cap.
"""

from __future__ import annotations

import argparse
import collections
import sys

from cq_ros.engine import Team, greedy_team, make_learners, world_seed
from cq_ros.gridmap import load_map
from cq_ros.settings import run_settings
from cq_ros.world import GridWorld

LAST = 400  # the steps of an AGV not home that are summarised


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", required=True)
    parser.add_argument("--algo", default="indep", choices=("indep", "cq"))
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--greedy", type=int, default=2, help="greedy episodes to play after learning")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    gridmap = load_map(args.map)
    settings = run_settings(gridmap, args.set)
    team = Team(GridWorld(gridmap, settings, seed=world_seed(args.seed, 0)),
                make_learners(args.algo, gridmap, settings, args.seed, 0))
    window = collections.deque(maxlen=100)
    for episode in range(args.episodes):
        window.append(team.episode())
        if (episode + 1) % 100 == 0 or episode + 1 == args.episodes:
            print(f"stuck_agents: episodes {episode + 1}/{args.episodes}, last {len(window)}: "
                  f"{sum(e.truncated for e in window)} truncated, "
                  f"{sum(e.collisions for e in window) / len(window):.2f} collisions/ep", file=sys.stderr, flush=True)
    floor = settings.reward_wall / (1 - settings.gamma)
    print(f"{args.map}, {args.algo}, seed {args.seed}, {args.episodes} learning episodes; waiting floor "
          f"reward_wall / (1 - gamma) = {floor:.1f}")
    greedy = greedy_team(team)
    w, cells = greedy.world, gridmap.cells
    for episode in range(args.greedy):
        w.reset_joint()
        trail = collections.defaultdict(lambda: collections.deque(maxlen=LAST))
        over = greedy.start()  # Team.episode's loop, with the trail kept (learn ends the learners' episodes)
        while not over:
            actions = greedy.choose()
            rewards = w.step_joint(actions)
            over = greedy.learn(actions, rewards)
            for i in range(w.n):
                if not w.done[i]:
                    trail[i].append((w.cells[i], actions[i], rewards[i]))
        home = [i + 1 for i in range(w.n) if w.done[i]]
        print(f"greedy episode {episode}: {w.t} steps, {len(home)}/{w.n} home, arrivals "
              f"{dict((i + 1, t) for i, t in enumerate(w.arrival) if t is not None)}")
        for i in range(w.n):
            if w.done[i]:
                continue
            where = collections.Counter(c for c, _, _ in trail[i])
            cell = where.most_common(1)[0][0]
            q = [round(v, 1) for v in greedy.learners[i].q_local[cell]]
            print(f"  agv{i + 1} (goal {cells[gridmap.goals[i]]}): last {len(trail[i])} steps in "
                  f"{ {cells[c]: n for c, n in where.most_common(3)} }, actions "
                  f"{dict(collections.Counter(a for _, a, _ in trail[i]))}, rewards "
                  f"{dict(collections.Counter(r for _, _, r in trail[i]))}; Q_k at {cells[cell]}: {q}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
