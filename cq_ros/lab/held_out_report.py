"""The tables of a held-out study (study.md, also printed; `cq-ros study` and `report`), from OUT's files alone:
per size, per configuration the mean and 95% t interval over units (cq_ros.lab.study), the paired differences
from the first configuration, bootstrap intervals of ratios, and the curve of frozen greedy collisions.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .held_out_protocol import COPIES, KEY, TUNING_SEEDS, Config, generator_seeds, read_rows, seeds_of
from .study import Interval, makespan_ratio, mean_interval, paired_difference, ratio_interval

BOOTSTRAP_SEED = 0
# (label, unit column without its copy, digits) of the per-configuration tables
FIGURES = (("greedy collisions/ep", "collisions", 3), ("every AGV home", "home", 2), ("heard/ep", "heard", 1),
           ("makespan / planner's", "makespan_ratio", 2), ("states", "states", 0))


def shown_rows(out: Path, name: str) -> list[dict]:
    """The rows of OUT/NAME (units.csv, curve.csv or planner.csv) of the units the last command asked for
    (study.json's `shown`: its sizes, maps and runs); OUT may hold more, from a larger command before it. One
    row per unit and configuration (and curve point), the last written: a unit played again after a stop
    between its curve and its row (the same seeds, the same figures) counts once."""
    protocol = json.loads((out / "study.json").read_text())
    shown = protocol["shown"]
    seeds, sizes = set(seeds_of(protocol)[:shown["maps"]]), set(shown["sizes"])
    kept: dict[tuple, dict] = {}
    for r in read_rows(out / name):
        if r["agents"] in sizes and r["generator_seed"] in seeds and r["run"] < shown["runs"]:
            kept[tuple(r.get(k) for k in (*KEY, "episode"))] = r
    return list(kept.values())


def report(out: Path) -> str:
    """study.md, from OUT's files alone: the units of the sizes, maps, runs and configurations the last command
    asked for (study.json's `shown`), so that a page can show a kept study as the command printed it."""
    protocol = json.loads((out / "study.json").read_text())
    shown = protocol["shown"]
    sizes, maps, runs, command = (shown[k] for k in ("sizes", "maps", "runs", "command"))
    configs = [Config.of_record(protocol["configs"][name]) for name in shown["configs"]]
    mine, curve, planner = (shown_rows(out, name) for name in ("units.csv", "curve.csv", "planner.csv"))
    seconds = sum(r["seconds"] for r in mine)
    tuning = protocol.get("generator_seeds") == "tuning"
    seeds = generator_seeds(tuning)
    where = (f"Generator seeds {', '.join(map(str, seeds[:maps]))} (the tuning seeds, where settings are chosen; "
             "no figure here is a held-out result)" if tuning else
             f"Generator seeds {seeds[0]}-{seeds[maps - 1]} (held out; tuning seeds "
             f"{', '.join(map(str, TUNING_SEEDS))} never)")
    lines = [
        f"# {'Tuning' if tuning else 'Held-out'} study", "", f"Command: `{command}`", "",
        f"{where}, slip {protocol['slip']:g}; learner seed {protocol['seed']}, runs "
        f"0-{runs - 1}; {protocol['episodes']} learning episodes per configuration, then from that run "
        f"{protocol['greedy_episodes']} greedy episodes frozen (eval_learning=0, the primary figure) and "
        f"{protocol['greedy_episodes']} learning (eval_learning=1); the curve: {protocol['curve_episodes']} frozen "
        f"greedy episodes every {protocol['curve_every']}. Units played in {seconds:.0f} s (summed over units). "
        "A unit is one map and one run; mean ± half-width of the 95% t interval over units; ratios with bootstrap "
        f"95% intervals (units resampled, seed {BOOTSTRAP_SEED}).",
        *(f"Settings of {c.name}: {' '.join(c.sets)}" for c in configs if c.sets),
    ]
    for agents in sizes:
        lines += size_tables(agents, [r for r in mine if r["agents"] == agents], configs,
                             [p for p in planner if p["agents"] == agents])
        lines += curve_table([r for r in curve if r["agents"] == agents], configs)
    return "\n".join(lines) + "\n"


def unit_values(rows: list[dict], config: str, column: str, units: Sequence[tuple] | None = None) -> list[float]:
    """Each unit's figure for one configuration, in the units' order: of every unit it played, or of `units`
    ((generator_seed, run) pairs) where given, so that two configurations' lists pair unit by unit even where
    one has played units the other has not (a study resumed with a new configuration, stopped part way)."""
    played = {(r["generator_seed"], r["run"]): r for r in rows if r["config"] == config}
    mine = [played[u] for u in (sorted(played) if units is None else units)]
    if column.endswith("makespan_ratio"):
        copy = column.split("_")[0]
        return [r[f"{copy}_makespan"] / r["planner_makespan"] for r in mine]
    return [r[column] for r in mine]


def size_tables(agents: int, rows: list[dict], configs: Sequence[Config], planner: list[dict]) -> list[str]:
    """The tables of one fleet size: `rows` its units, `planner` its executions of the plan."""
    def column(copy: str, name: str) -> str:
        return name if name == "states" else f"{copy}_{name}"

    def figure(config: str, copy: str, name: str) -> Interval:
        if name == "makespan_ratio":
            return makespan_ratio(unit_values(rows, config, f"{copy}_makespan"),
                                  unit_values(rows, config, "planner_makespan"))
        return mean_interval(unit_values(rows, config, column(copy, name)))

    present = [c for c in configs if any(r["config"] == c.name for r in rows)]
    units = len({(r["generator_seed"], r["run"]) for r in rows})
    header = " | ".join(label for label, _, _ in FIGURES)
    lines = ["", f"## {agents} AGVs: {units} units", "",
             f"The planner's plan executed under the same delays: makespan "
             f"{mean_interval([p['makespan'] for p in planner]).show(1)}, collisions "
             f"{mean_interval([p['collisions'] for p in planner]).show(2)}, messages "
             f"{mean_interval([p['messages'] for p in planner]).show(1)}, every AGV home in "
             f"{sum(int(p['home']) for p in planner)} of {len(planner)}."]
    if not present:
        return lines
    first = present[0].name
    # paired figures over the units every configuration played, the same units in the same order for each
    shared = sorted(set.intersection(*({(r["generator_seed"], r["run"]) for r in rows if r["config"] == c.name}
                                       for c in present)))
    over = "" if len(shared) == units else f" (over the {len(shared)} units every configuration played)"

    def paired(config: str, name: str) -> list[float]:
        return unit_values(rows, config, name, shared)

    for copy in COPIES:
        lines += ["", f"Greedy policy, {copy}:", "", f"| configuration | {header} |",
                  "| --- |" + " ---: |" * len(FIGURES)]
        lines += [f"| {c.name} | " + " | ".join(figure(c.name, copy, n).show(d) for _, n, d in FIGURES) + " |"
                  for c in present]
        # A few units whose AGVs stall against each other until the step cap (colliding at every step) can carry
        # the mean: the median and the units always home say how many.
        lines += ["", "Median over units of greedy collisions/ep: " + ", ".join(
            f"{c.name} {np.median(unit_values(rows, c.name, f'{copy}_collisions')):.3f}" for c in present)
            + "; units in which every greedy episode brought every AGV home: " + ", ".join(
            f"{c.name} {sum(v == 1 for v in unit_values(rows, c.name, f'{copy}_home'))} of {units}" for c in present)
            + "."]
        if len(present) < 2:
            continue
        lines += ["", f"Paired differences, {copy}{over}:", "", f"| configuration | {header} |",
                  "| --- |" + " ---: |" * len(FIGURES)]
        lines += [f"| {c.name} - {first} | " + " | ".join(
            paired_difference(paired(c.name, column(copy, n)), paired(first, column(copy, n))).show(d)
            for _, n, d in FIGURES) + " |" for c in present[1:]]
        lines += ["", f"Ratios of means, {copy} (bootstrap 95%){over}:", "",
                  f"| configuration | collisions: it / {first} | heard: {first} / it |", "| --- | ---: | ---: |"]
        lines += [f"| {c.name} | "
                  + show_ratio(ratio_interval(paired(c.name, f"{copy}_collisions"), paired(first, f"{copy}_collisions"),
                                              BOOTSTRAP_SEED)) + " | "
                  + show_ratio(ratio_interval(paired(first, f"{copy}_heard"), paired(c.name, f"{copy}_heard"),
                                              BOOTSTRAP_SEED))
                  + " |" for c in present[1:]]
    return lines


def converged_at(points: dict[int, list[float]]) -> int:
    """The first episode from which every point's mean lies inside the last point's 95% interval."""
    episodes = sorted(points)
    last = mean_interval(points[episodes[-1]])
    at = episodes[-1]
    for e in reversed(episodes):
        mean = float(np.mean(points[e]))
        if not (last.low <= mean <= last.high or mean == last.mean):
            break
        at = e
    return at


def curve_table(rows: list[dict], configs: Sequence[Config]) -> list[str]:
    """Frozen greedy collisions per episode against learning episodes, mean over units, per configuration."""
    present = [c.name for c in configs if any(r["config"] == c.name for r in rows)]
    if not present:
        return []
    points = {c: {} for c in present}
    for r in sorted(rows, key=lambda r: (r["generator_seed"], r["run"])):
        if r["config"] in points:
            points[r["config"]].setdefault(int(r["episode"]), []).append(r["collisions"])
    episodes = sorted({e for p in points.values() for e in p})
    lines = ["", "Frozen greedy collisions per episode against learning episodes (mean over units; the last "
             "row is the table's):", "", "| episode | " + " | ".join(present) + " |",
             "| ---: |" + " ---: |" * len(present)]
    lines += [f"| {e} | " + " | ".join(f"{np.mean(points[c][e]):.3f}" if e in points[c] else "-" for c in present)
              + " |" for e in episodes]
    lines += ["", "Inside the last point's 95% interval from episode on: "
              + ", ".join(f"{c} {converged_at(points[c])}" for c in present) + "."]
    return lines


def show_ratio(r: Interval) -> str:
    """A ratio and its interval; none where the denominator's mean is 0 (what indep hears, say)."""
    if math.isinf(r.mean):
        return "- (divides by 0)"
    return f"{r.mean:.2f} ({r.low:.2f} to {r.high:.2f})"
