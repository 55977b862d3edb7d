"""The result files, read and written in one place: what `cq-ros experiment`, `cq-ros reproduce`, `cq-ros launch`
and `cq-ros collect` write, and what the summary, the plots, and the reproduction's report read.

A result directory holds, for one map:
- `episodes.csv`: one row per algorithm, run and learning episode: EPISODE_COLUMNS, the keys (map, algo, run,
  episode; runs and episodes numbered from 0 as on the wire and in bags) then an episode's record
  (cq_ros.episode.COLUMNS, whose meanings it states; files kept from before `heard` was a column are read too,
  without it);
- `greedy.csv`: the same columns, one row per greedy episode played after learning (episodes numbered from 0
  within each run's greedy episodes);
- `observe.csv`: OBSERVE_COLUMNS, the joint states each CQ agent keeps at the end of each run (Fig. 5b);
- `manifest.json`: every setting, the seeds, package versions and the wall time (`manifest_for`).
Rows go by algorithm in the registry's order (cq_ros.learners), then by run and episode.
"""

from __future__ import annotations

import csv
import json
import os
import platform
import sys
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .. import __version__
from .. import episode as record
from ..engine import RunResult
from ..gridmap import GridMap
from ..learners import algo_sort_key
from ..settings import Settings
from .output import check_folder

EPISODES, GREEDY, OBSERVE, MANIFEST = "episodes.csv", "greedy.csv", "observe.csv", "manifest.json"
KEYS = ("map", "algo", "run", "episode")
EPISODE_COLUMNS = (*KEYS, *record.COLUMNS)
GREEDY_COLUMNS = EPISODE_COLUMNS
OBSERVE_COLUMNS = ("map", "algo", "run", "agent", "row", "col", "peer", "peer_row", "peer_col", "confidence")
# The manifest's fields that are the run's own circumstances: all the others are the same, byte for byte,
# whether the runs executed in one process, with --jobs or on a cluster.
CIRCUMSTANCES = ("command", "finished_at", "wall_time_s", "executed_on", "engine")

Runs = dict[str, np.ndarray]  # column name -> array shaped (runs, episodes)
Episodes = dict[tuple[str, str], Runs]  # (map, algo) -> its columns


class ResultExists(FileExistsError):
    """The output directory already holds a result (or is a file)."""


