"""Read an experiment's result files and boil them down to the numbers the paper argues with.

The engine writes one row per (map, algorithm, run, episode) to ``episodes.csv`` and, at the end of each
run, every joint state a CQ agent keeps to ``observe.csv``. This module turns those into arrays shaped
(runs, episodes) per (map, algorithm), computes the headline metrics (collisions once learning has
settled, when collisions stop for good, the size of the state space, how often global information is
used) and prints them as a Markdown or a terminal table. ``plots.py`` draws the paper's figures from the
same arrays.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

EPISODES_HEADER = "map,algo,run,episode,steps,collisions,joint_plays,states,return,truncated"
OBSERVE_HEADER = "map,algo,run,agent,row,col,peer,peer_row,peer_col,confidence"
COLUMNS = ("steps", "collisions", "joint_plays", "states", "return", "truncated")

# The paper's order (baselines first, CQ last); algorithms it does not know follow alphabetically.
ALGO_ORDER = ("indep", "js", "jsa", "loc", "cq", "fcq")

Runs = dict[str, np.ndarray]  # column name -> array shaped (runs, episodes)
Episodes = dict[tuple[str, str], Runs]  # (map, algo) -> its columns

_NUMERIC = ("run", "episode", *COLUMNS)
# Counts parse three times faster as integers than as floats, which matters at 2M rows.
_FAST_DTYPE = np.dtype([(name, "f8" if name == "return" else "i8") for name in _NUMERIC])
_ANY_DTYPE = np.dtype([(name, "f8") for name in _NUMERIC])


def greedy_lines(path: str | os.PathLike) -> list[str]:
    """One line per algorithm of a greedy.csv (`cq-ros experiment` and `cq-ros launch` end with them): the
    greedy policy's collisions and steps per episode over every run's greedy episodes, and how many were
    truncated. An algorithm without greedy episodes (eval_episodes 0) has no line."""
    totals: dict[str, list[float]] = {}  # algo -> [runs, episodes, collisions, steps, truncated]
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            n = int(row["episodes"])
            if n == 0:
                continue
            t = totals.setdefault(row["algo"], [0, 0, 0.0, 0.0, 0])
            t[0] += 1
            t[1] += n
            t[2] += float(row["collisions"]) * n
            t[3] += float(row["steps"]) * n
            t[4] += int(row["truncated"])
    return [f"greedy policy, {algo}, {runs} run{'s' if runs > 1 else ''} x {episodes // runs} episodes: "
            f"{collisions / episodes:.2f} collisions/ep, {steps / episodes:.1f} steps/ep, {truncated} truncated"
            for algo, (runs, episodes, collisions, steps, truncated) in sorted(totals.items(),
                                                                               key=lambda kv: algo_sort_key(kv[0]))]


def algo_sort_key(algo: str) -> tuple[int, str]:
    return (ALGO_ORDER.index(algo) if algo in ALGO_ORDER else len(ALGO_ORDER), algo)


# --- loading -------------------------------------------------------------------------------------------


def load_episodes(path: str | os.PathLike) -> Episodes:
    """``episodes.csv`` as {(map, algo): {column: float array shaped (runs, episodes)}}.

    Row order in the file does not matter. Every (map, algo) must hold each of its runs for each episode
    1..E exactly once; anything else is a ValueError naming the group, so a half-written file is noticed
    rather than averaged.
    """
    _check_header(path, EPISODES_HEADER)
    keys, codes = _group_codes(path)
    if codes.size == 0:
        return {}
    values = _numeric_columns(path)
    if values.size != codes.size:
        raise ValueError(f"{path}: {codes.size} data lines but {values.size} parsed rows")
    order = np.argsort(codes, kind="stable")
    bounds = np.cumsum(np.bincount(codes, minlength=len(keys)))
    groups = np.split(order, bounds[:-1])
    return {key: _rectangle(values[rows], key, path) for key, rows in sorted(zip(keys, groups), key=lambda kv: kv[0])}


def by_map(data: Episodes) -> dict[str, dict[str, Runs]]:
    """``data`` regrouped as {map: {algo: runs}}, algorithms in the paper's order."""
    grouped: dict[str, dict[str, Runs]] = {}
    for (name, algo) in sorted(data, key=lambda key: (key[0], algo_sort_key(key[1]))):
        grouped.setdefault(name, {})[algo] = data[(name, algo)]
    return grouped


def _check_header(path: str | os.PathLike, expected: str) -> None:
    with open(path, encoding="utf-8") as f:
        header = f.readline().strip()
    if header != expected:
        raise ValueError(f"{path}: header must be {expected!r}, got {header!r}")


