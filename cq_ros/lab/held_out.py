"""`cq-ros study`: learners judged on delayed warehouses that no setting was tuned on, against the planner.

Per fleet size, `maps` warehouses generated from held-out generator seeds (HELD_OUT_SEEDS; the tuning seeds,
TUNING_SEEDS, are refused) x `runs` runs: a unit is one map and one run, in which every configuration meets the
same delays. Every configuration learns for the same `episodes`, then its greedy policy plays `greedy_episodes`
episodes FROZEN (`eval_learning=0`: what a deployed fleet does, the primary figure) and, in a second run of the
same seeds, on a greedy copy that goes on learning (`eval_learning=1`, beside it). The planner's plan is carried
out under the same delays (cq_ros.mapf.execute: execution r draws run r's delays), the yardstick of makespans.
The runs play through the lab (cq_ros.lab.experiment.run_jobs), on whichever engine it plays.

It prints, and writes to OUT/study.md, per size: per configuration the mean and 95% t interval over units
(cq_ros.lab.study) of greedy collisions and peer positions heard per episode, the every-AGV-home rate, the
greedy makespan over the planner's executed makespan, and the states at the end of learning; the paired
differences from the first configuration; bootstrap intervals of the ratios of collisions (each / the first) and
of heard (the first / each); OUT/units.csv keeps every unit's figures, OUT/maps/ the maps.
"""

from __future__ import annotations

import csv
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..gridmap import load_map
from ..mapf.execute import execute
from ..mapf.planner import plan
from ..mapgen.warehouse import warehouse_text
from ..settings import Settings, run_settings_and_presets
from .experiment import Job, run_jobs
from .results import prepare_output
from .study import Interval, home_rate, makespan_ratio, mean_interval, paired_difference, ratio_interval

# Generator seeds: those the settings were chosen on (docs/choices.md), and the block the study draws from,
# which no document, test or tuning run names (map i of a size is HELD_OUT_SEEDS[i]).
TUNING_SEEDS = (0, 7)
HELD_OUT_SEEDS = range(1001, 1101)
BOOTSTRAP_SEED = 0
COPIES = ("frozen", "learning")  # eval_learning 0 and 1
# (label, unit column, digits) of the per-configuration tables
FIGURES = (("greedy collisions/ep", "collisions", 3), ("every AGV home", "home", 2), ("heard/ep", "heard", 1),
           ("makespan / planner's", "makespan_ratio", 2), ("states", "states", 0))


@dataclass(frozen=True)
class Config:
    name: str
    algo: str
    preset: str | None = None


def parse_configs(algos: Sequence[str], paper: bool) -> list[Config]:
    """The learners by name, and with `paper` the paper's CQ (algo cq, preset paper) as `cq_paper`."""
    return [Config(a, a) for a in algos] + ([Config("cq_paper", "cq", "paper")] if paper else [])


def generated(out: Path, agents: int, seed: int, slip: float) -> Path:
    """The warehouse `cq-ros generate warehouse --agents AGENTS --seed SEED --slip SLIP` makes, kept in OUT/maps."""
    path = out / "maps" / f"warehouse_{agents}_gen{seed}.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(warehouse_text(agents, seed=seed, slip=slip))
    return path


def study(out: Path, sizes: Sequence[int], maps: int, runs: int, episodes: int, greedy_episodes: int,
          configs: Sequence[Config], seed: int = 0, slip: float = 0.1, overrides: Sequence[str] = (),
          workers: int | None = None, cluster: str | None = None, learning_copy: bool = True, force: bool = False,
          command: str = "") -> str:
    """Play the study and write OUT/study.md, OUT/units.csv and the maps; returns the tables printed."""
    if maps > len(HELD_OUT_SEEDS):
        raise ValueError(f"--maps takes at most {len(HELD_OUT_SEEDS)} (the held-out generator seeds), got {maps}")
    out = prepare_output(out, force)
    started = time.perf_counter()
    copies = COPIES if learning_copy else COPIES[:1]
    units = [(agents, HELD_OUT_SEEDS[i], r) for agents in sizes for i in range(maps) for r in range(runs)]
    paths = {(a, g): generated(out, a, g, slip) for a, g in dict.fromkeys((a, g) for a, g, _ in units)}
    jobs: dict[tuple, Job] = {}
    presets: dict[tuple, dict] = {}
    for (agents, g), path in paths.items():
        for c in configs:
            for copy in copies:
                wanted = [*overrides, f"eval_learning={COPIES.index(copy)}", f"eval_episodes={greedy_episodes}"]
                settings, presets[(c.name, copy)] = run_settings_and_presets(load_map(path), wanted, c.preset)
                for r in range(runs):
                    jobs[(agents, g, r, c.name, copy)] = Job(str(path), c.algo, r, episodes, seed, settings)
    planner = planned(paths, runs, seed, overrides)
    results, _ = run_jobs(list(jobs.values()), workers, label="study", cluster=cluster)
    rows = [unit_row(key, results[job], planner[key[:3]]) for key, job in jobs.items()]
    with open(out / "units.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    text = "\n".join([
        "# Held-out study", "", f"Command: `{command}`", "",
        f"Generator seeds {HELD_OUT_SEEDS[0]}-{HELD_OUT_SEEDS[maps - 1]} (held out; tuning seeds "
        f"{', '.join(map(str, TUNING_SEEDS))} never), slip {slip:g}; learner seed {seed}, runs 0-{runs - 1}; "
        f"{episodes} learning episodes, then {greedy_episodes} greedy episodes "
        + ("frozen and, in a second run of the same seeds, learning" if learning_copy else "frozen")
        + f"; {time.perf_counter() - started:.0f} s. A unit is one map and one run; mean ± half-width of the 95% "
        "t interval over units; ratios with bootstrap 95% intervals (units resampled, seed "
        f"{BOOTSTRAP_SEED}).",
        *(f"Preset {name} for {config} ({copy}): " + " ".join(f"{k}={v}" for k, v in set_.items())
          for (config, copy), applied in presets.items() if copy == "frozen" for name, set_ in applied.items()),
        *(line for agents in sizes for line in size_tables(agents, rows, configs, copies, planner)),
    ]) + "\n"
    (out / "study.md").write_text(text)
    return text


