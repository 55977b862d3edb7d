"""`cq-ros study`: learners judged on delayed warehouses that no setting was tuned on, against the planner.

Per fleet size, `maps` warehouses generated from held-out generator seeds (HELD_OUT_SEEDS; the tuning seeds,
TUNING_SEEDS, are never among them; with `tuning`, from the tuning seeds instead, where settings are chosen) x
`runs` runs: a unit is one map and one run, in which every configuration meets the same delays and learns for the
same `episodes`. From that ONE learning run, two greedy copies play
`greedy_episodes` episodes each: one FROZEN (`eval_learning=0`: what a deployed fleet does, the primary figure)
and one that goes on learning (`eval_learning=1`, beside it). Every `curve_every` learning episodes a frozen greedy
copy plays `curve_episodes` episodes: the curve of greedy collisions against episodes, which shows where each
learner has converged (its last point is the frozen copy's figure). The copies are deep copies, so the learning
run is the one `cq-ros experiment` plays with the same seeds. The planner's plan is carried out under the same
delays (cq_ros.mapf.execute: execution r draws run r's delays), the yardstick of makespans. The units play
through the lab's runner (cq_ros.lab.runner), on the compiled engine where it plays the learner.

OUT keeps: units.csv (one row per unit and configuration, written as each finishes: a rerun with the same protocol
plays only the units missing, so a study resumes, or grows by maps, runs, sizes or configurations), curve.csv,
planner.csv (the planner's executions), study.json (the protocol a resume must match, each configuration's resolved
settings included, and what the last command showed), maps/ and study.md, the tables (also printed; `report` makes
them again from OUT): per size, per configuration the mean and 95% t interval over units (cq_ros.lab.study) of
greedy collisions and peer positions heard per episode, the every-AGV-home rate, the greedy makespan over the
planner's executed makespan, and the states at the end of learning; the paired differences from the first
configuration; bootstrap intervals of the ratios of collisions (each / the first) and of heard (the first / each);
and the curve.
"""

from __future__ import annotations

import csv
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from .. import compiled
from .. import episode as record
from ..engine import Team, greedy_team, make_learners, world_seed
from ..gridmap import GridMap, load_map, parse_map
from ..learners import LEARNERS
from ..mapf.execute import execute
from ..mapf.planner import plan
from ..mapgen.warehouse import warehouse_text
from ..settings import Settings, run_settings
from ..world import GridWorld
from .output import check_folder
from .results import ResultExists
from .runner import run_all
from .study import Interval, home_rate, makespan_ratio, mean_interval, paired_difference, ratio_interval

# Generator seeds: those the settings were chosen on (docs/choices.md), and the block the study draws from,
# which no tuning run, and no document or test but the study's own, names (map i of a size is
# HELD_OUT_SEEDS[i]).
TUNING_SEEDS = (0, 7)
HELD_OUT_SEEDS = range(1001, 1101)
BOOTSTRAP_SEED = 0
COPIES = ("frozen", "learning")  # eval_learning 0 and 1
FIGURES_PER_COPY = ("collisions", "home", "heard", "makespan")
# (label, unit column without its copy, digits) of the per-configuration tables
FIGURES = (("greedy collisions/ep", "collisions", 3), ("every AGV home", "home", 2), ("heard/ep", "heard", 1),
           ("makespan / planner's", "makespan_ratio", 2), ("states", "states", 0))
KEY = ("agents", "generator_seed", "run", "config")
PLANNER = ("makespan", "collisions", "messages", "home")


@dataclass(frozen=True)
class Config:
    name: str
    algo: str
    sets: tuple[str, ...] = ()  # settings of its own ("key=value"), over the study's

    def record(self) -> dict:
        """As study.json keeps it (`sets` only where there are any, as in studies kept before variants were)."""
        kept = {"name": self.name, "algo": self.algo}
        return {**kept, "sets": list(self.sets)} if self.sets else kept

    @classmethod
    def of_record(cls, record: dict) -> "Config":
        return cls(**{**record, "sets": tuple(record.get("sets", ()))})


def parse_variant(spec: str) -> Config:
    """"cq_a2=cq:alpha=0.2,gamma=0.95" -> Config("cq_a2", "cq", sets=("alpha=0.2", "gamma=0.95"))."""
    name, sep, rest = spec.partition("=")
    algo, _, pairs = rest.partition(":")
    if not sep or not name or not algo:
        raise ValueError(f"--variant takes NAME=ALGO:KEY=VALUE,..., got {spec!r}")
    if algo not in LEARNERS:
        raise ValueError(f"--variant {spec!r}: unknown algorithm {algo!r}; choose from {','.join(LEARNERS)}")
    return Config(name, algo, sets=tuple(pair for pair in pairs.split(",") if pair))


