"""Experiments: many (algorithm, run) pairs spread over the cores or a Dask cluster, written as result files
(cq_ros.lab.results says which and what they hold) and figures. An existing result is never overwritten unless
asked.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from .. import compiled
from ..engine import RunResult
from ..gridmap import GridMap, load_map
from .results import engines_of, manifest_for, prepare_output, write_results
from .runner import run_all
from ..settings import Settings, run_settings


@dataclass(frozen=True)
class Job:
    map_name: str
    algo: str
    run: int
    episodes: int
    seed: int
    settings: Settings = field(default_factory=Settings)
    engine: str = "compiled"  # cq_ros.compiled.ENGINES: the compiled engine where it plays the learner


def _play(maps: dict[str, GridMap], job: Job, on_episode: Callable[[], None]) -> RunResult:
    return compiled.play(job.algo, maps[job.map_name], job.settings, job.seed, job.run, job.episodes, on_episode,
                         engine=job.engine)


def run_jobs(jobs: list[Job], workers: int | None = None, label: str = "runs", progress_interval: float = 30.0,
             cluster: str | None = None, done: dict[Job, RunResult] | None = None
             ) -> tuple[dict[Job, RunResult], dict]:
    """Play every job (cq_ros.lab.runner: in this process, on `workers` local processes, or on the Dask scheduler at
    `cluster`), showing progress; each job's result, and where they ran (the manifest's `executed_on`). `done`
    gets each result as its run ends, for a caller to keep when the rest is interrupted (keep_interrupted).
    The maps travel with the jobs, read here once: a worker on another machine needs no map file."""
    maps = {job.map_name: load_map(job.map_name) for job in jobs}
    if any(compiled.engine_of(job.algo, job.engine) == "compiled" for job in jobs):
        compiled.prepare()  # here, once: the workers then load the compiled engine from its cache
    done = {} if done is None else done
    ran = run_all(jobs, partial(_play, maps), workers, cluster, label, progress_interval,
                  on_result=lambda i, result: done.__setitem__(jobs[i], result))
    return dict(zip(jobs, ran.results)), ran.executed_on


def keep_interrupted(out: Path, jobs: list[Job], done: dict[Job, RunResult],
                     write: Callable[[list[str]], None]) -> None:
    """After Ctrl-C (or SIGTERM) while `jobs` played: the runs that finished (`done`) written by `write`, given
    the runs missing (the manifest's `interrupted`), and one line on stderr saying which; nothing if none
    finished. The runs cut short are lost: a run's results are whole or absent."""
    if not done:
        return
    missing = [f"{job.map_name} {job.algo} seed {job.seed} run {job.run}" for job in jobs if job not in done]
    write(missing)
    shown = ", ".join(missing[:6]) + (f" and {len(missing) - 6} more" if len(missing) > 6 else "")
    print(f"interrupted: the {len(done)} of {len(jobs)} runs that finished are kept in {out}; missing: {shown}",
          file=sys.stderr)


def experiment(map_name: str, algos: list[str], runs: int, episodes: int, seed: int, out: Path,
               settings: Settings | None = None, workers: int | None = None, force: bool = False,
               figures: bool = True, cluster: str | None = None, engine: str = "compiled") -> Path:
    """Run every algorithm on one map and write the result directory; returns it. Without `settings`, the
    run's are the map's (`cq_ros.settings.run_settings`). The runs go to `workers` local processes, or to the
    Dask scheduler at `cluster`, and play on `engine` (cq_ros.compiled.play)."""
    gridmap = load_map(map_name)
    if settings is None:
        settings = run_settings(gridmap)
    out = prepare_output(out, force)
    started = time.perf_counter()
    jobs = [Job(str(map_name), a, r, episodes, seed, settings, engine) for a in algos for r in range(runs)]

    def write(results: list[RunResult], executed_on: dict | None, **extra) -> None:
        write_results(out, gridmap, results,
                      manifest_for(gridmap, algos, runs, episodes, seed, settings, time.perf_counter() - started,
                                   executed_on, engine=engines_of(results), **extra))

    done: dict[Job, RunResult] = {}
    try:
        results, executed_on = run_jobs(jobs, workers, label=gridmap.name, cluster=cluster, done=done)
    except KeyboardInterrupt:
        keep_interrupted(out, jobs, done, lambda missing: write(list(done.values()), None, interrupted=missing))
        raise
    write(list(results.values()), executed_on)
    if figures:
        from .plots import write_figures  # matplotlib only where figures are wanted

        write_figures(out)
    return out
