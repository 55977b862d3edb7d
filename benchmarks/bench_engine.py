"""Offline engine speed: the compiled engine against the reference (Python) engine in the same run, CPU time
per agent-step (a joint step's CPU time over the fleet) of indep and CQ on tunnel_to_goal and warehouse_16,
medians of interleaved repeats, their ratio, and whether both gave the same episodes; then, on `--engine`
(default compiled), the joint steps per second of every algorithm on the two tunnels (one core, one run each,
learning only: no greedy evaluation), CQ's ratio to independent learners, and the CPU per agent-step of indep
and CQ on warehouse_8, _16 and _32 with the maps' own settings, with its ratio of warehouse_32 to warehouse_8
(1.0 for a step linear in the fleet); optionally the wall time of the whole reproduce grid on all cores.
`--limit` prints, instead, the limit under the compiled engine: on warehouse_16 and tunnel_to_goal, indep and
CQ, the CPU per agent-step of the reference engine, the compiled engine, the compiled world alone (learners
taken out: it replays the joint actions the learners chose, the same episodes) and the leanest kernel of the
same rules and learning dynamics (benchmarks/lean_kernel.py, which says what it drops), medians of interleaved
repeats, and their ratios. `--process` prints, instead, whole processes: the wall and CPU seconds of
`cq-ros experiment --map tunnel_to_goal --algo cq --runs 1 --episodes 5000` on each engine, start-up and output
included, with and without figures, beside its floor: the same command at 1 episode without greedy ones
(start-up and output alone), and the imports alone.

    python benchmarks/bench_engine.py [--episodes 3000] [--warehouse-episodes 30] [--repeats 3]
                                      [--engine compiled|reference] [--grid] [--grid-episodes 10000] [--limit]
                                      [--process]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cq_ros import compiled
from cq_ros.gridmap import load_map
from cq_ros.learners import ALGORITHMS
from cq_ros.settings import Settings, run_settings

WAREHOUSES = ("warehouse_8", "warehouse_16", "warehouse_32")
COMPARED = (("tunnel_to_goal", "indep"), ("tunnel_to_goal", "cq"), ("warehouse_16", "indep"), ("warehouse_16", "cq"))


def steps_per_second(algo: str, map_name: str, episodes: int, engine: str, seed: int = 0) -> tuple[float, int]:
    gridmap = load_map(map_name)
    started = time.perf_counter()
    table = compiled.play(algo, gridmap, Settings(eval_episodes=0), seed, 0, episodes, engine=engine).episodes
    seconds = time.perf_counter() - started
    steps = int(table["steps"].sum())
    return steps / seconds, steps


def cpu_per_agent_step(algo: str, map_name: str, episodes: int, engine: str, seed: int = 0):
    """Nanoseconds of this process's CPU per agent-step (CPU time, not wall: other sessions' load on the
    machine moves it less), the joint steps played, and the episodes' table."""
    gridmap = load_map(map_name)
    started = time.process_time()
    table = compiled.play(algo, gridmap, run_settings(gridmap, {"eval_episodes": 0}), seed, 0, episodes,
                          engine=engine).episodes
    seconds = time.process_time() - started
    steps = int(table["steps"].sum())
    return seconds / (steps * gridmap.n_agents) * 1e9, steps, table


def compare(episodes: dict[str, int], repeats: int) -> None:
    """Both engines on the same runs, interleaved, `repeats` times: medians, ratio, same episodes."""
    for map_name, algo in COMPARED:
        cost: dict[str, list[float]] = {"reference": [], "compiled": []}
        tables = {}
        for _ in range(repeats):
            for engine in cost:
                ns, steps, tables[engine] = cpu_per_agent_step(algo, map_name, episodes[map_name], engine)
                cost[engine].append(ns)
        ref, comp = statistics.median(cost["reference"]), statistics.median(cost["compiled"])
        same = tables["reference"].tobytes() == tables["compiled"].tobytes()
        print(f"{map_name:<17} {algo:<6} reference {ref:>8,.0f} ns, compiled {comp:>6,.1f} ns CPU per agent-step: "
              f"{ref / comp:>5,.0f}x  ({steps:,} joint steps, {episodes[map_name]} episodes, same episodes: "
              f"{'yes' if same else 'NO'})", flush=True)


