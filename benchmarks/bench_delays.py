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

The protocol on generated maps (`--generate AGENTS:SEED,SEED ...`, repeatable), the tool of tuning (on the tuning
generator seeds, cq_ros.lab.held_out_protocol.TUNING_SEEDS, with `--variant`s): instead of `--maps`, warehouses made by
`cq-ros generate warehouse --agents AGENTS --seed SEED --slip P` (P from `--gen-slip`, 0.1). The held-out figures
come from `cq-ros study` (cq_ros.lab.held_out: frozen and learning greedy copies, the planner, ratios, a curve).
`--variant NAME=ALGO:KEY=VALUE,...` (repeatable) adds a configuration: an algorithm with settings of its own over
the maps' and `--set`'s. For each number of agents, a unit is one map and one run (run r of every configuration on a
map: the same learner and world seeds, the same delays), and per configuration it prints the mean over units and the
half-width of a 95% t interval, then each configuration's paired differences from the first (the same maps, the same
runs):
- greedy collisions: per greedy episode;
- greedy all home: the share of greedy episodes in which every AGV reached its goal before the step cap;
- greedy heard: peer positions the learners took in per greedy episode (all agents together);
- exploring collisions: per episode over the last 10% of learning;
- states: the states the learners condition on at the end of learning (local plus joint, summed over them).

    python benchmarks/bench_delays.py --generate 8:101,102 [--generate 12:103] [--gen-slip 0.1]
        [--algos cq,cq_paper,indep] [--variant cq_a2=cq:alpha=0.2] [--seeds 0] [--runs 3]
        [--episodes 2000] [--jobs 2]
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
from cq_ros.gridmap import GridMap, load_map
from cq_ros.lab.held_out_protocol import parse_configs
from cq_ros.lab.study import mean_interval
from cq_ros.mapgen.warehouse import warehouse_map
from cq_ros.mapf.planner import plan
from cq_ros.settings import SettingsError, run_settings
from cq_ros.world import GridWorld


MapRef = str | tuple[int, int, float]  # a map's name or file, or (agents, generator seed, slip) of a generated one


def the_map(ref: MapRef) -> GridMap:
    """The map a reference names; a generated one made again from its generator seed wherever it is needed."""
    if isinstance(ref, tuple):
        agents, seed, slip = ref
        return warehouse_map(agents, seed=seed, slip=slip, name=f"warehouse_{agents}_gen{seed}")
    return load_map(ref)


