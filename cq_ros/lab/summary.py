"""Boil an experiment's results down to the numbers the paper argues with.

cq_ros.lab.results reads ``episodes.csv`` as arrays shaped (runs, episodes) per (map, algorithm) and
``observe.csv`` as the joint states kept; this module computes the headline metrics (collisions once learning has
settled, when collisions stop for good, the size of the state space, how often global information is
used) and prints them as a Markdown or a terminal table. ``plots.py`` draws the paper's figures from the
same arrays.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from ..learners import algo_sort_key
from .results import Episodes, Observation, Runs, load_greedy


def greedy_lines(path: str | os.PathLike) -> list[str]:
    """One line per algorithm of a greedy.csv (`cq-ros experiment` and `cq-ros launch` end with them): the
    greedy policy's collisions and steps per episode over every run's greedy episodes, and how many were
    truncated. An algorithm without greedy episodes (eval_episodes 0) has no line."""
    totals: dict[str, list[float]] = {}  # algo -> [runs, episodes, collisions, steps, truncated]
    for g in load_greedy(path):
        t = totals.setdefault(g.algo, [0, 0, 0.0, 0.0, 0])
        t[0] += 1
        t[1] += g.episodes
        t[2] += g.collisions * g.episodes
        t[3] += g.steps * g.episodes
        t[4] += g.truncated
    return [f"greedy policy, {algo}, {runs} run{'s' if runs > 1 else ''} x {episodes // runs} episodes: "
            f"{collisions / episodes:.2f} collisions/ep, {steps / episodes:.1f} steps/ep, {truncated} truncated"
            for algo, (runs, episodes, collisions, steps, truncated) in totals.items()]


def by_map(data: Episodes) -> dict[str, dict[str, Runs]]:
    """``data`` regrouped as {map: {algo: runs}}, algorithms in the registry's order (cq_ros.learners)."""
    grouped: dict[str, dict[str, Runs]] = {}
    for (name, algo) in sorted(data, key=lambda key: (key[0], algo_sort_key(key[1]))):
        grouped.setdefault(name, {})[algo] = data[(name, algo)]
    return grouped


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
           f"run-mean collisions stays below {threshold:g} ('never' if it is not below at the end). "
           if settled else "")
        + "Final states = local plus joint states of all agents after the last episode, mean over runs."
    )


def _markdown_row(cells: Iterable[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _console_row(cells: list[str], widths: list[int]) -> str:
    text = [cell.ljust(width) for cell, width in zip(cells[:_TEXT_COLUMNS], widths)]
    numbers = [cell.rjust(width) for cell, width in zip(cells[_TEXT_COLUMNS:], widths[_TEXT_COLUMNS:])]
    return "  ".join(text + numbers).rstrip()

