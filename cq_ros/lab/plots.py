"""The paper's figures, drawn from an experiment's result directory as PNGs a person can put in a paper.

Fig. 3 collisions per episode (on a linear axis, as the paper draws it, and on a linear-then-log axis that
shows late fractions of a collision beside early hundreds), Fig. 4 joint plays (CQ, LoC), Fig. 5a CQ's state space
per agent against the local and the joint state space, Fig. 5b where each CQ agent observes its peers and how
confidently, plus steps (and return) per episode. Every curve is the mean over runs with a band of one standard
deviation over runs, each run first smoothed by a trailing moving average (``summary.moving_average``).

Figures are built on ``matplotlib.figure.Figure`` directly, never through pyplot: that renders PNGs with
Agg whatever backend the caller has chosen, and leaves no global figure state behind.
"""

from __future__ import annotations

import math

import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle
from matplotlib.patheffects import withStroke
from matplotlib.ticker import LogLocator, NullFormatter, StrMethodFormatter

from ..gridmap import GridMap, load_map
from ..learners import CQ_LEARNERS, REGISTRY
from .results import EPISODES, OBSERVE, Episodes, Observation, Runs, load_episodes, load_manifest, load_observations
from .summary import by_map, moving_average, observation_strength

DPI = 150
JOINT_PLAY_ALGOS = ("loc", *CQ_LEARNERS)  # the learners that decide where to use global information
STATE_SPACE_ALGOS = CQ_LEARNERS  # the learners whose state space grows and shrinks

_LABELS = {a.name: a.label for a in REGISTRY}
_COLOURS = {a.name: a.colour for a in REGISTRY}
_SPARE_COLOURS = ("#bcbd22", "#e377c2", "#17becf")  # for an algorithm the registry does not know (an old result's)
_WALL_COLOUR = "0.1"
_OUTSIDE_COLOUR = "0.35"  # '#' cells, not part of the world
_SIZE = (7.0, 4.2)  # inches; 1050 x 630 pixels at DPI


# --- one curve per algorithm ---------------------------------------------------------------------------


def plot_collisions(
    data: Episodes, out_png: str | os.PathLike, map_name: str | None = None, smooth: int = 100, log: bool = False
) -> Path:
    """Fig. 3: collisions per episode, one line per algorithm; on a linear axis, or with ``log`` on the
    linear-then-log count axis."""
    name, by_algo = _one_map(data, map_name)
    values = {algo: runs["collisions"] for algo, runs in by_algo.items()}
    return _count_figure(name, "collisions", values, smooth, out_png, log)


def plot_joint_plays(
    data: Episodes, out_png: str | os.PathLike, map_name: str | None = None, smooth: int = 100
) -> Path:
    """Fig. 4: per episode, how often the agents used global information (CQ: acted from a joint state;
    LoC: chose COORDINATE). Only the algorithms that make that choice are drawn."""
    name, by_algo = _one_map(data, map_name)
    values = {algo: runs["joint_plays"] for algo, runs in by_algo.items() if algo in JOINT_PLAY_ALGOS}
    if not values:
        raise ValueError(f"{name}: no algorithm of {', '.join(JOINT_PLAY_ALGOS)} to draw joint plays for")
    return _count_figure(name, "joint plays", values, smooth, out_png)


def _count_figure(name: str, what: str, values: dict[str, np.ndarray], smooth: int, out_png, log: bool = True) -> Path:
    """A count per episode, one curve per algorithm, on the linear-then-log count axis (or a linear one)."""
    fig, ax = _figure()
    _curves(ax, values, smooth)
    if log:
        _count_axis(ax)
    else:
        ax.set_ylim(0, None)
    _finish(ax, f"{name}: {what} per episode", _y_label(f"{what} per episode", smooth), values)
    return _save(fig, out_png)