def limit(episodes: dict[str, int], repeats: int) -> None:
    """The reference, our compiled engine, the compiled world alone and the lean kernel on the same work,
    interleaved `repeats` times: medians of CPU ns per agent-step and their ratios."""
    from lean_kernel import lean_run, recorded_actions, world_alone

    for map_name in ("warehouse_16", "tunnel_to_goal"):  # load (or compile) the lean kernels, not timed
        gridmap = load_map(map_name)
        lean_run("cq", gridmap, run_settings(gridmap, {}), 1)
        world_alone(gridmap, run_settings(gridmap, {}), *recorded_actions("indep", gridmap, Settings(), 1))
    print(f"{'map':<15} {'algo':<6} {'reference':>10} {'compiled':>9} {'world':>7} {'lean':>7}   "
          f"ns CPU per agent-step, medians of {repeats}; ratios")
    for map_name, algo in (("warehouse_16", "indep"), ("warehouse_16", "cq"), ("tunnel_to_goal", "indep"),
                           ("tunnel_to_goal", "cq")):
        gridmap = load_map(map_name)
        settings, n = run_settings(gridmap, {"eval_episodes": 0}), gridmap.n_agents
        cost: dict[str, list[float]] = {"reference": [], "compiled": [], "world": [], "lean": []}
        actions, lengths = recorded_actions(algo, gridmap, settings, episodes[map_name])
        lean_steps = 0
        for r in range(repeats):
            for engine in ("reference", "compiled"):
                ns, steps, table = cpu_per_agent_step(algo, map_name, episodes[map_name], engine)
                cost[engine].append(ns)
            started = time.process_time()
            replayed = world_alone(gridmap, settings, actions, lengths) == table["collisions"].sum()
            cost["world"].append((time.process_time() - started) / (steps * n) * 1e9)
            started = time.process_time()
            lean_steps = int(lean_run(algo, gridmap, settings, episodes[map_name], seed=r)[:, 0].sum())
            cost["lean"].append((time.process_time() - started) / (lean_steps * n) * 1e9)
            print(f"  {map_name} {algo} repeat {r + 1}/{repeats}: "
                  + ", ".join(f"{k} {v[-1]:,.1f}" for k, v in cost.items()), file=sys.stderr, flush=True)
        ref, comp, world, lean = (statistics.median(cost[k]) for k in cost)
        print(f"{map_name:<15} {algo:<6} {ref:>10,.0f} {comp:>9,.1f} {world:>7,.1f} {lean:>7,.1f}   "
              f"reference/compiled {ref / comp:,.0f}x, reference/lean {ref / lean:,.0f}x, compiled/lean "
              f"{comp / lean:.2f}x, world alone {world / comp:.0%} of compiled  ({steps:,} joint steps "
              f"compiled, {lean_steps:,} lean, {episodes[map_name]} episodes; the world alone replays the run's "
              f"collisions: {'yes' if replayed else 'NO'})", flush=True)