def parse_configs(algos: Sequence[str], variants: Sequence[str] = ()) -> list[Config]:
    """The learners by name, then each variant (NAME=ALGO:KEY=VALUE,...: a learner with settings of its own)."""
    configs = [Config(a, a) for a in algos]
    configs += [parse_variant(v) for v in variants]
    names = [c.name for c in configs]
    if len(set(names)) < len(names):
        raise ValueError(f"configuration names must differ, got {', '.join(names)}")
    return configs


def generator_seeds(tuning: bool) -> Sequence[int]:
    """The generator seeds a study draws its maps from, in order: the tuning seeds, or the held-out ones."""
    return TUNING_SEEDS if tuning else HELD_OUT_SEEDS


@dataclass(frozen=True)
class Unit:
    """One unit's learning run of one configuration (cq_ros.lab.runner's Run: map_name, algo, run, episodes)."""

    map_name: str
    algo: str
    run: int
    episodes: int
    seed: int
    settings: Settings
    config: str
    agents: int
    generator_seed: int
    greedy_episodes: int
    curve_every: int
    curve_episodes: int


class Learning:
    """One run's world and learners, on the engine cq_ros.compiled.engine_of chooses: learning episodes, and greedy
    copies of the team as it stands."""

    def __init__(self, algo: str, gridmap: GridMap, settings: Settings, seed: int, run: int):
        if compiled.engine_of(algo) == "compiled":
            from ..compiled.engine import Kernel

            self.kernel, self.team = Kernel(algo, gridmap, settings, seed, run), None
        else:
            self.kernel = None
            self.team = Team(GridWorld(gridmap, settings, seed=world_seed(seed, run)),
                             make_learners(algo, gridmap, settings, seed, run))

    def play(self, episodes: int, on_episode: Callable[[], None]) -> np.ndarray:
        if self.kernel is not None:
            return self.kernel.play(episodes, on_episode)
        rows = []
        for _ in range(episodes):
            rows.append(self.team.episode())
            on_episode()
        return record.table(rows)

    def greedy(self, learning: bool, episodes: int, keep: bool = True) -> np.ndarray:
        """`episodes` episodes of a greedy copy, frozen or learning; the run itself is left as it was, unless
        `keep` is False (nothing follows: the run itself plays them, no copy made)."""
        if self.kernel is not None:
            return self.kernel.greedy(learning, keep).play(episodes)
        team = greedy_team(self.team, learning, keep)
        return record.table(team.episode() for _ in range(episodes))


def greedy_figures(table: np.ndarray) -> dict[str, float]:
    return {"collisions": float(table["collisions"].mean()), "home": home_rate(table["truncated"]),
            "heard": float(table["heard"].mean()), "makespan": float(table["steps"].mean())}