def plot_steps(
    data: Episodes,
    out_png: str | os.PathLike,
    map_name: str | None = None,
    smooth: int = 100,
    show_return: bool = True,
) -> Path:
    """Steps to finish an episode (log scale: early episodes take orders of magnitude longer), and below
    it, if ``show_return``, the return per episode (the agents' rewards summed), sharing the legend."""
    name, by_algo = _one_map(data, map_name)
    if show_return:
        fig = Figure(figsize=(_SIZE[0], _SIZE[1] * 1.6), dpi=DPI, layout="constrained")
        steps_ax, return_ax = fig.subplots(2, 1, sharex=True)
    else:
        fig, steps_ax = _figure()
    steps = {algo: runs["steps"] for algo, runs in by_algo.items()}
    _curves(steps_ax, steps, smooth)
    steps_ax.set_yscale("log")
    steps_ax.yaxis.set_major_locator(LogLocator(subs=(1, 2, 5)))
    steps_ax.yaxis.set_major_formatter(StrMethodFormatter("{x:g}"))
    steps_ax.yaxis.set_minor_formatter(NullFormatter())
    _finish(steps_ax, f"{name}: steps per episode", _y_label("steps per episode", smooth), steps)
    if show_return:
        steps_ax.set_xlabel("")
        returns = {algo: runs["return"] for algo, runs in by_algo.items()}
        _curves(return_ax, returns, smooth)
        _finish(return_ax, "return per episode", _y_label("return per episode", smooth), returns, legend=False)
    return _save(fig, out_png)


def _one_map(data: Episodes, map_name: str | None) -> tuple[str, dict[str, Runs]]:
    maps = by_map(data)
    if map_name is None and len(maps) == 1:
        map_name = next(iter(maps))
    if map_name not in maps:
        raise ValueError(f"choose a map: map_name={map_name!r}, the data holds {', '.join(maps) or 'no map'}")
    return map_name, maps[map_name]


def _figure() -> tuple[Figure, Axes]:
    fig = Figure(figsize=_SIZE, dpi=DPI, layout="constrained")
    return fig, fig.add_subplot()


def _curves(ax: Axes, values_by_algo: dict[str, np.ndarray], window: int) -> None:
    for index, (algo, values) in enumerate(values_by_algo.items()):
        _mean_band(ax, values, window, _label(algo), _colour(algo, index))


def _mean_band(ax: Axes, values: np.ndarray, window: int, label: str, colour: str) -> None:
    """The run mean as a line and ± 1 s.d. over runs as a band; the band stops at the smallest value
    observed, so counts never get a band below zero."""
    smoothed = moving_average(values, window)
    mean, spread = smoothed.mean(axis=0), smoothed.std(axis=0)
    episodes = np.arange(mean.size)
    ax.fill_between(episodes, np.maximum(mean - spread, values.min()), mean + spread, color=colour, alpha=0.2, lw=0)
    ax.plot(episodes, mean, color=colour, label=label, lw=1.3)


def _count_axis(ax: Axes) -> None:
    """A y axis linear from 0 to 1 and logarithmic above, with plain-number ticks.

    Early episodes can have hundreds of collisions and late ones a fraction of one: this keeps both
    readable and, unlike a log axis, shows zero, which is what Fig. 3 is about.
    """
    ax.set_yscale("symlog", linthresh=1, linscale=2)
    top = max(1.0, ax.get_ylim()[1])
    decades = 10.0 ** np.arange(0, np.ceil(np.log10(top)) + 1)
    ticks = [0, 0.25, 0.5, 0.75, *(d * m for d in decades for m in (1, 2, 5) if d * m <= top)]
    ax.set_yticks(ticks, [f"{t:g}" for t in ticks])
    ax.set_yticks([], minor=True)
    ax.set_ylim(-0.04, top)  # a little below zero, so that a curve at zero does not hide in the spine


def _finish(ax: Axes, title: str, y_label: str, values_by_algo: dict[str, np.ndarray], legend: bool = True) -> None:
    ax.set_title(title)
    ax.set_xlabel("episode")
    ax.set_ylabel(y_label)
    ax.set_xlim(1, max(values.shape[1] for values in values_by_algo.values()))
    ax.grid(True, which="major", alpha=0.3)
    if legend:
        ax.legend(title=_runs_text(values_by_algo), fontsize="small", title_fontsize="small", loc="best")


def _y_label(quantity: str, window: int) -> str:
    return quantity if window == 1 else f"{quantity}\n(moving average over {window} episodes)"


def _runs_text(values_by_algo: dict[str, np.ndarray]) -> str:
    counts = {values.shape[0] for values in values_by_algo.values()}
    runs = f"{counts.pop()} runs" if len(counts) == 1 else "the runs"
    return f"mean of {runs}, band ± 1 s.d."


def _label(algo: str) -> str:
    return _LABELS.get(algo, algo)


def _colour(algo: str, index: int) -> str:
    return _COLOURS.get(algo, _SPARE_COLOURS[index % len(_SPARE_COLOURS)])


def _save(fig: Figure, out_png: str | os.PathLike) -> Path:
    path = Path(out_png)
    fig.savefig(path, dpi=DPI)
    return path


