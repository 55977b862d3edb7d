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
settings included, and what the last command showed: held_out_protocol.py), maps/ and study.md, the tables (also
printed; held_out_report.py makes them again from OUT): per size, per configuration the mean and 95% t interval
over units (cq_ros.lab.study) of greedy collisions and peer positions heard per episode, the every-AGV-home rate,
the greedy makespan over the planner's executed makespan, and the states at the end of learning; the paired
differences from the first configuration; bootstrap intervals of the ratios of collisions (each / the first) and
of heard (the first / each); and the curve.
"""

from __future__ import annotations

import json
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
from ..mapf.execute import execute
from ..mapf.planner import plan
from ..mapgen.warehouse import warehouse_text
from ..settings import Settings, run_settings
from ..world import GridWorld
from .held_out_protocol import (COPIES, KEY, Config, append_rows, generator_seeds, open_output, protocol_of,
                                read_rows)
from .held_out_report import report
from .results import ResultExists
from .runner import run_all
from .study import home_rate


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
