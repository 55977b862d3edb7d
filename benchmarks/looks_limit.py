"""What a learner would hear that looked at a peer only where and when it could collide: the limit of CQ's looks.

On a generated delayed warehouse (`cq-ros generate warehouse`, as bench_delays.py --generate makes it), one run
of ALGO as bench_delays.py plays it (2000 learning episodes, then the greedy episodes on a copy of the team);
per greedy episode, all agents together:
- own: the peer positions the learners took in (bench_delays.py's "greedy heard");
- in range: the peers within 2 cells of each acting agent at each step (what `near` would hear on the same
  steps);
- at collision cells: the same, counted only at the steps an agent stands in a cell where it collided while
  learning (in any episode, or in the last 10%): a learner that looked at a peer only where collisions happen
  and only when the peer could collide this step would hear this much.

    python benchmarks/looks_limit.py --generate 8:0,7 [--algo cq] [--runs 3] [--episodes 2000] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
from statistics import mean

from cq_ros.engine import Team, greedy_team, make_learners, world_seed
from cq_ros.mapgen.warehouse import warehouse_map
from cq_ros.settings import run_settings
from cq_ros.world import GridWorld


def one_run(agents: int, gen: int, slip: float, algo: str, run: int, episodes: int, overrides: list[str]) -> dict:
    gm = warehouse_map(agents, seed=gen, slip=slip, name=f"warehouse_{agents}_gen{gen}")
    st = run_settings(gm, [*overrides, f"slip={slip}"])
    team = Team(GridWorld(gm, st, seed=world_seed(0, run)), make_learners(algo, gm, st, 0, run))
    hit_all = [set() for _ in range(agents)]  # per agent, the cells where it collided while learning
    hit_tail = [set() for _ in range(agents)]  # the same, in the last 10% of the episodes
    tail_from = episodes - max(1, episodes // 10)
    world, inner = team.world, team.world.step_joint
    episode = 0

    def step_joint(actions):
        before = list(world.cells)
        rewards = inner(actions)
        for i, reward in enumerate(rewards):
            if actions[i] is not None and reward == st.reward_collision:  # a collision leaves the agent in its cell
                hit_all[i].add(before[i])
                if episode >= tail_from:
                    hit_tail[i].add(before[i])
        return rewards

    world.step_joint = step_joint  # Team.episode looks it up at each episode's start
    for episode in range(episodes):
        team.episode()
    del world.step_joint  # the greedy copy steps its own world, not this one
    heard = sum(learner.heard for learner in team.learners)
    greedy = greedy_team(team)
    count = {"in range": 0, "at collision cells": 0, "at collision cells, last 10%": 0}

    def on_step(w, actions, looks):
        cells = w.cells
        for i, action in enumerate(actions):
            if action is None:
                continue
            near = sum(1 for j in range(agents) if j != i and gm.distance(cells[i], cells[j]) <= 2)
            count["in range"] += near
            count["at collision cells"] += near if cells[i] in hit_all[i] else 0
            count["at collision cells, last 10%"] += near if cells[i] in hit_tail[i] else 0

    played = [greedy.episode(on_step) for _ in range(st.eval_episodes)]
    n = len(played)
    own = sum(learner.heard for learner in greedy.learners) - heard
    return {"own": own / n, **{k: v / n for k, v in count.items()},
            "collisions": sum(p.collisions for p in played) / n,
            "collision cells per agent": mean(len(h) for h in hit_all), "of cells": gm.n_cells}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--generate", action="append", required=True, metavar="AGENTS:SEED,SEED")
    parser.add_argument("--gen-slip", type=float, default=0.1)
    parser.add_argument("--algo", default="cq")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    print("python benchmarks/looks_limit.py " + " ".join(f"--generate {g}" for g in args.generate)
          + f" --algo {args.algo} --runs {args.runs} --episodes {args.episodes}"
          + "".join(f" --set {o}" for o in args.overrides))
    for spec in args.generate:
        agents, _, seeds = spec.partition(":")
        rows = [one_run(int(agents), int(g), args.gen_slip, args.algo, r, args.episodes, args.overrides)
                for g in seeds.split(",") for r in range(args.runs)]
        print(f"\n{agents} AGVs, generator seeds {seeds}, {args.algo}: {len(rows)} runs; per greedy episode, mean "
              f"(min-max) over runs")
        for key in rows[0]:
            values = [row[key] for row in rows]
            print(f"  {key}: {mean(values):.2f} ({min(values):.2f}-{max(values):.2f})", flush=True)


if __name__ == "__main__":
    main()