def planned(paths: dict[tuple[int, int], Path], runs: int, seed: int,
            overrides: Sequence[str]) -> dict[tuple[int, int, int], dict]:
    """The planner's plan of each map executed in run r's delays: {(agents, generator seed, run): figures}."""
    found = {}
    for n, ((agents, g), path) in enumerate(sorted(paths.items())):
        print(f"study: planning {path.name} ({n + 1}/{len(paths)})", file=sys.stderr, flush=True)
        gridmap = load_map(path)
        the_plan = plan(gridmap)
        settings: Settings = run_settings_and_presets(gridmap, overrides)[0]
        for r in range(runs):
            done = execute(the_plan, gridmap, settings, seed, r)
            makespan = max(len(p) - 1 if a is None else a for p, a in zip(done.paths, done.arrivals))
            found[(agents, g, r)] = {"makespan": makespan, "collisions": done.collisions,
                                     "messages": done.messages, "home": done.home}
    return found


def unit_row(key: tuple, result, planner: dict) -> dict:
    agents, g, r, config, copy = key
    greedy, episodes = result.greedy, result.episodes
    tail = max(1, len(episodes) // 10)
    makespan = float(greedy["steps"].mean())
    return {"agents": agents, "generator_seed": g, "run": r, "config": config, "copy": copy,
            "collisions": float(greedy["collisions"].mean()), "home": home_rate(greedy["truncated"]),
            "heard": float(greedy["heard"].mean()), "makespan": makespan,
            "planner_makespan": planner["makespan"],
            "states": float(episodes["states"][-1]),
            "exploring_collisions": float(episodes["collisions"][-tail:].mean())}


def size_tables(agents: int, rows: list[dict], configs: Sequence[Config], copies: Sequence[str],
                planner: dict) -> list[str]:
    """The tables of one fleet size."""
    def values(config: str, copy: str, column: str) -> list[float]:
        """Each unit's figure, in the units' order (the same for every configuration)."""
        mine = [row for row in rows if (row["agents"], row["config"], row["copy"]) == (agents, config, copy)]
        if column == "makespan_ratio":
            return [row["makespan"] / row["planner_makespan"] for row in mine]
        return [row[column] for row in mine]

    def figure(config: str, copy: str, column: str) -> Interval:
        if column == "makespan_ratio":
            return makespan_ratio(values(config, copy, "makespan"), values(config, copy, "planner_makespan"))
        return mean_interval(values(config, copy, column))

    mine = [p for (a, _, _), p in sorted(planner.items()) if a == agents]
    header = " | ".join(label for label, _, _ in FIGURES)
    lines = ["", f"## {agents} AGVs: {len(mine)} units", "",
             f"The planner's plan executed under the same delays: makespan "
             f"{mean_interval([p['makespan'] for p in mine]).show(1)}, collisions "
             f"{mean_interval([p['collisions'] for p in mine]).show(2)}, messages "
             f"{mean_interval([p['messages'] for p in mine]).show(1)}, every AGV home in "
             f"{sum(p['home'] for p in mine)} of {len(mine)}."]
    first = configs[0].name
    for copy in copies:
        lines += ["", f"Greedy policy, {copy}:", "", f"| configuration | {header} |",
                  "| --- |" + " ---: |" * len(FIGURES)]
        lines += [f"| {c.name} | " + " | ".join(figure(c.name, copy, col).show(d) for _, col, d in FIGURES) + " |"
                  for c in configs]
        if len(configs) < 2:
            continue
        lines += ["", f"Paired differences, {copy}:", "", f"| configuration | {header} |",
                  "| --- |" + " ---: |" * len(FIGURES)]
        lines += [f"| {c.name} - {first} | " + " | ".join(
            paired_difference(values(c.name, copy, col), values(first, copy, col)).show(d) for _, col, d in FIGURES)
            + " |" for c in configs[1:]]
        lines += ["", f"Ratios of means, {copy} (bootstrap 95%):", "",
                  f"| configuration | collisions: it / {first} | heard: {first} / it |", "| --- | ---: | ---: |"]
        lines += [f"| {c.name} | "
                  + _ratio(ratio_interval(values(c.name, copy, "collisions"), values(first, copy, "collisions"),
                                          BOOTSTRAP_SEED)) + " | "
                  + _ratio(ratio_interval(values(first, copy, "heard"), values(c.name, copy, "heard"), BOOTSTRAP_SEED))
                  + " |" for c in configs[1:]]
    return lines


def _ratio(r: Interval) -> str:
    return f"{r.mean:.2f} ({r.low:.2f} to {r.high:.2f})"