# --- Fig. 5a: the state space ----------------------------------------------------------------------------


def plot_state_space(
    data: Episodes,
    out_png: str | os.PathLike,
    n_cells: int,
    n_agents: int,
    map_name: str | None = None,
    smooth: int = 100,
) -> Path:
    """Fig. 5a: states in use per agent (``states / n_agents``) for CQ, against the local state space of an
    independent learner (``n_cells``) and the joint one of JS/JSA (``n_cells ** n_agents``).

    The joint line is usually far above the curve; the y axis is then broken in two so that the curve's
    ups and downs stay visible under it (a log axis would flatten them). The axis starts at the data,
    not at zero, for the same reason.
    """
    name, by_algo = _one_map(data, map_name)
    chosen = {algo: runs["states"] / n_agents for algo, runs in by_algo.items() if algo in STATE_SPACE_ALGOS}
    if not chosen:
        raise ValueError(f"{name}: no algorithm of {', '.join(STATE_SPACE_ALGOS)} to draw the state space of")
    local, joint = n_cells, n_cells**n_agents  # an int of any size: 1,092 cells and 128 agents overflow a float
    fig = Figure(figsize=_SIZE, dpi=DPI, layout="constrained")
    if joint > 2 * max(local, *(float(values.max()) for values in chosen.values())):
        # The joint line on an axis of its own, placed at its logarithm (exact for any int) and labelled with
        # the count: the band above the break shows where the line is, not a scale.
        upper, lower = fig.subplots(2, 1, sharex=True, height_ratios=(1, 4))
        _broken_axis(upper, lower)
        at = math.log10(joint)
        upper.set_ylim(at - 0.05, at + 0.05)
        upper.set_yticks([at], [_count(joint)])
        upper.grid(True, alpha=0.3)
    else:
        upper = lower = fig.add_subplot()
        at = joint
    joint_line = upper.axhline(at, color="black", lw=1.2, ls="--",
                               label=f"joint state space (JS, JSA): {n_cells}^{n_agents} = {_count(joint)}")
    lower.axhline(local, color="black", lw=1.2, ls=":", label=f"local state space (Indep): {_count(local)}")
    _curves(lower, chosen, smooth)
    upper.set_title(f"{name}: size of the state space per agent")
    lower.set_xlabel("episode")
    lower.set_ylabel(_y_label("states per agent (local + joint)", smooth))
    lower.set_xlim(1, max(values.shape[1] for values in chosen.values()))
    lower.grid(True, alpha=0.3)
    handles = lower.get_legend_handles_labels()[0]
    if upper is not lower:
        handles.insert(0, joint_line)
    lower.legend(handles=handles, title=_runs_text(chosen), fontsize="small", title_fontsize="small", loc="best")
    return _save(fig, out_png)


def _count(n: int) -> str:
    """n in full below 10^7, else as 1.23e+45; past a float's range from its logarithm, which any int has."""
    if n < 10**7:
        return f"{n:,}"
    if n < 10**300:
        return f"{n:.2e}"
    exponent = math.log10(n)
    return f"{10 ** (exponent % 1):.2f}e+{math.floor(exponent)}"


def _broken_axis(upper: Axes, lower: Axes) -> None:
    """Hide the spines between two stacked axes and draw the usual diagonal break marks on them."""
    upper.spines.bottom.set_visible(False)
    lower.spines.top.set_visible(False)
    upper.tick_params(axis="x", bottom=False, labelbottom=False)
    marks = dict(marker=[(-1, -0.5), (1, 0.5)], markersize=10, linestyle="none", color="black", clip_on=False)
    upper.plot([0, 1], [0, 0], transform=upper.transAxes, **marks)
    lower.plot([0, 1], [1, 1], transform=lower.transAxes, **marks)


# --- Fig. 5b: where the agents observe ---------------------------------------------------------------------


