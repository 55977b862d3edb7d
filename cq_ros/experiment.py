"""Experiments: many (algorithm, run) pairs spread over the cores, written as result files.

A result directory holds `episodes.csv` (one row per algorithm, run and episode), `observe.csv`
(the joint states each CQ agent keeps at the end of each run, for Fig. 5b), `greedy.csv` (per run,
collisions and steps per episode of the final greedy policy), `manifest.json` (every
parameter, seed, package version and the wall time) and the figures. An existing result is never
overwritten unless asked.
"""

from __future__ import annotations

import csv
import json
import multiprocessing
import os
import platform
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

from tqdm import tqdm

from . import __version__
from .engine import RunResult, run
from .gridmap import GridMap, load_map
from .learners import LEARNERS
from .settings import Settings, run_settings

EPISODE_COLUMNS = ("map", "algo", "run", "episode", "steps", "collisions", "joint_plays", "states", "return", "truncated")
GREEDY_COLUMNS = ("map", "algo", "run", "episodes", "collisions", "steps", "truncated")
OBSERVE_COLUMNS = ("map", "algo", "run", "agent", "row", "col", "peer", "peer_row", "peer_col", "confidence")


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


class Progress:
    """Episodes and runs done, with the rate and the time left, on stderr: a tqdm bar on a terminal;
    elsewhere (a log, CI, a pipe) a plain line at the start, then every `interval` seconds, and at the end."""

    def __init__(self, label: str, episodes: int, runs: int, interval: float = 30.0):
        self.label, self.episodes, self.runs, self.interval = label, episodes, runs, interval
        self.tty = sys.stderr.isatty()
        self.bar = tqdm(total=episodes, desc=label, unit="episode", disable=not self.tty)
        self.started = self.shown_at = time.monotonic()
        self.done = self.runs_done = 0
        if not self.tty:
            self._line()

    def update(self, episodes_done: int, runs_done: int) -> None:
        if self.tty:
            self.bar.set_postfix_str(f"runs {runs_done}/{self.runs}", refresh=False)
            self.bar.update(episodes_done - self.done)
        self.done, self.runs_done = episodes_done, runs_done
        if not self.tty and time.monotonic() - self.shown_at >= self.interval:
            self._line()

    def close(self) -> None:
        self.bar.close()
        if not self.tty:
            self._line()

    def _line(self) -> None:
        now = time.monotonic()
        self.shown_at, elapsed = now, now - self.started
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = f"{(self.episodes - self.done) / rate:.0f} s left" if rate > 0 else "time left unknown"
        print(f"{self.label}: runs {self.runs_done}/{self.runs}, episodes {self.done:,}/{self.episodes:,}, "
              f"{rate:,.0f} episodes/s, {elapsed:.0f} s elapsed, {left}", file=sys.stderr, flush=True)


# In a worker process: the episodes played by every worker, shared with the parent for its progress.
_episodes_played = None


def _count_in(counter) -> None:
    global _episodes_played
    _episodes_played = counter


def _count_episode() -> None:
    with _episodes_played.get_lock():
        _episodes_played.value += 1


def _play(job: Job, on_episode: Callable[[], None] = _count_episode) -> tuple[Job, RunResult, float]:
    started = time.perf_counter()
    result = run(job.algo, load_map(job.map_name), job.settings, job.seed, job.run, job.episodes, on_episode)
    return job, result, time.perf_counter() - started


def run_jobs(jobs: list[Job], workers: int | None = None, label: str = "runs",
             progress_interval: float = 30.0) -> dict[Job, RunResult]:
    """Play every job, in parallel where there is more than one core, showing progress (see Progress).
    Each worker counts its episodes in one shared counter, which the parent reads while it waits."""
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    results: dict[Job, RunResult] = {}
    progress = Progress(label, sum(job.episodes for job in jobs), len(jobs), progress_interval)
    if workers == 1:
        def played_one() -> None:
            progress.update(progress.done + 1, len(results))

        for job in jobs:
            job, result, _ = _play(job, played_one)
            results[job] = result
            progress.update(progress.done, len(results))
    else:
        counter = multiprocessing.Value("q", 0)
        with ProcessPoolExecutor(max_workers=workers, initializer=_count_in, initargs=(counter,)) as pool:
            pending = {pool.submit(_play, job) for job in jobs}
            while pending:
                done, pending = wait(pending, timeout=min(1.0, progress_interval), return_when=FIRST_COMPLETED)
                for future in done:
                    job, result, _ = future.result()
                    results[job] = result
                progress.update(counter.value, len(results))
    progress.close()
    return results


def prepare_output(out: Path, force: bool) -> Path:
    """An output directory that is ours to write: new, empty, or (with force) an old result."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ResultExists(f"output {out} is a file, not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ResultExists(f"output directory {out} is not empty; choose another or pass --force to overwrite")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # e.g. a parent that is a file, or no permission: one line, not a traceback
        raise ResultExists(f"cannot make output directory {out}: {e.strerror or e}") from None
    return out


def write_results(out: Path, gridmap: GridMap, results: list[RunResult], manifest: dict) -> None:
    """episodes.csv, observe.csv, greedy.csv and manifest.json for one map."""
    ordered = sorted(results, key=lambda r: (list(LEARNERS).index(r.algo), r.run))
    with open(out / "episodes.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(EPISODE_COLUMNS)
        for r in ordered:
            for e, (steps, coll, plays, states, ret, trunc) in enumerate(r.episodes, start=1):
                w.writerow((gridmap.name, r.algo, r.run, e, int(steps), int(coll), int(plays), int(states),
                            f"{ret:g}", int(trunc)))
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
                 wall_time: float, **extra) -> dict:
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
               figures: bool = True) -> Path:
    """Run every algorithm on one map and write the result directory; returns it. Without `settings`, the
    run's are the map's (`cq_ros.settings.run_settings`)."""
    gridmap = load_map(map_name)
    settings = run_settings(gridmap) if settings is None else settings
    out = prepare_output(out, force)
    started = time.perf_counter()
    jobs = [Job(str(map_name), a, r, episodes, seed, settings) for a in algos for r in range(runs)]
    results = run_jobs(jobs, workers, label=gridmap.name)
    wall = time.perf_counter() - started
    write_results(out, gridmap, list(results.values()),
                  manifest_for(gridmap, algos, runs, episodes, seed, settings, wall, workers=workers))
    if figures:
        from .plots import write_figures  # matplotlib only where figures are wanted

        write_figures(out)
    return out