def whole_processes(repeats: int) -> None:
    """Wall and CPU seconds (medians of interleaved repeats) of whole `cq-ros experiment` processes on each engine,
    and of their floor: the command at 1 episode without greedy ones (start-up and output) and the imports alone."""
    experiment = [sys.executable, "-m", "cq_ros.cli", "experiment", "--map", "tunnel_to_goal", "--algo", "cq",
                  "--runs", "1", "--force", "--out"]
    cases = {}
    for engine in compiled.ENGINES:
        for label, episodes, tail in (("5000 episodes", 5000, []),
                                      ("5000 episodes, --no-figures", 5000, ["--no-figures"]),
                                      ("1 episode, no greedy ones, --no-figures", 1,
                                       ["--no-figures", "--set", "eval_episodes=0"])):
            cases[f"experiment {label}, {engine}"] = (experiment, ["--episodes", str(episodes), "--engine", engine,
                                                                   *tail])
    for module in ("cq_ros.cli.main", "numba", "cq_ros.compiled.engine"):
        cases[f"python -c 'import {module}'"] = ([sys.executable, "-c", f"import {module}"], None)
    wall: dict[str, list[float]] = {name: [] for name in cases}
    cpu: dict[str, list[float]] = {name: [] for name in cases}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(repeats):
            for name, (head, tail) in cases.items():
                command = head if tail is None else [*head, str(Path(tmp) / "out"), *tail]
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                started = time.perf_counter()
                subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                wall[name].append(time.perf_counter() - started)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu[name].append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
            print(f"repeat {r + 1}/{repeats} done", file=sys.stderr, flush=True)
    for name in cases:
        print(f"{name:<62} {statistics.median(wall[name]):6.2f} s wall {statistics.median(cpu[name]):6.2f} s CPU")
    for tail in ("", ", --no-figures"):
        ratio = statistics.median(wall[f"experiment 5000 episodes{tail}, reference"]) / statistics.median(
            wall[f"experiment 5000 episodes{tail}, compiled"])
        print(f"reference / compiled, 5000 episodes{tail}: {ratio:.2f}x wall")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=3000)
    parser.add_argument("--warehouse-episodes", type=int, default=30)
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats of the comparison (median)")
    parser.add_argument("--engine", choices=compiled.ENGINES, default="compiled",
                        help="the engine of the tables after the comparison")
    parser.add_argument("--grid", action="store_true", help="also time the full reproduce grid (minutes)")
    parser.add_argument("--grid-runs", type=int, default=10)
    parser.add_argument("--grid-episodes", type=int, default=10_000)
    parser.add_argument("--limit", action="store_true",
                        help="only the limit: reference, compiled, world alone and the lean kernel side by side")
    parser.add_argument("--process", action="store_true",
                        help="only whole processes: cq-ros experiment on each engine beside its start-up floor")
    args = parser.parse_args()

    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
          f"load average {os.getloadavg()[0]:.2f}")
    started = time.perf_counter()
    if not compiled.prepare():
        raise SystemExit("the compiled engine cannot load here: nothing to compare")
    print(f"compiled engine loaded in {time.perf_counter() - started:.1f} s")
    if args.process:
        whole_processes(args.repeats)
        print(f"load average {os.getloadavg()[0]:.2f}")
        return
    if args.limit:
        limit({"tunnel_to_goal": args.episodes, "warehouse_16": args.warehouse_episodes}, args.repeats)
        print(f"load average {os.getloadavg()[0]:.2f}")
        return
    compare({"tunnel_to_goal": args.episodes, "warehouse_16": args.warehouse_episodes}, args.repeats)

    print(f"engine: {args.engine}")
    for map_name in ("tunnel_to_goal", "tunnel_to_goal_3"):
        rates = {}
        for algo in ALGORITHMS:
            rates[algo], steps = steps_per_second(algo, map_name, args.episodes, args.engine)
            print(f"{map_name:<17} {algo:<6} {rates[algo]:>12,.0f} joint steps/s  "
                  f"({steps:,} steps, {args.episodes} episodes, {compiled.engine_of(algo, args.engine)})")
        print(f"{map_name:<17} cq/indep speed ratio: {rates['cq'] / rates['indep']:.2f}")

    for algo in ("indep", "cq"):
        cost = {}
        for map_name in WAREHOUSES:
            cost[map_name], steps, _ = cpu_per_agent_step(algo, map_name, args.warehouse_episodes, args.engine)
            print(f"{map_name:<17} {algo:<6} {cost[map_name]:>10,.1f} ns CPU per agent-step  "
                  f"({steps:,} joint steps, {args.warehouse_episodes} episodes)", flush=True)
        print(f"warehouse_32 / warehouse_8 {algo:<6} cost per agent-step: "
              f"{cost['warehouse_32'] / cost['warehouse_8']:.2f}x")
    print(f"load average {os.getloadavg()[0]:.2f}")

    if args.grid:
        from cq_ros.lab.reproduce import reproduce

        with tempfile.TemporaryDirectory() as out:
            started = time.perf_counter()
            reproduce(Path(out) / "grid", args.grid_runs, args.grid_episodes, seed=0, settings=Settings(),
                      sweep=False, figures=False, engine=args.engine)
            print(f"reproduce grid ({args.grid_runs} runs x {args.grid_episodes} episodes, 4 maps x 5 algorithms, "
                  f"no sweep, no figures, {args.engine} engine): {time.perf_counter() - started:.0f} s wall on "
                  f"{os.cpu_count()} cores")


if __name__ == "__main__":
    main()