def _group_codes(path: str | os.PathLike) -> tuple[list[tuple[str, str]], np.ndarray]:
    """The distinct (map, algo) pairs and, per data line, the index of its pair.

    A dict lookup on the text before the eight numeric fields is the cheapest way to turn the two string
    columns into integers (numpy's string parsing is about twice as slow).
    """
    codes_of: dict[str, int] = {}
    with open(path, encoding="utf-8") as f:
        next(f)
        codes = np.fromiter(
            (codes_of.setdefault(line.rsplit(",", 8)[0], len(codes_of)) for line in f if not line.isspace()),
            dtype=np.int64,
        )
    keys = [tuple(prefix.split(",")) for prefix in codes_of]
    return keys, codes


def _numeric_columns(path: str | os.PathLike) -> np.ndarray:
    try:
        return np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(2, 10), dtype=_FAST_DTYPE, ndmin=1)
    except ValueError:
        # A writer that formats counts as floats ("12.0") is still within the contract, only slower to read.
        return np.loadtxt(path, delimiter=",", skiprows=1, usecols=range(2, 10), dtype=_ANY_DTYPE, ndmin=1)


def _rectangle(rows: np.ndarray, key: tuple[str, str], path: str | os.PathLike) -> Runs:
    runs, run_index = np.unique(rows["run"], return_inverse=True)
    episodes = int(rows["episode"].max()) + 1
    cell = run_index * episodes + rows["episode"].astype(np.int64)
    if rows["episode"].min() < 0 or rows.size != runs.size * episodes or np.bincount(cell).max() > 1:
        raise ValueError(
            f"{path}: {key[0]}/{key[1]} must have episodes 0..{episodes - 1} once for each of its {runs.size} runs "
            f"({runs.size * episodes} rows), found {rows.size} rows"
        )
    columns = {}
    for name in COLUMNS:
        table = np.empty(runs.size * episodes)
        table[cell] = rows[name]
        columns[name] = table.reshape(runs.size, episodes)
    return columns


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
    _check_header(path, OBSERVE_HEADER)
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


def observation_strength(observations: Iterable[Observation]) -> dict[int, dict[tuple[int, int], float]]:
    """Per agent, per own cell (row, col): how strongly the agent observes its peers there, in (0, 1].

    Confidences are summed over the joint states kept in a cell and over runs, then divided by the
    agent's largest cell sum: confidences have no fixed scale, so only each agent's relative weighting
    means something (and a sum over runs is a mean over runs up to that same factor).
    """
    sums: dict[int, dict[tuple[int, int], float]] = {}
    for obs in observations:
        cells = sums.setdefault(obs.agent, {})
        cells[(obs.row, obs.col)] = cells.get((obs.row, obs.col), 0.0) + obs.confidence
    return {agent: _normalised(cells) for agent, cells in sorted(sums.items())}


def _normalised(cells: dict[tuple[int, int], float]) -> dict[tuple[int, int], float]:
    top = max(cells.values())
    return {cell: value / top for cell, value in cells.items()}


# --- metrics -------------------------------------------------------------------------------------------


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average along the last (episode) axis, same shape as ``x``.

    Entry t is the mean of x[t - window + 1 .. t]; the first window - 1 entries average what there is so
    far, so the curve starts at the first episode and never looks ahead.
    """
    if window < 1:
        raise ValueError(f"window must be at least 1, got {window}")
    x = np.asarray(x, dtype=np.float64)
    sums = np.cumsum(x, axis=-1)
    sums[..., window:] = sums[..., window:] - sums[..., :-window]
    counts = np.minimum(np.arange(1, x.shape[-1] + 1), window)
    return sums / counts


def settled_episode(collisions: np.ndarray, window: int = 100, threshold: float = 0.05) -> int | None:
    """The first episode (from 0, so also the number of episodes before it) from which the moving average of
    the run-mean collisions stays below ``threshold`` to the end; None if it is not below at the last episode.

    Because the average trails, this is when the smoothed curve settles, up to ``window`` episodes after
    the last collision that mattered.
    """
    smoothed = moving_average(np.asarray(collisions).mean(axis=0), window)
    above = np.flatnonzero(smoothed >= threshold)
    if above.size == 0:
        return 0
    if above[-1] == smoothed.size - 1:
        return None
    return int(above[-1]) + 1


@dataclass(frozen=True)
class Metrics:
    """The headline numbers of one (map, algorithm). "tail" = the last ``tail`` fraction of episodes."""

    map: str
    algo: str
    runs: int
    episodes: int
    collisions_tail: float  # collisions per episode in the tail, mean over runs
    collisions_tail_std: float  # standard deviation over runs (ddof 0) of each run's tail mean
    settled_episode: int | None
    final_states: float  # states in use at the last episode (all agents, local plus joint), mean over runs
    joint_plays_tail: float
    joint_plays_all: float
    steps_tail: float
    truncated: int  # truncated episodes, all runs together


def compute_metrics(data: Episodes, window: int = 100, threshold: float = 0.05, tail: float = 0.1) -> list[Metrics]:
    """Metrics for every (map, algo) in ``data``, by map, then in the paper's algorithm order."""
    return [
        _metrics((name, algo), runs, window, threshold, tail)
        for name, algos in by_map(data).items()
        for algo, runs in algos.items()
    ]


