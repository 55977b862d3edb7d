"""Warehouse scaling: every learner on the 8-, 16- and 32-AGV warehouses, against a planner that is not learned.

One row per map and algorithm, averaged over runs (each run in a fresh process with --jobs, so its peak memory
is its own; on a Dask cluster, --cluster, a worker plays run after run, and the peak is the process's
high-water mark reset at the run's start, so it can include what an earlier run left allocated):
- home at ep: the first checkpoint (every --check-every learning episodes) at which the greedy policy brings
  every AGV home with no collision ("-" if it never did);
- greedy: the greedy policy at the end: runs that got all home with no collision, and its sum of costs
  (the step each AGV arrived, summed; a stuck AGV counts the step cap) as a ratio to the planner's;
- states/agent: local plus joint states each learner conditions on at the end (JSA: its one table);
- peers/step: peer positions an agent needed per step of its own, over all learning;
- steps/s: joint steps per CPU second while learning; peak MiB: the run's peak resident memory.
JSA stops where its joint actions (4^n) outgrow a table, and a run stops after --budget CPU seconds of learning
and greedy checks:
the row says where.

    python benchmarks/bench_warehouse.py [--maps warehouse_8,warehouse_16,warehouse_32]
        [--algos indep,js,jsa,loc,cq] [--runs 3] [--episodes 2000] [--check-every 100] [--budget 600] [--jobs 2]
        [--cluster tcp://HOST:PORT] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import copy
import os
import platform
import sys
import time
from dataclasses import dataclass

from cq_ros.lab.cluster import ClusterError, scheduler_address
from cq_ros.engine import Team, make_learners, world_seed
from cq_ros.gridmap import load_map
from cq_ros.learners import ALGORITHMS
from cq_ros.learners.jsa import MAX_AGENTS
from cq_ros.mapf.planner import plan
from cq_ros.lab.runner import RunFailed, run_all
from cq_ros.settings import SettingsError, run_settings
from cq_ros.world import GridWorld

GREEDY_CAP = 500  # steps a greedy check may take; a warehouse's plan takes a few dozen


def greedy_play(team: Team) -> tuple[bool, int]:
    """One greedy episode on a copy of the team: (every AGV home without collision, sum of costs)."""
    greedy = copy.deepcopy(team)
    greedy.world.step_cap = GREEDY_CAP
    for learner in greedy.learners:
        learner.make_greedy()  # as the engine's greedy episodes: epsilon 0, frozen unless eval_learning
        learner.__dict__.pop("observe", None)  # the counting wrapper would call the original learner
    episode = greedy.episode()
    cost = sum(GREEDY_CAP if t is None else t for t in greedy.world.arrival)
    return greedy.world.finished and episode.collisions == 0, cost


@dataclass(frozen=True)
class BenchRun:
    map_name: str
    algo: str
    run: int
    episodes: int
    check_every: int
    budget: float
    seed: int
    overrides: tuple[str, ...]


def reset_peak_memory() -> None:
    """The process's high-water mark of resident memory set back to what it holds now (Linux 4.0 on)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass  # elsewhere the peak stays the process's own since it started


def peak_mib() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:")) / 1024


def one_run(job: BenchRun, on_episode) -> dict:
    reset_peak_memory()
    gridmap, run, seed = load_map(job.map_name), job.run, job.seed
    if job.algo == "jsa" and gridmap.n_agents > MAX_AGENTS:
        return {"stopped": f"4^{gridmap.n_agents} joint actions per joint state (at most {MAX_AGENTS} agents)"}
    settings = run_settings(gridmap, list(job.overrides))
    team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, run)),
                make_learners(job.algo, gridmap, settings, seed, run))
    looks = [0, 0]  # peer positions asked for, agent-steps

    def counted(observe):
        def observe_and_count(cell):
            need = observe(cell)
            looks[0] += len(need)
            looks[1] += 1
            return need
        return observe_and_count

    for learner in team.learners:
        learner.observe = counted(learner.observe)
    home_at, stopped, steps, learning = None, None, 0, 0.0
    begun = time.process_time()  # CPU seconds: the budget and the rate do not hang on the machine's load
    for episode in range(1, job.episodes + 1):
        started = time.process_time()
        steps += team.episode().steps
        learning += time.process_time() - started
        on_episode()
        if home_at is None and episode % job.check_every == 0 and greedy_play(team)[0]:
            home_at = episode
        if time.process_time() - begun > job.budget:  # greedy checks count: copying JS's tables is no small cost
            stopped = f"{job.budget:.0f} CPU s budget at episode {episode}"
            break
    home, cost = greedy_play(team)
    return {
        "home_at": home_at, "home": home, "cost": cost, "stopped": stopped,
        "states": sum(learner.state_count() for learner in team.learners) / len(team.learners),
        "peers": looks[0] / max(1, looks[1]) if not team.central else gridmap.n_agents - 1,
        "rate": steps / learning, "peak_mib": peak_mib(),
    }