def play_unit(maps: dict[str, GridMap], unit: Unit, on_episode: Callable[[], None],
              learning_of: Callable[..., Learning] = Learning) -> dict:
    """Learn, with the curve's frozen copies on the way, then the frozen and learning copies: the unit's figures
    ({copy}_{figure}, states, exploring collisions, seconds) and its curve [(episode, collisions, home)].
    `learning_of(algo, gridmap, settings, seed, run)` makes the run (a learner outside the registry plays the
    study's units through it: benchmarks/limit_learner.py)."""
    started = time.perf_counter()
    learning = learning_of(unit.algo, maps[unit.map_name], unit.settings, unit.seed, unit.run)
    tables, curve, done = [], [], 0
    while done < unit.episodes:
        size = min(unit.curve_every, unit.episodes - done)
        tables.append(learning.play(size, on_episode))
        done += size
        if done < unit.episodes:
            point = greedy_figures(learning.greedy(False, unit.curve_episodes))
            curve.append((done, point["collisions"], point["home"]))
    episodes = np.concatenate(tables)
    row: dict = {}
    for copy in COPIES:
        figures = greedy_figures(learning.greedy(copy == "learning", unit.greedy_episodes, keep=copy != COPIES[-1]))
        row.update({f"{copy}_{name}": value for name, value in figures.items()})
    curve.append((unit.episodes, row["frozen_collisions"], row["frozen_home"]))
    tail = max(1, len(episodes) // 10)
    row.update(states=float(episodes["states"][-1]),
               exploring_collisions=float(episodes["collisions"][-tail:].mean()),
               seconds=round(time.perf_counter() - started, 2))
    return {"row": row, "curve": curve}


def generated(out: Path, agents: int, seed: int, slip: float) -> Path:
    """The warehouse `cq-ros generate warehouse --agents AGENTS --seed SEED --slip SLIP` makes, kept in OUT/maps.
    One kept there already must be it: units played on another map (a generator changed since) must not be
    resumed as if on this one (ResultExists)."""
    path = out / "maps" / f"warehouse_{agents}_gen{seed}.txt"
    text = warehouse_text(agents, seed=seed, slip=slip)
    if path.exists() and path.read_text() != text:
        raise ResultExists(f"{path} is not the map the generator makes now: the units played on it would be "
                           "mixed with units on another map; choose another output directory or pass --force")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def config_settings(config: Config, gridmap: GridMap, overrides: Sequence[str],
                    greedy_episodes: int) -> Settings:
    """The settings a configuration plays with on `gridmap`."""
    return run_settings(gridmap, [*overrides, *config.sets, "eval_learning=0", f"eval_episodes={greedy_episodes}"])


def protocol_of(episodes: int, greedy_episodes: int, curve_every: int, curve_episodes: int, seed: int, slip: float,
                overrides: Sequence[str], configs: Sequence[Config], tuning: bool = False,
                settings: dict[str, dict] | None = None) -> dict:
    """What a resumed study must share with the units already played (maps, runs, sizes and configurations may
    grow; a configuration keeps its algorithm and settings, and the settings they resolve to, `settings`,
    which a change of the code's defaults moves). A tuning study says so (`generator_seeds`); a held-out one, as
    every study kept before tuning studies were, has no such key."""
    return {"episodes": episodes, "greedy_episodes": greedy_episodes, "curve_every": curve_every,
            "curve_episodes": curve_episodes, "seed": seed, "slip": slip, "overrides": list(overrides),
            **({"generator_seeds": "tuning"} if tuning else {}),
            "configs": {c.name: c.record() for c in configs}, "settings": settings or {}}


def settings_moved(old: dict, new: dict) -> list[str]:
    """For each configuration both protocols resolved, the settings whose values differ, as "name (key a -> b)"."""
    moved = []
    for name in sorted(set(old) & set(new)):
        keys = [k for k in sorted(set(old[name]) | set(new[name])) if old[name].get(k) != new[name].get(k)]
        if keys:
            moved.append(f"the settings of {name} ("
                         + ", ".join(f"{k} {old[name].get(k)} -> {new[name].get(k)}" for k in keys) + ")")
    return moved


def seeds_of(protocol: dict) -> Sequence[int]:
    return generator_seeds(protocol.get("generator_seeds") == "tuning")


def open_output(out: Path, protocol: dict, force: bool) -> Path:
    """OUT, new, or holding a study of the same protocol (to resume it); with force, emptied first."""
    out = Path(out)
    kept = out / "study.json"
    if out.is_dir() and any(out.iterdir()):
        if force:
            for name in ("units.csv", "curve.csv", "planner.csv", "study.json", "study.md"):
                (out / name).unlink(missing_ok=True)
            for path in (out / "maps").glob("warehouse_*_gen*.txt"):
                path.unlink()
        elif not kept.exists():
            raise ResultExists(f"output directory {out} is not empty and holds no study; choose another or pass "
                               "--force to overwrite")
        else:
            old = json.loads(kept.read_text())
            mine = {k: v for k, v in protocol.items() if k not in ("configs", "settings", "shown")}
            clash = [k for k in {*mine, "generator_seeds"} if old.get(k) != mine.get(k)] + [
                name for name, c in protocol["configs"].items() if old["configs"].get(name, c) != c] + settings_moved(
                old.get("settings", {}), protocol["settings"])
            if clash:
                raise ResultExists(f"output directory {out} holds a study of another protocol ({', '.join(clash)} "
                                   "differ); choose another or pass --force to overwrite")
            protocol = {**old, **protocol, "configs": {**old["configs"], **protocol["configs"]},
                        "settings": {**old.get("settings", {}), **protocol["settings"]}}
    out = check_folder(out, "output directory")
    kept.write_text(json.dumps(protocol, indent=1) + "\n")
    return out


def read_rows(path: Path) -> list[dict]:
    """A csv's rows, numbers as numbers (the configuration's name stays a string)."""
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return [{k: v if k == "config" else (int(v) if k in KEY else float(v)) for k, v in row.items()}
                for row in csv.DictReader(f)]


def append_rows(path: Path, rows: list[dict]) -> None:
    new = not path.exists()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        if new:
            writer.writeheader()
        writer.writerows(rows)


def study(out: Path, sizes: Sequence[int], maps: int, runs: int, episodes: int, greedy_episodes: int,
          configs: Sequence[Config], seed: int = 0, slip: float = 0.1, overrides: Sequence[str] = (),
          workers: int | None = None, cluster: str | None = None, force: bool = False, command: str = "",
          curve_every: int = 250, curve_episodes: int = 20, tuning: bool = False) -> str:
    """Play the units OUT does not hold yet and write OUT (the module says what); returns the tables printed."""
    seeds = generator_seeds(tuning)
    if maps > len(seeds):
        raise ValueError(f"--maps takes at most {len(seeds)} (the {'tuning' if tuning else 'held-out'} generator "
                         f"seeds), got {maps}")
    # Each configuration's settings as today's code makes them (the generated maps all carry the same `set`
    # lines): a resume whose defaults moved since the units were played is refused, not mixed with them.
    first = parse_map(warehouse_text(sizes[0], seed=seeds[0], slip=slip))
    resolved = {c.name: config_settings(c, first, overrides, greedy_episodes).as_dict() for c in configs}
    out = open_output(out, protocol_of(episodes, greedy_episodes, curve_every, curve_episodes, seed, slip, overrides,
                                       configs, tuning, resolved), force)
    started = time.perf_counter()
    wanted = [(a, seeds[i], r) for a in sizes for i in range(maps) for r in range(runs)]
    paths = {(a, g): generated(out, a, g, slip) for a, g in dict.fromkeys((a, g) for a, g, _ in wanted)}
    planner = planned(out, paths, runs, seed, overrides)
    done = {tuple(row[k] for k in KEY) for row in read_rows(out / "units.csv")}
    units = []
    for (agents, g), path in paths.items():
        for c in configs:
            settings = config_settings(c, load_map(path), overrides, greedy_episodes)
            units += [Unit(str(path), c.algo, r, episodes, seed, settings, c.name, agents, g, greedy_episodes,
                           curve_every, curve_episodes) for r in range(runs) if (agents, g, r, c.name) not in done]
    if len(units) < len(wanted) * len(configs):
        print(f"study: {len(wanted) * len(configs) - len(units)} units of {out} played already, {len(units)} to play",
              file=sys.stderr, flush=True)
    loaded = {path: load_map(path) for path in {u.map_name for u in units}}
    if any(compiled.engine_of(u.algo) == "compiled" for u in units):
        compiled.prepare()  # here, once: the workers then load the compiled engine from its cache

    def keep(index: int, result: dict) -> None:
        """A unit's rows, kept as soon as it ends: a study stopped later plays only what it had not finished."""
        u = units[index]
        key = {"agents": u.agents, "generator_seed": u.generator_seed, "run": u.run, "config": u.config}
        # The curve first: a unit's row in units.csv is what marks it played, so a study stopped between the
        # two writes plays the unit again (shown_rows keeps one row per unit) rather than lose its curve.
        append_rows(out / "curve.csv", [{**key, "episode": e, "collisions": c, "home": h}
                                        for e, c, h in result["curve"]])
        append_rows(out / "units.csv", [{**key, **result["row"], "planner_makespan":
                                         planner[(u.agents, u.generator_seed, u.run)]["makespan"]}])
        finished[0] += 1
        print(f"study: unit {finished[0]}/{len(units)}, {time.perf_counter() - started:.0f} s elapsed",
              file=sys.stderr, flush=True)

    finished = [0]
    run_all(units, partial(play_unit, loaded), workers, cluster, label="study units", on_result=keep)
    kept = json.loads((out / "study.json").read_text())
    kept["shown"] = {"sizes": list(sizes), "maps": maps, "runs": runs, "configs": [c.name for c in configs],
                     "command": command}
    (out / "study.json").write_text(json.dumps(kept, indent=1) + "\n")
    text = report(out)
    (out / "study.md").write_text(text)
    return text


def planned(out: Path, paths: dict[tuple[int, int], Path], runs: int, seed: int,
            overrides: Sequence[str]) -> dict[tuple[int, int, int], dict]:
    """The planner's plan of each map executed in run r's delays: {(agents, generator seed, run): figures}, kept
    in OUT/planner.csv (a resume reads what it holds)."""
    found = {(int(r["agents"]), int(r["generator_seed"]), int(r["run"])): r
             for r in read_rows(out / "planner.csv")}
    missing = [(a, g) for a, g in sorted(paths) if any((a, g, r) not in found for r in range(runs))]
    for n, (agents, g) in enumerate(missing):
        print(f"study: planning {paths[(agents, g)].name} ({n + 1}/{len(missing)})", file=sys.stderr, flush=True)
        gridmap = load_map(paths[(agents, g)])
        the_plan = plan(gridmap)
        settings: Settings = run_settings(gridmap, overrides)
        new = []
        for r in range(runs):
            if (agents, g, r) in found:
                continue
            done = execute(the_plan, gridmap, settings, seed, r)
            makespan = max(len(p) - 1 if a is None else a for p, a in zip(done.paths, done.arrivals))
            found[(agents, g, r)] = {"agents": agents, "generator_seed": g, "run": r, "makespan": makespan,
                                     "collisions": done.collisions, "messages": done.messages, "home": int(done.home)}
            new.append(found[(agents, g, r)])
        append_rows(out / "planner.csv", new)
    return found


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