def one_run(map_ref: MapRef, algo: str, slip: float, seed: int, run: int, episodes: int, overrides: list[str]) -> dict:
    gridmap = the_map(map_ref)
    settings = run_settings(gridmap, [*overrides, f"slip={slip}"])
    if algo == "adg":
        done = execute(plan(gridmap), gridmap, settings, seed, run)
        steps = max(a or done.paths[i].__len__() - 1 for i, a in enumerate(done.arrivals))
        cost = sum(len(path) - 1 if a is None else a for path, a in zip(done.paths, done.arrivals))
        return {"explore": 0.0, "heard": 0.0, "states": 0.0, "g_heard": done.messages / max(1, steps),
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
    states = played.states  # at the end of learning: whether a learner had room to learn in that many episodes
    heard = sum(learner.heard for learner in team.learners)
    greedy = greedy_team(team)
    world = greedy.world
    g_collisions, g_costs, g_finished, g_steps = [], [], [], 0
    for _ in range(settings.eval_episodes):
        played = greedy.episode()
        g_collisions.append(played.collisions)
        g_costs.append(sum(played.steps if t is None else t for t in world.arrival))
        g_finished.append(world.finished)
        g_steps += played.steps
    g_heard = sum(learner.heard for learner in greedy.learners) - heard
    return {
        "explore": collisions / tail, "heard": heard / max(1, steps), "states": float(states),
        "g_heard": g_heard / max(1, g_steps), "g_heard_episode": g_heard / len(g_finished),
        "g_collisions": sum(g_collisions) / len(g_collisions), "g_cost": sum(g_costs) / len(g_costs),
        "g_home": all(g_finished), "g_home_share": sum(g_finished) / len(g_finished),
    }


def row(key: tuple, results: list[dict], planned: int) -> str:
    def mean(name):
        return sum(r[name] for r in results) / len(results)

    worst = max(r["g_collisions"] for r in results)
    map_name, slip, algo = key
    return (f"| {map_name} | {slip:g} | {algo} | {sum(r['g_home'] for r in results)}/{len(results)} "
            f"| {mean('g_collisions'):.3f} ({worst:.2f}) | {mean('g_cost') / planned:.2f} "
            f"| {mean('heard'):.3f} | {mean('g_heard'):.3f} | {mean('explore'):.2f} |")


HELD_OUT = (("greedy collisions", "g_collisions", 3), ("greedy all home", "g_home_share", 2),
            ("greedy heard", "g_heard_episode", 1), ("exploring collisions", "explore", 2), ("states", "states", 0))


def interval(values: list[float], digits: int) -> str:
    """The mean and the half-width of its 95% t interval (none for a single value): cq_ros.lab.study's."""
    return mean_interval(values).show(digits)


def parse_generate(specs: list[str]) -> list[tuple[int, list[int]]]:
    """["8:1,2,3", "12:4,5"] -> [(8, [1, 2, 3]), (12, [4, 5])]; ValueError for anything else."""
    found = []
    for spec in specs:
        agents, sep, seeds = spec.partition(":")
        if not sep or not seeds:
            raise ValueError(f"--generate takes AGENTS:SEED,SEED..., got {spec!r}")
        found.append((int(agents), [int(seed) for seed in seeds.split(",")]))
    return found


def held_out(args, configs: list[tuple[str, str, list[str]]], groups: list[tuple[int, list[int]]],
             seeds: list[int]) -> None:
    """The held-out protocol: every configuration on every generated map, run by run; per number of agents the
    configurations' means with 95% t intervals over units (map, seed, run), and their paired differences from
    the first configuration."""
    units = [(agents, (agents, g, args.gen_slip), s, r) for agents, gen in groups for g in gen for s in seeds
             for r in range(args.runs)]
    results: dict[tuple, dict] = {}
    started = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = {pool.submit(one_run, ref, algo, args.gen_slip, s, r, args.episodes, [*args.overrides, *own]):
                   (name, ref, s, r) for _, ref, s, r in units for name, algo, own in configs}
        for future in tqdm(as_completed(futures), total=len(futures), desc="runs", file=sys.stderr):
            results[futures[future]] = future.result()
    print(f"{time.perf_counter() - started:.0f} s; load {os.getloadavg()[0]:.1f}")
    header = " | ".join(label for label, _, _ in HELD_OUT)
    first = configs[0][0]
    for agents, gen in groups:
        mine = [(ref, s, r) for a, ref, s, r in units if a == agents]
        print(f"\n{agents} AGVs, generator seeds {','.join(map(str, gen))}, slip {args.gen_slip:g}: {len(mine)} units "
              "(map, seed, run); mean ± 95% t interval over units")
        print(f"\n| configuration | {header} |\n| --- |" + " ---: |" * len(HELD_OUT))
        for name, _, _ in configs:
            cells = [interval([results[(name, *u)][key] for u in mine], digits) for _, key, digits in HELD_OUT]
            print(f"| {name} | {' | '.join(cells)} |")
        if len(configs) > 1:
            print(f"\n| paired difference | {header} |\n| --- |" + " ---: |" * len(HELD_OUT))
            for name, _, _ in configs[1:]:
                cells = [interval([results[(name, *u)][key] - results[(first, *u)][key] for u in mine], digits)
                         for _, key, digits in HELD_OUT]
                print(f"| {name} - {first} | {' | '.join(cells)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", default="warehouse_8")
    parser.add_argument("--generate", action="append", default=[], metavar="AGENTS:SEED,SEED",
                        help="the held-out protocol on warehouses generated with these generator seeds (repeatable)")
    parser.add_argument("--gen-slip", type=float, default=0.1, help="the generated warehouses' slip")
    parser.add_argument("--variant", action="append", default=[], metavar="NAME=ALGO:KEY=VALUE,...",
                        help="a configuration: an algorithm with settings of its own (repeatable; --generate only)")
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
        groups = parse_generate(args.generate)
        configs = [(c.name, c.algo, list(c.sets)) for c in parse_configs(algos, args.variant)]
        if args.variant and not groups:
            raise ValueError("--variant needs --generate")
        for agents, gen in groups:
            for g in gen:
                for _, algo, own in configs:
                    run_settings(the_map((agents, g, args.gen_slip)), [*args.overrides, *own])
                    if algo == "adg":
                        raise ValueError("--generate measures learners; adg is the shipped maps' yardstick")
        for name in ([] if groups else maps):
            for slip in slips:
                run_settings(load_map(name), [*args.overrides, f"slip={slip}"])
        for _, algo, _ in configs:
            if algo != "adg":
                make_learners(algo, load_map(maps[0]), run_settings(load_map(maps[0])), 0, 0)
    except (SettingsError, ValueError, KeyError) as e:
        parser.error(str(e))

    print("python benchmarks/bench_delays.py " + " ".join(sys.argv[1:]))
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; seeds {args.seeds} x "
          f"{args.runs} runs x {args.episodes} episodes"
          + (f"; settings: {' '.join(args.overrides)}" if args.overrides else ""))
    if groups:
        held_out(args, configs, groups, seeds)
        return
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