def _metrics(key: tuple[str, str], runs: Runs, window: int, threshold: float, tail: float) -> Metrics:
    n_runs, n_episodes = runs["collisions"].shape
    last = slice(-max(1, math.ceil(n_episodes * tail)), None)
    collisions_per_run = runs["collisions"][:, last].mean(axis=1)
    return Metrics(
        map=key[0],
        algo=key[1],
        runs=n_runs,
        episodes=n_episodes,
        collisions_tail=float(collisions_per_run.mean()),
        collisions_tail_std=float(collisions_per_run.std()),
        settled_episode=settled_episode(runs["collisions"], window, threshold),
        final_states=float(runs["states"][:, -1].mean()),
        joint_plays_tail=float(runs["joint_plays"][:, last].mean()),
        joint_plays_all=float(runs["joint_plays"].mean()),
        steps_tail=float(runs["steps"][:, last].mean()),
        truncated=int(runs["truncated"].sum()),
    )


# --- tables --------------------------------------------------------------------------------------------

_TEXT_COLUMNS = 2  # map and algo are left-aligned, the numbers right-aligned


def _headers(tail: float, settled: bool = True) -> list[str]:
    last = f"last {tail:.0%}"
    return [
        "map",
        "algo",
        "runs x episodes",
        f"collisions/ep ({last})",
        *["collision-free from ep"] * settled,
        "final states",
        f"joint plays/ep ({last})",
        "joint plays/ep (all)",
        f"steps/ep ({last})",
        "truncated",
    ]


def summary_table(data: Episodes, window: int = 100, threshold: float = 0.05, tail: float = 0.1,
                  settled: bool = True) -> str:
    """A Markdown table of ``compute_metrics`` (one row per map and algorithm) with a note on its terms;
    without the "collision-free from" column if not ``settled`` (one seed's crossing, which moves with the seed)."""
    headers = _headers(tail, settled)
    rows = _cells(compute_metrics(data, window, threshold, tail), settled)
    align = ["---"] * _TEXT_COLUMNS + ["---:"] * (len(headers) - _TEXT_COLUMNS)
    lines = [_markdown_row(headers), _markdown_row(align), *(_markdown_row(row) for row in rows)]
    return "\n".join(lines) + "\n\n" + _note(window, threshold, tail, settled) + "\n"


def format_console_table(data: Episodes, window: int = 100, threshold: float = 0.05, tail: float = 0.1) -> str:
    """The same table as plain text in aligned columns, for a terminal."""
    rows = [_headers(tail), *_cells(compute_metrics(data, window, threshold, tail))]
    widths = [max(len(cell) for cell in column) for column in zip(*rows)]
    lines = [_console_row(row, widths) for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    return "\n".join(lines) + "\n\n" + _note(window, threshold, tail) + "\n"


def _cells(metrics: list[Metrics], settled: bool = True) -> list[list[str]]:
    return [
        [
            m.map,
            m.algo,
            f"{m.runs} x {m.episodes}",
            f"{_number(m.collisions_tail)} ± {_number(m.collisions_tail_std)}",
            *["never" if m.settled_episode is None else str(m.settled_episode)] * settled,
            _number(m.final_states),
            _number(m.joint_plays_tail),
            _number(m.joint_plays_all),
            _number(m.steps_tail),
            str(m.truncated),
        ]
        for m in metrics
    ]


def _number(x: float) -> str:
    # Three significant digits, but never scientific notation for state counts in the thousands.
    return f"{x:.0f}" if abs(x) >= 1000 else f"{x:.3g}"


def _note(window: int, threshold: float, tail: float, settled: bool = True) -> str:
    return (
        f"Collisions per episode over the last {tail:.0%} of episodes as mean ± s.d. over runs. "
        + (f"Collision-free from = first episode from which the {window}-episode trailing mean of the "
           f"run-mean collisions stays below {threshold:g} ('never' if it is not below at the end). " if settled else "")
        + "Final states = local plus joint states of all agents after the last episode, mean over runs."
    )


def _markdown_row(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _console_row(cells: list[str], widths: list[int]) -> str:
    text = [cell.ljust(width) for cell, width in zip(cells[:_TEXT_COLUMNS], widths)]
    numbers = [cell.rjust(width) for cell, width in zip(cells[_TEXT_COLUMNS:], widths[_TEXT_COLUMNS:])]
    return "  ".join(text + numbers).rstrip()

