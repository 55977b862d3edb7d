"""`cq-ros reproduce`: runs the paper's grid (reproduce_grid.py), its figures, the same grid with exploration
that stops, a settings sweep, and our CQ beside the paper's on the four maps, on local processes or a Dask
cluster; writes every folder's results and REPORT.md (reproduce_report.py), in which every claim of the
paper's section 4 is checked against the numbers measured (reproduce_claims.py).
"""

from __future__ import annotations

import shlex
import time
from collections.abc import Sequence
from pathlib import Path

from ..gridmap import load_map
from ..learners import ALGORITHMS
from ..settings import Settings
from .experiment import Job, keep_interrupted, run_jobs
from .reproduce_grid import CQ, OURS, OURS_DIR, PAPER_MAPS, SWEEP_MAP, decaying, seed_dir, sweep_variants
from .reproduce_report import render_report
from .results import engines_of, manifest_for, prepare_output, write_results


def reproduce(out: Path, runs: int = 10, episodes: int = 10_000, seed: int | Sequence[int] = 0,
              settings: Settings = Settings(), workers: int | None = None, force: bool = False, sweep: bool = True,
              figures: bool = True, cluster: str | None = None, command: str | None = None,
              engine: str = "compiled") -> Path:
    """Run the grid, again with exploration that stops (in decay/), for each master seed in `seed` (one or
    several), and the sweep (first seed), on `workers` local processes or on the Dask scheduler at `cluster`;
    write every map's results and figures (first seed) and REPORT.md; returns its path. REPORT.md names
    `command` as the command that made it (the CLI gives its own; default: this call as a `cq-ros reproduce`)."""
    seeds = (seed,) if isinstance(seed, int) else tuple(dict.fromkeys(seed))
    out = prepare_output(out, force)
    started = time.perf_counter()
    decay = decaying(settings, episodes)
    grids = {".": settings, "decay": decay}
    jobs = [Job(m, a, r, episodes, sd, s, engine) for sd in seeds for s in grids.values() for m in PAPER_MAPS
            for a in ALGORITHMS for r in range(runs)]
    variants = sweep_variants(settings) if sweep else []
    for v in variants:
        jobs += [Job(SWEEP_MAP, CQ, r, episodes, seeds[0], settings.with_overrides(v.changes), engine)
                 for r in range(runs)]
    jobs += [Job(m, OURS, r, episodes, seeds[0], settings, engine) for m in PAPER_MAPS for r in range(runs)]
    jobs = list(dict.fromkeys(jobs))  # the "defaults" variant is the grid's own CQ runs on the sweep map
    done: dict = {}

    def write(results: dict, executed_on: dict | None, **extra) -> None:
        _write_grid(out, results, jobs, seeds, grids, variants, runs, episodes, settings,
                    time.perf_counter() - started, executed_on, extra)

    try:
        results, executed_on = run_jobs(jobs, workers, label="reproduce", cluster=cluster, done=done)
    except KeyboardInterrupt:
        keep_interrupted(out, jobs, done, lambda missing: write(done, None, interrupted=missing))
        raise
    write(results, executed_on)
    if figures:
        from .plots import write_figures

        for where in grids:
            for m in PAPER_MAPS:
                write_figures(out / where / m)
    report = out / "REPORT.md"
    command = command or as_command(out, runs, episodes, seeds, settings, sweep, workers, cluster)
    report.write_text(render_report(out, episodes, seeds, settings, variants, time.perf_counter() - started,
                                    executed_on, command))
    return report


def _write_grid(out: Path, results: dict, jobs: list, seeds: Sequence[int], grids: dict, variants: list,
                runs: int, episodes: int, settings: Settings, wall: float, executed_on: dict | None,
                extra: dict) -> None:
    """Every folder of the grid with the results it has (after Ctrl-C, those of the runs that finished: a folder
    none of whose runs did is not made); `extra` joins each manifest."""
    def put(folder: Path, map_name: str, algos, seed: int, grid_settings: Settings, **more) -> None:
        mine = [results[j] for j in jobs if j in results and j.algo in algos
                and (j.map_name, j.seed, j.settings) == (map_name, seed, grid_settings)]
        if mine:
            folder.mkdir(parents=True, exist_ok=True)
            gridmap = load_map(map_name)
            write_results(folder, gridmap, mine, manifest_for(gridmap, algos, runs, episodes, seed, grid_settings,
                                                              wall, executed_on, engine=engines_of(mine), **more,
                                                              **extra))

    for sd in seeds:
        for where, grid_settings in grids.items():
            for m in PAPER_MAPS:
                put(seed_dir(out, seeds, sd) / where / m, m, ALGORITHMS, sd, grid_settings)
    for v in variants:
        put(out / "sweep" / v.name, SWEEP_MAP, [CQ], seeds[0], settings.with_overrides(v.changes), variant=v.name)
    for m in PAPER_MAPS:
        put(out / OURS_DIR / m, m, [OURS], seeds[0], settings)


def as_command(out: Path, runs: int, episodes: int, seeds: Sequence[int], settings: Settings, sweep: bool,
               workers: int | None, cluster: str | None) -> str:
    """The `cq-ros reproduce` command line that runs what a call of `reproduce` with these arguments runs."""
    seeding = f"--seed {seeds[0]}" if len(seeds) == 1 else "--seeds " + ",".join(map(str, seeds))
    base = Settings().as_dict()
    words = ["cq-ros", "reproduce", "--out", str(out), "--runs", str(runs), "--episodes", str(episodes),
             *seeding.split(), *([] if sweep else ["--no-sweep"]),
             *(["--jobs", str(workers)] if workers else []), *(["--cluster", cluster] if cluster else [])]
    for k, v in settings.as_dict().items():
        if base[k] != v:
            words += ["--set", f"{k}={v}"]
    return shlex.join(words)