def plot_observe_map(
    observe_rows: Iterable[Observation],
    gridmap: GridMap,
    out_png: str | os.PathLike,
    algo: str = "cq",
) -> Path:
    """Fig. 5b: the map, and per agent the cells where it keeps joint states (observes its peers).

    ``observe_rows`` are the rows of one map and one algorithm. Each agent owns a vertical strip of every
    cell (agent 1 the left one), so agents observing in the same cell both show; a strip's opacity is the
    agent's confidence there, summed over runs and normalised by the agent's largest (see
    ``summary.observation_strength``).
    """
    strength = observation_strength(observe_rows)
    cell_inches = min(0.6, 9.0 / gridmap.width)
    fig = Figure(figsize=(max(5.0, gridmap.width * cell_inches + 0.8), gridmap.height * cell_inches + 1.2), dpi=DPI,
                 layout="constrained")
    ax = fig.add_subplot()
    _draw_grid(ax, gridmap)
    for agent, cells in strength.items():
        for (row, col), alpha in cells.items():
            ax.add_patch(Rectangle(_strip(agent, gridmap.n_agents, row, col), 1 / gridmap.n_agents, 1,
                                   facecolor=to_rgba(_agent_colour(agent), alpha), lw=0))
    _draw_walls(ax, gridmap)
    _mark_starts_and_goals(ax, gridmap)
    kept = "" if strength else " (no joint states kept)"
    ax.set_title(f"{gridmap.name}: where {_label(algo)} agents observe others{kept}")
    fig.legend(handles=_agent_handles(gridmap.n_agents), loc="outside lower center", ncol=min(gridmap.n_agents, 4),
               fontsize="small", frameon=False, title_fontsize="small",
               title="opacity = confidence in the joint states of a cell, summed over runs, per agent")
    return _save(fig, out_png)


def _strip(agent: int, n_agents: int, row: int, col: int) -> tuple[float, float]:
    """Lower-left corner (x, y) of agent's strip of cell (row, col); agents count from 1."""
    return col + (agent - 1) / n_agents, row


def _agent_colour(agent: int) -> tuple[float, ...]:
    return to_rgba(f"C{(agent - 1) % 10}")


def _agent_handles(n_agents: int) -> list[Patch]:
    where = {1: "left", n_agents: "right"} if n_agents == 2 else {}
    return [
        Patch(color=_agent_colour(agent), label=f"agent {agent} ({where.get(agent, f'strip {agent} of {n_agents}')})")
        for agent in range(1, n_agents + 1)
    ]


def _draw_grid(ax: Axes, gridmap: GridMap) -> None:
    ax.set_xlim(-0.05, gridmap.width + 0.05)
    ax.set_ylim(gridmap.height + 0.05, -0.05)  # row 0 at the top, as in the map file
    ax.set_aspect("equal")
    ax.axis("off")
    world = set(gridmap.cells)
    for row in range(gridmap.height):
        for col in range(gridmap.width):
            inside = (row, col) in world
            ax.add_patch(Rectangle((col, row), 1, 1, facecolor="white" if inside else _OUTSIDE_COLOUR,
                                   edgecolor="0.85", lw=0.5))


def _draw_walls(ax: Axes, gridmap: GridMap) -> None:
    """A wall on every side of a cell that an action cannot cross (map border, '#' cells, walls)."""
    segments = []
    for cell, (row, col) in enumerate(gridmap.cells):
        sides = (((col, row), (col + 1, row)), ((col + 1, row), (col + 1, row + 1)),
                 ((col, row + 1), (col + 1, row + 1)), ((col, row), (col, row + 1)))  # N, E, S, W
        segments.extend(side for side, target in zip(sides, gridmap.neighbours[cell]) if target == cell)
    # Walls are axis-parallel, so nothing is lost without antialiasing, and it keeps the overlapping
    # segment ends from showing as darker stubs.
    ax.add_collection(LineCollection(segments, colors=_WALL_COLOUR, linewidths=2.5, capstyle="projecting",
                                     antialiaseds=False))


def _mark_starts_and_goals(ax: Axes, gridmap: GridMap) -> None:
    labels: dict[int, list[str]] = {}
    for agent, start in enumerate(gridmap.starts, 1):
        labels.setdefault(start, []).append(f"S{agent}")
    shared_goal = len(set(gridmap.goals)) == 1 and gridmap.n_agents > 1
    for agent, goal in enumerate(gridmap.goals, 1):
        labels.setdefault(goal, []).append("G" if shared_goal else f"G{agent}")
    for cell, texts in labels.items():
        row, col = gridmap.cells[cell]
        ax.text(col + 0.5, row + 0.5, "\n".join(dict.fromkeys(texts)), ha="center", va="center",
                fontsize="small", fontweight="bold", path_effects=[withStroke(linewidth=2.5, foreground="white")])


# --- a whole result directory ----------------------------------------------------------------------------