def prepare_output(out: Path, force: bool) -> Path:
    """An output directory that is ours to write: new, empty, or (with force) an old result; and one that takes
    a file (cq_ros.lab.output.check_folder: OutputError for a read-only or full one)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ResultExists(f"output {out} is a file, not a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ResultExists(f"output directory {out} is not empty; choose another or pass --force to overwrite")
    return check_folder(out, "output directory")  # made, and a probe written: OutputError for a bad one


# --- writing -------------------------------------------------------------------------------------------


def episode_row(map_name: str, algo: str, run: int, episode: int, values) -> tuple:
    """One row of episodes.csv or greedy.csv: `episode` from 0 as on the wire and in bags, `values` one element
    of a cq_ros.episode table (RunResult.episodes or .greedy), its counts written as whole numbers."""
    return (map_name, algo, run, episode, *(int(values[c]) if c in record.INTEGER else f"{float(values[c]):g}"
                                            for c in record.COLUMNS))


def _write_episodes(path: Path, map_name: str, results: list[RunResult], which: str) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(EPISODE_COLUMNS)
        for r in results:
            w.writerows(episode_row(map_name, r.algo, r.run, e, values) for e, values in enumerate(getattr(r, which)))


def write_results(out: Path, gridmap: GridMap, results: list[RunResult], manifest: dict, *,
                  episodes_written: bool = False) -> None:
    """episodes.csv (unless `episodes_written`: a launch writes it as the episodes come), observe.csv,
    greedy.csv and manifest.json for one map."""
    ordered = sorted(results, key=lambda r: (algo_sort_key(r.algo), r.run))
    if not episodes_written:
        _write_episodes(out / EPISODES, gridmap.name, ordered, "episodes")
    with open(out / OBSERVE, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(OBSERVE_COLUMNS)
        for r in ordered:
            for agent, cell, peer, peer_cell, conf in r.joint_states:
                w.writerow((gridmap.name, r.algo, r.run, agent + 1, *gridmap.cells[cell], peer + 1,
                            *gridmap.cells[peer_cell], f"{conf:.6g}"))
    _write_episodes(out / GREEDY, gridmap.name, ordered, "greedy")
    (out / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")


def engines_of(results) -> dict[str, str | list[str]]:
    """The manifest's `engine`: which engine played each algorithm's runs (cq_ros.compiled.ENGINES), one name
    where all its runs played on one, else one per run in run order. Both engines give the same files."""
    played: dict[str, list[str]] = {}
    for r in sorted(results, key=lambda r: (algo_sort_key(r.algo), r.run)):
        played.setdefault(r.algo, []).append(r.engine)
    return {algo: names[0] if len(set(names)) == 1 else names for algo, names in played.items()}


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
    for package in ("numpy", "numba", "scipy", "matplotlib"):
        try:
            found[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            pass
    return found


# --- reading -------------------------------------------------------------------------------------------

_KEPT_EPISODE_COLUMNS = (*KEYS, *record.KEPT_COLUMNS)  # episodes.csv and greedy.csv as written before `heard`


def _dtypes(values: tuple[str, ...]) -> tuple[np.dtype, np.dtype]:
    """The columns after map and algo (all numbers): counts as integers, which parse three times faster than
    floats (it matters at 2M rows), and all as floats."""
    fast = np.dtype([(name, "i8" if name in (*KEYS, *record.INTEGER) else "f8") for name in values])
    return fast, np.dtype([(name, "f8") for name in values])


def load_episodes(path: str | os.PathLike) -> Episodes:
    """``episodes.csv`` (or a greedy.csv) as {(map, algo): {column: float array shaped (runs, episodes)}}.

    Row order in the file does not matter. Every (map, algo) must hold each of its runs for each episode
    1..E exactly once; anything else is a ValueError naming the group, so a half-written file is noticed
    rather than averaged.
    """
    header = _header(path)
    if header not in (EPISODE_COLUMNS, _KEPT_EPISODE_COLUMNS):
        _check_header(path, EPISODE_COLUMNS)
    keys, codes = _group_codes(path, len(header) - 2)
    if codes.size == 0:
        return {}
    values = _numeric_columns(path, header[2:])
    if values.size != codes.size:
        raise ValueError(f"{path}: {codes.size} data lines but {values.size} parsed rows")
    order = np.argsort(codes, kind="stable")
    bounds = np.cumsum(np.bincount(codes, minlength=len(keys)))
    groups = np.split(order, bounds[:-1])
    names = header[len(KEYS):]
    return {key: _rectangle(values[rows], key, path, names)
            for key, rows in sorted(zip(keys, groups), key=lambda kv: kv[0])}


def _header(path: str | os.PathLike) -> tuple[str, ...]:
    with open(path, encoding="utf-8") as f:
        return tuple(f.readline().strip().split(","))


def _check_header(path: str | os.PathLike, expected: tuple[str, ...]) -> None:
    header = _header(path)
    if header != expected:
        raise ValueError(f"{path}: header must be {','.join(expected)!r}, got {','.join(header)!r}")


def _group_codes(path: str | os.PathLike, numbers: int) -> tuple[list[tuple[str, str]], np.ndarray]:
    """The distinct (map, algo) pairs and, per data line (of `numbers` numeric fields after them), the index of
    its pair.

    A dict lookup on the text before the numeric fields is the cheapest way to turn the two string
    columns into integers (numpy's string parsing is about twice as slow).
    """
    codes_of: dict[str, int] = {}
    with open(path, encoding="utf-8") as f:
        next(f)
        codes = np.fromiter(
            (codes_of.setdefault(line.rsplit(",", numbers)[0], len(codes_of)) for line in f if not line.isspace()),
            dtype=np.int64,
        )
    keys = [tuple(prefix.split(",")) for prefix in codes_of]
    return keys, codes


def _numeric_columns(path: str | os.PathLike, values: tuple[str, ...]) -> np.ndarray:
    columns = range(2, 2 + len(values))
    fast, floats = _dtypes(values)
    try:
        return np.loadtxt(path, delimiter=",", skiprows=1, usecols=columns, dtype=fast, ndmin=1)
    except ValueError:
        # A writer that formats counts as floats ("12.0") is still within the contract, only slower to read.
        return np.loadtxt(path, delimiter=",", skiprows=1, usecols=columns, dtype=floats, ndmin=1)


def _rectangle(rows: np.ndarray, key: tuple[str, str], path: str | os.PathLike, names: tuple[str, ...]) -> Runs:
    runs, run_index = np.unique(rows["run"], return_inverse=True)
    episodes = int(rows["episode"].max()) + 1
    cell = run_index * episodes + rows["episode"].astype(np.int64)
    if rows["episode"].min() < 0 or rows.size != runs.size * episodes or np.bincount(cell).max() > 1:
        raise ValueError(
            f"{path}: {key[0]}/{key[1]} must have episodes 0..{episodes - 1} once for each of its {runs.size} runs "
            f"({runs.size * episodes} rows), found {rows.size} rows"
        )
    columns = {}
    for name in names:
        table = np.empty(runs.size * episodes)
        table[cell] = rows[name]
        columns[name] = table.reshape(runs.size, episodes)
    return columns


def load_manifest(result_dir: str | os.PathLike) -> dict:
    """A result directory's manifest.json ({} if it has none)."""
    path = Path(result_dir) / MANIFEST
    return json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}


