"""`cq-ros plan`: plan every AGV's route centrally (cq_ros.mapf.planner), replay it through the world, and
execute it under the world's delays over seeded executions (cq_ros.mapf.execute): the learners' yardstick."""

from __future__ import annotations

import sys
import time

from tqdm import tqdm

from ..gridmap import ACTIONS, load_map
from ..mapf.execute import (
    dependencies,
    execute_many,
    moves_can_fail,
    spread,
    stall_risk,
)
from ..mapf.planner import NoPlan, OutOfTime, PlanError, distances_to, plan, validate
from ..settings import Settings, run_settings


def run(args) -> int:
    """The command, from its parsed arguments (cq_ros.cli.offline_parser builds the parser): 0, or 1 without a plan."""
    gridmap = load_map(args.map)
    delays = [f"{key}={value}" for key, value in (("slip", args.slip), ("start_hold", args.start_hold))
              if value is not None]
    settings = run_settings(gridmap, args.overrides + delays)  # checked before the search starts
    started = time.perf_counter()
    progress = PlanProgress()
    try:
        result = plan(gridmap, args.seed, args.cbs_nodes, args.orders, args.rounds, progress, args.time_limit)
    except OutOfTime as e:
        print(f"cq-ros plan: {e} (--time-limit gives it longer)", file=sys.stderr)
        return 1
    except NoPlan as e:
        print(f"cq-ros plan: {e} (--cbs-nodes and --orders search longer)", file=sys.stderr)
        return 1
    finally:
        progress.close()
    seconds = time.perf_counter() - started
    try:
        arrivals = validate(gridmap, result)
    except PlanError as e:
        print(f"cq-ros plan: the world rejects the plan (a planner bug): {e}", file=sys.stderr)
        return 1
    alone = sum(distances_to(gridmap, goal)[start] for start, goal in zip(gridmap.starts, gridmap.goals))
    least = "the least possible" if result.optimal else f"the least possible is at least {result.lower_bound}"
    print(f"{gridmap.name}: {gridmap.n_agents} agents, {result.method}")
    print(f"makespan {result.makespan}, sum of costs {result.sum_of_costs} ({least}; each agent alone: {alone:g})")
    print("arrival steps: " + ", ".join(f"agv{i + 1} {step}" for i, step in enumerate(arrivals)))
    print(f"planning time {seconds:.2f} s; replayed through the world: every agent at its goal, no collision")
    if args.show:
        for i, (path, actions) in enumerate(zip(result.paths, result.actions)):
            moves = "".join(ACTIONS[a][0] if b != a_cell else ACTIONS[a][0].lower()
                            for a, a_cell, b in zip(actions, path, path[1:]))
            print(f"agv{i + 1} {gridmap.cells[path[0]]} -> {gridmap.cells[path[-1]]}: {moves or '(at its goal)'}")
    if args.executions:
        _print_executions(result, gridmap, settings, args.seed, args.executions, args.stop_anywhere)
    return 0


def _print_executions(the_plan, gridmap, settings: Settings, seed: int, runs: int, stop_anywhere: bool) -> None:
    progress = PlanProgress()
    try:
        executions = execute_many(the_plan, gridmap, settings, seed, runs,
                                  lambda done: progress("executions", done, runs), stop_anywhere)
    finally:
        progress.close()
    how = ("the action dependency graph keeps the plan's order at every shared cell" if moves_can_fail(settings)
           else "no move can fail, so the AGVs follow the plan's clock")
    if stop_anywhere and moves_can_fail(settings):
        how += ", and an AGV may wait where no wall is (sending no action)"
    print(f"\n{runs} executions (seed {seed}, runs 0-{runs - 1}) with slip {settings.slip:g}, start_hold "
          f"{settings.start_hold}: {how}")
    print(f"{'':<14} {'mean':>8} {'min':>6} {'max':>6}")
    notes = {"waits": "wall bumps while waiting", "held": "steps staying where no wall is, no action sent",
             "stalls": "AGVs waiting on each other in a cycle, one sets out under the bare ADG",
             "delays": "moves the delays failed", "messages": "one per cross-agent dependency, on leaving the cell"}
    for name, figure in spread(executions).items():
        label = name.replace("_", " ")
        if figure is None:
            print(f"{label:<14} {'-':>8} {'-':>6} {'-':>6}")
        else:
            print(f"{label:<14} {figure.mean:>8.2f} {figure.low:>6g} {figure.high:>6g}  {notes.get(name, '')}".rstrip())
    home = sum(e.home for e in executions)
    print(f"every AGV home in {home} of {runs}; stuck {sum(e.stuck for e in executions)}, "
          f"truncated at the step cap {sum(e.truncated for e in executions)}")
    if moves_can_fail(settings):
        cycle = stall_risk(dependencies(gridmap, the_plan, stop_anywhere))
        print("the stretches between wait cells wait on each other in no cycle: no execution stalls" if not cycle
              else "the stretches of " + ", ".join(f"agv{i + 1}" for i in cycle) + " wait on each other in a "
              "cycle: an execution can stall")


class PlanProgress:
    """The planner's progress on stderr: a tqdm bar per phase on a terminal, a plain line at most every 30 s
    elsewhere."""

    def __init__(self):
        self.tty = sys.stderr.isatty()
        self.bar = None
        self.phase = None
        self.last_line = time.monotonic()

    def __call__(self, phase: str, done: int, total: int) -> None:
        if self.tty:
            if phase != self.phase:
                self.close()
                self.bar = tqdm(total=total, desc=f"plan: {phase}", leave=False)
            self.bar.update(done - self.bar.n)
        elif time.monotonic() - self.last_line >= 30:
            print(f"cq-ros plan: {phase} {done}/{total}", file=sys.stderr, flush=True)
            self.last_line = time.monotonic()
        self.phase = phase

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
