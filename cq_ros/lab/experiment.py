"""Experiments: many (algorithm, run) pairs spread over the cores or a Dask cluster, written as result files.

A result directory holds `episodes.csv` (one row per algorithm, run and episode), `observe.csv`
(the joint states each CQ agent keeps at the end of each run, for Fig. 5b), `greedy.csv` (per run,
collisions and steps per episode of the final greedy policy), `manifest.json` (every
parameter, seed, package version and the wall time) and the figures. An existing result is never
overwritten unless asked.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import partial
from importlib import metadata
from pathlib import Path

from .. import __version__
from ..engine import RunResult, run
from ..gridmap import GridMap, load_map
from ..learners import LEARNERS
from .output import check_folder
from .runner import run_all
from ..settings import Settings, run_settings

EPISODE_COLUMNS = ("map", "algo", "run", "episode", "steps", "collisions", "joint_plays", "states", "return", "truncated")
GREEDY_COLUMNS = ("map", "algo", "run", "episodes", "collisions", "steps", "truncated")
OBSERVE_COLUMNS = ("map", "algo", "run", "agent", "row", "col", "peer", "peer_row", "peer_col", "confidence")
# The manifest's fields that are the run's own circumstances: all the others are the same, byte for byte,
# whether the runs executed in one process, with --jobs or on a cluster.
CIRCUMSTANCES = ("command", "finished_at", "wall_time_s", "executed_on")


class ResultExists(FileExistsError):
    """The output directory already holds a result (or is a file)."""


@dataclass(frozen=True)
class Job:
    map_name: str
    algo: str
    run: int
    episodes: int
    seed: int
    settings: Settings = field(default_factory=Settings)


def _play(maps: dict[str, GridMap], job: Job, on_episode: Callable[[], None]) -> RunResult:
    return run(job.algo, maps[job.map_name], job.settings, job.seed, job.run, job.episodes, on_episode)


def run_jobs(jobs: list[Job], workers: int | None = None, label: str = "runs", progress_interval: float = 30.0,
             cluster: str | None = None) -> tuple[dict[Job, RunResult], dict]:
    """Play every job (cq_ros.lab.runner: in this process, on `workers` local processes, or on the Dask scheduler at
    `cluster`), showing progress; each job's result, and where they ran (the manifest's `executed_on`).
    The maps travel with the jobs, read here once: a worker on another machine needs no map file."""
    maps = {job.map_name: load_map(job.map_name) for job in jobs}
    ran = run_all(jobs, partial(_play, maps), workers, cluster, label, progress_interval)
    return dict(zip(jobs, ran.results)), ran.executed_on


def prepare_output(out: Path, force: bool) -> Path:
    """An output directory that is ours to write: new, empty, or (with force) an old result; and one that takes
    a file (cq_ros.lab.output.check_folder: OutputError for a read-only or full one)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ResultExists(f"output {out} is a file, not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ResultExists(f"output directory {out} is not empty; choose another or pass --force to overwrite")
    return check_folder(out, "output directory")  # made, and a probe written: OutputError for a bad one


def episode_row(map_name: str, algo: str, run: int, episode: int, values) -> tuple:
    """One row of episodes.csv: `episode` from 0 as on the wire and in bags, `values` a row of RunResult.episodes.
    Every writer's values go through float64 as RunResult's do, so a JS state space past 2**53 (cells**N) is
    written alike offline and by a launch, which hears it exactly."""
    steps, coll, plays, states, ret, trunc = map(float, values)
    return (map_name, algo, run, episode, int(steps), int(coll), int(plays), int(states), f"{ret:g}", int(trunc))


def write_results(out: Path, gridmap: GridMap, results: list[RunResult], manifest: dict, *,
                  episodes_written: bool = False) -> None:
    """episodes.csv (unless `episodes_written`: a launch writes it as the episodes come), observe.csv,
    greedy.csv and manifest.json for one map."""
    ordered = sorted(results, key=lambda r: (list(LEARNERS).index(r.algo), r.run))
    if not episodes_written:
        with open(out / "episodes.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(EPISODE_COLUMNS)
            for r in ordered:
                w.writerows(episode_row(gridmap.name, r.algo, r.run, e, values)
                            for e, values in enumerate(r.episodes))
    with open(out / "observe.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(OBSERVE_COLUMNS)
        for r in ordered:
            for agent, cell, peer, peer_cell, conf in r.joint_states:
                w.writerow((gridmap.name, r.algo, r.run, agent + 1, *gridmap.cells[cell], peer + 1,
                            *gridmap.cells[peer_cell], f"{conf:.6g}"))
    with open(out / "greedy.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(GREEDY_COLUMNS)
        for r in ordered:
            g = r.greedy
            w.writerow((gridmap.name, r.algo, r.run, len(g), f"{g[:, 1].mean():g}" if len(g) else "",
                        f"{g[:, 0].mean():g}" if len(g) else "", int(g[:, 5].sum())))
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")


def manifest_for(gridmap: GridMap, algos, runs: int, episodes: int, seed: int, settings: Settings,
                 wall_time: float, executed_on: dict | None = None, **extra) -> dict:
    """The manifest of a result folder; `executed_on` says where the runs ran (cq_ros.lab.runner), where they
    ran elsewhere than in this process's own engine (a launch's nodes say so in their own entries)."""
    return {
        "map": gridmap.name,
        "map_source": str(Path(gridmap.source).resolve()) if Path(gridmap.source).is_file() else gridmap.source,
        "n_agents": gridmap.n_agents,
        "n_cells": gridmap.n_cells,
        "algos": list(algos),
        "runs": runs,
        "episodes": episodes,
        "seed": seed,
        "seeds": "learner of agent i in run r: SeedSequence([seed, r, i]); world: SeedSequence([seed, r, 2**31])",
        "settings": settings.as_dict(),
        # The map's own defaults (its `set` lines), and those of them the run used (not overridden).
        "map_defaults": dict(gridmap.defaults),
        "settings_from_map": {k: v for k, v in gridmap.defaults.items() if getattr(settings, k) == v},
        "versions": versions(),
        "command": sys.argv,
        "finished_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "wall_time_s": round(wall_time, 2),
        **({"executed_on": executed_on} if executed_on is not None else {}),
        **extra,
    }


def versions() -> dict:
    found = {"cq_ros": __version__, "python": platform.python_version(), "machine": platform.machine(),
             "cores": os.cpu_count()}
    for package in ("numpy", "scipy", "matplotlib"):
        try:
            found[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    return found


def experiment(map_name: str, algos: list[str], runs: int, episodes: int, seed: int, out: Path,
               settings: Settings | None = None, workers: int | None = None, force: bool = False,
               figures: bool = True, cluster: str | None = None) -> Path:
    """Run every algorithm on one map and write the result directory; returns it. Without `settings`, the
    run's are the map's (`cq_ros.settings.run_settings`). The runs go to `workers` local processes, or to the
    Dask scheduler at `cluster`."""
    gridmap = load_map(map_name)
    settings = run_settings(gridmap) if settings is None else settings
    out = prepare_output(out, force)
    started = time.perf_counter()
    jobs = [Job(str(map_name), a, r, episodes, seed, settings) for a in algos for r in range(runs)]
    results, executed_on = run_jobs(jobs, workers, label=gridmap.name, cluster=cluster)
    wall = time.perf_counter() - started
    write_results(out, gridmap, list(results.values()),
                  manifest_for(gridmap, algos, runs, episodes, seed, settings, wall, executed_on))
    if figures:
        from .plots import write_figures  # matplotlib only where figures are wanted

        write_figures(out)
    return out
