"""Where looking pays: every learner on delayed warehouses, its greedy policy against a plan that is not learned.

One row per map, slip and algorithm, over seeds x runs (each run as `cq-ros experiment` plays it: the same
learner and world seeds, `episodes` learning episodes, then `eval_episodes` greedy ones on a copy of the team,
in the same delayed world):
- greedy home: runs whose greedy episodes all bring every AGV home without truncation;
- greedy collisions: per greedy episode, mean over runs (and the worst run);
- greedy cost / planner: the greedy episodes' sum of costs (the step each AGV arrives, summed; an AGV not home
  counts the episode's length) over the planner's sum of costs without delays;
- heard/step: peer positions the learners took in per joint step (all agents together), while learning and in
  the greedy episodes: CQ's looks against `near`, which looks at every peer within 2 cells at every step;
- exploring collisions: per episode over the last 10% of learning.
The algorithm `adg` is the yardstick that is not learned: the planner's plan carried out by its action
dependency graph under the same delays (cq_ros.mapf.execute; run r of a seed draws the delays a learner's run r
draws), one execution per run: its greedy columns are the execution's, and heard/step its dependency messages
per step.

    python benchmarks/bench_delays.py [--maps warehouse_8] [--algos indep,near,loc,cq] [--slips 0,0.1]
        [--seeds 0,1,2] [--runs 10] [--episodes 2000] [--jobs 2] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

from tqdm import tqdm

from cq_ros.engine import Team, greedy_team, make_learners, world_seed
from cq_ros.mapf.execute import execute
from cq_ros.gridmap import load_map
from cq_ros.mapf.planner import plan
from cq_ros.settings import SettingsError, run_settings
from cq_ros.world import GridWorld


def one_run(map_name: str, algo: str, slip: float, seed: int, run: int, episodes: int, overrides: list[str]) -> dict:
    gridmap = load_map(map_name)
    settings = run_settings(gridmap, [*overrides, f"slip={slip}"])
    if algo == "adg":
        done = execute(plan(gridmap), gridmap, settings, seed, run)
        steps = max(a or done.paths[i].__len__() - 1 for i, a in enumerate(done.arrivals))
        cost = sum(len(path) - 1 if a is None else a for path, a in zip(done.paths, done.arrivals))
        return {"explore": 0.0, "heard": 0.0, "g_heard": done.messages / max(1, steps),
                "g_collisions": float(done.collisions), "g_cost": float(cost), "g_home": done.home}
    team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, run)),
                make_learners(algo, gridmap, settings, seed, run))
    tail = max(1, episodes // 10)
    collisions = steps = 0
    for episode in range(episodes):
        played = team.episode()
        steps += played.steps
        if episode >= episodes - tail:
            collisions += played.collisions
    heard = sum(learner.heard for learner in team.learners)
    greedy = greedy_team(team)
    world = greedy.world
    g_collisions, g_costs, g_home, g_steps = [], [], True, 0
    for _ in range(settings.eval_episodes):
        played = greedy.episode()
        g_collisions.append(played.collisions)
        g_costs.append(sum(played.steps if t is None else t for t in world.arrival))
        g_home &= world.finished
        g_steps += played.steps
    return {
        "explore": collisions / tail, "heard": heard / max(1, steps),
        "g_heard": (sum(learner.heard for learner in greedy.learners) - heard) / max(1, g_steps),
        "g_collisions": sum(g_collisions) / len(g_collisions), "g_cost": sum(g_costs) / len(g_costs),
        "g_home": g_home,
    }


def row(key: tuple, results: list[dict], planned: int) -> str:
    def mean(name):
        return sum(r[name] for r in results) / len(results)

    worst = max(r["g_collisions"] for r in results)
    map_name, slip, algo = key
    return (f"| {map_name} | {slip:g} | {algo} | {sum(r['g_home'] for r in results)}/{len(results)} "
            f"| {mean('g_collisions'):.3f} ({worst:.2f}) | {mean('g_cost') / planned:.2f} "
            f"| {mean('heard'):.3f} | {mean('g_heard'):.3f} | {mean('explore'):.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", default="warehouse_8")
    parser.add_argument("--algos", default="indep,near,loc,cq")
    parser.add_argument("--slips", default="0,0.05,0.1,0.2")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="change a setting over the maps' own (repeatable), as in cq-ros experiment")
    args = parser.parse_args()
    maps, algos = args.maps.split(","), args.algos.split(",")
    try:
        slips = [float(s) for s in args.slips.split(",")]
        seeds = [int(s) for s in args.seeds.split(",")]
        for name in maps:
            for slip in slips:
                run_settings(load_map(name), [*args.overrides, f"slip={slip}"])
        for algo in algos:
            if algo != "adg":
                make_learners(algo, load_map(maps[0]), run_settings(load_map(maps[0])), 0, 0)
    except (SettingsError, ValueError, KeyError) as e:
        parser.error(str(e))

    print("python benchmarks/bench_delays.py " + " ".join(sys.argv[1:]))
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; seeds {args.seeds} x "
          f"{args.runs} runs x {args.episodes} episodes"
          + (f"; settings: {' '.join(args.overrides)}" if args.overrides else ""))
    planned = {}
    for name in maps:
        the_plan = plan(load_map(name))
        planned[name] = the_plan.sum_of_costs
        print(f"{name}: planner ({the_plan.method}) without delays: makespan {the_plan.makespan}, sum of costs "
              f"{the_plan.sum_of_costs}")
    jobs = [(m, a, p, s, r) for m in maps for p in slips for a in algos for s in seeds for r in range(args.runs)]
    results: dict[tuple, list[dict]] = {}
    started = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = {pool.submit(one_run, m, a, p, s, r, args.episodes, args.overrides): (m, p, a)
                   for m, a, p, s, r in jobs}
        for future in tqdm(as_completed(futures), total=len(jobs), desc="runs", file=sys.stderr):
            results.setdefault(futures[future], []).append(future.result())
    print(f"{time.perf_counter() - started:.0f} s; load {os.getloadavg()[0]:.1f}")
    print("| map | slip | algo | greedy home | greedy collisions (worst run) | greedy cost / planner | heard/step "
          "learning | heard/step greedy | exploring collisions |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for m in maps:
        for p in slips:
            for a in algos:
                print(row((m, p, a), results[(m, p, a)], planned[m]))


if __name__ == "__main__":
    main()