def write_figures(
    result_dir: str | os.PathLike,
    smooth: int | None = None,
    map_loader: Callable[[str], GridMap] | None = None,
) -> list[Path]:
    """Draw every figure of a result directory into it and return their paths.

    Reads ``episodes.csv``, ``manifest.json`` and, if present, ``observe.csv``. Writes collisions.png
    (linear axis), collisions_log.png (linear-then-log axis), steps.png, joint_plays.png (if LoC or CQ ran),
    state_space.png (if CQ ran) and observe_map.png (if the directory has an observe.csv: our CQ's, else the
    paper's; other algorithms found there get observe_map_<algo>.png). A directory holding several maps gets one
    set per map, each file name prefixed with ``<map>_``. ``smooth`` is the moving-average window of the
    per-episode curves, by default 1% of the episodes. ``map_loader`` turns a map name into a GridMap, for the
    observe map and for maps the manifest does not describe; by default the manifest's map is read from the file
    it was read from (``map_source``), any other by name.
    """
    result_dir = Path(result_dir)
    data = load_episodes(result_dir / EPISODES)
    manifest = load_manifest(result_dir)
    observe_path = result_dir / OBSERVE
    observations = load_observations(observe_path) if observe_path.exists() else None
    map_loader = map_loader or _manifest_map_loader(manifest)
    maps = by_map(data)
    written: list[Path] = []

    def draw(what: str, make: Callable[[], Path | list[Path]]) -> None:
        # A figure that cannot be drawn costs that figure, never the results written before it.
        try:
            made = make()
        except Exception as e:  # whatever a figure raises, the other figures and the results stand
            print(f"figure {what} of {result_dir} skipped: {type(e).__name__}: {e}", file=sys.stderr)
            return
        written.extend(made if isinstance(made, list) else [made])

    for name, by_algo in maps.items():
        prefix = f"{name}_" if len(maps) > 1 else ""
        window = smooth or max(1, next(iter(by_algo.values()))["collisions"].shape[1] // 100)
        draw(f"{prefix}collisions.png",
             lambda: plot_collisions(data, result_dir / f"{prefix}collisions.png", name, window))
        draw(f"{prefix}collisions_log.png",
             lambda: plot_collisions(data, result_dir / f"{prefix}collisions_log.png", name, window, log=True))
        if any(algo in JOINT_PLAY_ALGOS for algo in by_algo):
            draw(f"{prefix}joint_plays.png",
                 lambda: plot_joint_plays(data, result_dir / f"{prefix}joint_plays.png", name, window))
        if any(algo in STATE_SPACE_ALGOS for algo in by_algo):
            draw(f"{prefix}state_space.png",
                 lambda: plot_state_space(data, result_dir / f"{prefix}state_space.png",
                                          *_map_sizes(name, manifest, map_loader), name, window))
        if observations is not None:
            draw(f"{prefix}observe_map.png",
                 lambda: _observe_maps(observations, name, by_algo, map_loader, result_dir, prefix))
        draw(f"{prefix}steps.png", lambda: plot_steps(data, result_dir / f"{prefix}steps.png", name, window))
    return written


def _manifest_map_loader(manifest: dict) -> Callable[[str], GridMap]:
    # A map given as a path has a name (its file's stem) that no shipped map need have.
    source = Path(manifest.get("map_source", ""))

    def load(name: str) -> GridMap:
        return load_map(source) if manifest.get("map") == name and source.is_file() else load_map(name)

    return load


def _map_sizes(name: str, manifest: dict, map_loader: Callable[[str], GridMap]) -> tuple[int, int]:
    """(cells, agents) of a map: from the manifest when it describes this map, else from the map itself."""
    if manifest.get("map") == name and "n_cells" in manifest and "n_agents" in manifest:
        return int(manifest["n_cells"]), int(manifest["n_agents"])
    gridmap = map_loader(name)
    return len(gridmap.cells), gridmap.n_agents


def _observe_maps(
    observations: list[Observation],
    name: str,
    by_algo: dict[str, Runs],
    map_loader: Callable[[str], GridMap],
    result_dir: Path,
    prefix: str,
) -> list[Path]:
    # CQ is drawn even when it kept no joint state at all: an empty map is the finding (the paper's Fig. 4d).
    algos = {obs.algo for obs in observations if obs.map == name} | (set(STATE_SPACE_ALGOS) & set(by_algo))
    if not algos:
        return []
    gridmap = map_loader(name)
    main = next((a for a in reversed(STATE_SPACE_ALGOS) if a in algos), None)  # ours, else the paper's CQ
    return [
        plot_observe_map([obs for obs in observations if obs.map == name and obs.algo == algo], gridmap,
                         result_dir / f"{prefix}observe_map{'' if algo == main else '_' + algo}.png", algo)
        for algo in sorted(algos)
    ]