@dataclass(frozen=True)
class GreedyRun:
    """What one run's greedy policy did over its greedy episodes: collisions and steps per episode, and how
    many of them the step cap ended."""

    algo: str
    run: int
    episodes: int
    collisions: float
    steps: float
    truncated: int


def load_greedy(path: str | os.PathLike) -> list[GreedyRun]:
    """greedy.csv as one GreedyRun per (algorithm, run) with greedy episodes, in the registry's order."""
    found = [GreedyRun(algo, int(run), columns["steps"].shape[1], float(collisions.mean()), float(steps.mean()),
                       int(truncated.sum()))
             for (_, algo), columns in load_episodes(path).items()
             for run, (collisions, steps, truncated) in enumerate(zip(columns["collisions"], columns["steps"],
                                                                      columns["truncated"]))]
    return sorted(found, key=lambda g: (algo_sort_key(g.algo), g.run))


class Observation(NamedTuple):
    """One joint state an agent keeps at the end of a run: its own cell, a peer's cell, a confidence."""

    map: str
    algo: str
    run: int
    agent: int
    row: int
    col: int
    peer: int
    peer_row: int
    peer_col: int
    confidence: float


def load_observations(path: str | os.PathLike) -> list[Observation]:
    """``observe.csv`` as a list of Observation (a small file: only the joint states kept at the end)."""
    _check_header(path, OBSERVE_COLUMNS)
    with open(path, encoding="utf-8", newline="") as f:
        reader = csv.reader(f)
        next(reader)
        return [_observation(fields, path, reader.line_num) for fields in reader if fields]


def _observation(fields: list[str], path: str | os.PathLike, line: int) -> Observation:
    try:
        m, algo, *ints, confidence = fields
        return Observation(m, algo, *(int(v) for v in ints), float(confidence))
    except ValueError as exc:
        raise ValueError(f"{path}:{line}: malformed row {fields!r} ({exc})") from None