def row(map_name: str, algo: str, results: list[dict], planned: int) -> str:
    done = [r for r in results if "home" in r]
    if not done:
        return f"| {map_name} | {algo} | stopped: {results[0]['stopped']} | | | | | | |"
    home_at = [r["home_at"] for r in done if r["home_at"] is not None]
    stopped = [r["stopped"] for r in done if r["stopped"]]

    def mean(key):
        return sum(r[key] for r in done) / len(done)

    home = f"{min(home_at)}-{max(home_at)}" if home_at else "never"
    return (f"| {map_name} | {algo} | {home} ({len(home_at)}/{len(done)}) | {sum(r['home'] for r in done)}/{len(done)} "
            f"| {mean('cost') / planned:.2f} | {mean('states'):,.0f} | {mean('peers'):.2f} "
            f"| {mean('rate'):,.0f} | {max(r['peak_mib'] for r in done):.0f} |"
            + (f" stopped: {stopped[0]}" if stopped else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", default="warehouse_8,warehouse_16,warehouse_32")
    parser.add_argument("--algos", default=",".join(ALGORITHMS))
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=2000)
    parser.add_argument("--check-every", type=int, default=100)
    parser.add_argument("--budget", type=float, default=600.0,
                        help="CPU seconds of learning and greedy checks per run at most")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=int, default=os.cpu_count())
    where.add_argument("--cluster", type=scheduler_address, metavar="ADDRESS",
                       help="run on the workers of a running Dask scheduler, tcp://HOST:PORT")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="change a setting over the maps' own (repeatable), as in cq-ros experiment")
    args = parser.parse_args()
    maps, algos = args.maps.split(","), args.algos.split(",")
    try:
        for name in maps:
            run_settings(load_map(name), args.overrides)
    except SettingsError as e:
        parser.error(str(e))

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
          f"{args.runs} runs x {args.episodes} episodes, greedy checked every {args.check_every}"
          + (f"; settings: {' '.join(args.overrides)}" if args.overrides else ""))
    planned = {}
    for name in maps:
        started = time.perf_counter()
        the_plan = plan(load_map(name))
        planned[name] = sum(the_plan.arrivals)
        print(f"{name}: planner ({the_plan.method}) makespan {max(the_plan.arrivals)}, sum of costs "
              f"{planned[name]} (at least {the_plan.lower_bound}), {time.perf_counter() - started:.1f} s")

    jobs = [BenchRun(m, a, r, args.episodes, args.check_every, args.budget, args.seed, tuple(args.overrides))
            for m in maps for a in algos for r in range(args.runs)]
    try:
        ran = run_all(jobs, one_run, args.jobs, args.cluster, label="runs", fresh_process=True)
    except RunFailed as e:
        sys.exit(f"{e.details}bench_warehouse: error: {e}")
    except ClusterError as e:
        sys.exit(f"bench_warehouse: error: {e}")
    results: dict[tuple[str, str], list[dict]] = {}
    for job, result in zip(jobs, ran.results):
        results.setdefault((job.map_name, job.algo), []).append(result)

    print("| map | algo | home at ep (runs) | greedy home | greedy cost / planner | states/agent | peers/step "
          "| steps/s | peak MiB |")
    print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for m in maps:
        for a in algos:
            print(row(m, a, results[(m, a)], planned[m]))


if __name__ == "__main__":
    main()
