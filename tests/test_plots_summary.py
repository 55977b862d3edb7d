"""Tests of the result readers, metrics, tables and figures, on small hand-made result directories.

The maps are fakes shaped like ``cq_ros.gridmap.GridMap``, so these tests exercise only the reporting code.
"""

from __future__ import annotations

import csv
import json
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from cq_ros.lab import plots
from cq_ros.episode import COLUMNS
from cq_ros.lab.results import EPISODE_COLUMNS, OBSERVE_COLUMNS, Observation, load_episodes, load_observations
from cq_ros.lab.summary import (
    compute_metrics,
    format_console_table,
    moving_average,
    observation_strength,
    settled_episode,
    summary_table,
)

RUNS, EPISODES = 3, 200
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class FakeMap:
    """A GridMap look-alike: 3 rows x 4 columns, (0, 3) not part of the world, a wall east of (1, 1)."""

    name: str = "fake"
    height: int = 3
    width: int = 4
    starts: tuple[int, ...] = (0, 8)
    goals: tuple[int, ...] = (10, 10)

    @property
    def cells(self) -> tuple[tuple[int, int], ...]:
        return tuple((r, c) for r in range(self.height) for c in range(self.width) if (r, c) != (0, 3))

    @property
    def neighbours(self) -> tuple[tuple[int, int, int, int], ...]:
        index = {cell: i for i, cell in enumerate(self.cells)}
        walls = {((1, 1), (1, 2)), ((1, 2), (1, 1))}

        def move(i: int, d_row: int, d_col: int) -> int:
            row, col = self.cells[i]
            target = (row + d_row, col + d_col)
            return i if target not in index or ((row, col), target) in walls else index[target]

        steps = ((-1, 0), (0, 1), (1, 0), (0, -1))  # N, E, S, W
        return tuple(tuple(move(i, *step) for step in steps) for i in range(len(self.cells)))

    @property
    def n_agents(self) -> int:
        return len(self.starts)


def column(value: float) -> np.ndarray:
    return np.full((RUNS, EPISODES), value, dtype=float)


def hand_made(algo: str) -> dict[str, np.ndarray]:
    """Collisions 1 per episode in episodes 0-49, none after; each algorithm a little different."""
    collisions = column(0)
    collisions[:, :50] = 1
    steps = column(20)
    steps[:, -20:] = np.array([[10], [20], [30]])  # run r finishes the tail in 10 (r + 1) steps
    states = column(22 if algo == "cq" else 11)
    states[:, -1] = [24, 25, 29]
    joint_plays = column(4 if algo in ("cq", "loc") else 0)
    truncated = column(0)
    truncated[1, :3] = 1
    heard = column(7 if algo in ("cq", "loc") else 0)
    return {"steps": steps, "collisions": collisions, "joint_plays": joint_plays, "states": states,
            "return": -steps, "truncated": truncated, "heard": heard}


def write_episodes(path: Path, tables: dict[tuple[str, str], dict[str, np.ndarray]], reverse: bool = False) -> None:
    rows = []
    for (map_name, algo), columns in tables.items():
        for run in range(RUNS):
            for episode in range(EPISODES):
                values = [columns[name][run, episode] for name in COLUMNS]
                rows.append([map_name, algo, run, episode, *(f"{v:g}" for v in values)])
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(EPISODE_COLUMNS)
        writer.writerows(rows[::-1] if reverse else rows)


def write_result(directory: Path, maps: tuple[str, ...] = ("fake",), algos=("indep", "loc", "cq")) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    write_episodes(directory / "episodes.csv", {(m, a): hand_made(a) for m in maps for a in algos})
    with open(directory / "observe.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(OBSERVE_COLUMNS)
        for m in maps:
            writer.writerows([[m, "cq", 0, 1, 1, 1, 2, 1, 2, 2.5], [m, "cq", 1, 2, 1, 1, 1, 1, 0, 0.5],
                              [m, "cq", 1, 2, 2, 2, 1, 2, 1, 1.0]])
    manifest = {"map": maps[0], "n_agents": 2, "n_cells": 11, "algos": list(algos), "runs": RUNS,
                "episodes": EPISODES, "seed": 0, "settings": {}}
    (directory / "manifest.json").write_text(json.dumps(manifest))
    return directory


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    return struct.unpack(">II", data[16:24])


# --- loading ------------------------------------------------------------------------------------------


def test_load_episodes_gives_runs_by_episodes_whatever_the_row_order(tmp_path):
    tables = {("fake", "cq"): hand_made("cq"), ("fake", "indep"): hand_made("indep")}
    write_episodes(tmp_path / "episodes.csv", tables, reverse=True)
    data = load_episodes(tmp_path / "episodes.csv")
    assert set(data) == set(tables)
    for key, columns in tables.items():
        for name, expected in columns.items():
            assert data[key][name].shape == (RUNS, EPISODES)
            np.testing.assert_array_equal(data[key][name], expected)


def test_load_episodes_reads_counts_written_as_floats(tmp_path):
    path = tmp_path / "episodes.csv"
    rows = ["m,cq,0.0,0.0,12.0,1.0,0.0,9.0,-3.5,0.0,4.0", "m,cq,0.0,1.0,8.0,0.0,1.0,10.0,2.0,0.0,0.0"]
    path.write_text("\n".join([",".join(EPISODE_COLUMNS), *rows]) + "\n")
    data = load_episodes(path)
    np.testing.assert_array_equal(data[("m", "cq")]["steps"], [[12, 8]])
    np.testing.assert_array_equal(data[("m", "cq")]["return"], [[-3.5, 2.0]])


@pytest.mark.parametrize(
    "body, message",
    [
        ("m,cq,0,0,5,0,0,9,1,0,2\nm,cq,0,2,5,0,0,9,1,0,2\n", "episodes 0..2"),  # episode 1 missing
        ("m,cq,0,0,5,0,0,9,1,0,2\nm,cq,0,0,5,0,0,9,1,0,2\n", "episodes 0..0"),  # a row twice
        ("m,cq,0,0,5,0,0,9,1,0,2\nm,cq,1,0,5,0,0,9,1,0,2\nm,cq,1,1,5,0,0,9,1,0,2\n", "2 runs"),  # a short run
        ("m,cq,0,-1,5,0,0,9,1,0,2\nm,cq,0,0,5,0,0,9,1,0,2\n", "episodes"),  # before the first
    ],
)
def test_load_episodes_rejects_incomplete_groups(tmp_path, body, message):
    path = tmp_path / "episodes.csv"
    path.write_text(",".join(EPISODE_COLUMNS) + "\n" + body)
    with pytest.raises(ValueError, match=message):
        load_episodes(path)


def test_load_episodes_reads_a_file_kept_from_before_heard_was_a_column(tmp_path):
    path = tmp_path / "episodes.csv"
    kept = [c for c in EPISODE_COLUMNS if c != "heard"]
    assert EPISODE_COLUMNS[-1] == "heard"
    path.write_text(",".join(kept) + "\nm,cq,0,0,12,1,0,9,-3.5,0\nm,cq,0,1,8,0,1,10,2,0\n")
    data = load_episodes(path)[("m", "cq")]
    assert "heard" not in data
    np.testing.assert_array_equal(data["steps"], [[12, 8]])
    np.testing.assert_array_equal(data["truncated"], [[0, 0]])


def test_load_episodes_rejects_another_header(tmp_path):
    path = tmp_path / "episodes.csv"
    path.write_text("map,algo,run,episode,steps\nm,cq,0,0,5\n")
    with pytest.raises(ValueError, match="header"):
        load_episodes(path)


def test_load_observations_and_strength_per_agent(tmp_path):
    observations = load_observations(write_result(tmp_path) / "observe.csv")
    assert observations[0] == Observation("fake", "cq", 0, 1, 1, 1, 2, 1, 2, 2.5)
    # Agent 2 keeps 0.5 in (1, 1) and 1.0 in (2, 2): normalised by its largest.
    assert observation_strength(observations) == {1: {(1, 1): 1.0}, 2: {(1, 1): 0.5, (2, 2): 1.0}}


def test_observation_strength_sums_joint_states_and_runs_of_a_cell():
    rows = [Observation("m", "cq", run, 1, 0, 0, 2, r, 1, 1.0) for run in range(2) for r in range(3)]
    rows.append(Observation("m", "cq", 0, 1, 0, 1, 2, 0, 0, 3.0))
    assert observation_strength(rows) == {1: {(0, 0): 1.0, (0, 1): 0.5}}


# --- metrics ------------------------------------------------------------------------------------------


def test_moving_average_is_trailing_and_averages_what_there_is_at_the_start():
    np.testing.assert_allclose(moving_average([1, 2, 3, 4, 5], 2), [1, 1.5, 2.5, 3.5, 4.5])
    np.testing.assert_allclose(moving_average([1, 2, 3, 4, 5], 10), [1, 1.5, 2, 2.5, 3])
    np.testing.assert_allclose(moving_average([[1, 3, 5], [0, 0, 6]], 2), [[1, 2, 4], [0, 0, 3]])
    np.testing.assert_array_equal(moving_average([4, 0, 7], 1), [4, 0, 7])
    with pytest.raises(ValueError):
        moving_average([1, 2], 0)


def test_settled_episode_after_collisions_stop_at_episode_50():
    collisions = hand_made("cq")["collisions"]
    # Window 100: from episode 99 the average is (149 - t) / 100, below 0.05 from t = 145 on.
    assert settled_episode(collisions, window=100) == 145
    # Window 10: (59 - t) / 10 for t in 50..59, zero from episode 59.
    assert settled_episode(collisions, window=10) == 59


def test_settled_episode_waits_for_a_relapsing_run():
    collisions = hand_made("cq")["collisions"]
    collisions[0, 119] = 3  # run 0 collides 3 times in episode 119: run mean 1, window mean 0.1 until 128
    assert settled_episode(collisions, window=10) == 129
    collisions[2, -1] = 2  # 2 collisions of one run in the last episode: window mean 0.067, not settled
    assert settled_episode(collisions, window=10) is None
    assert settled_episode(np.zeros((2, 5)), window=10) == 0


def test_compute_metrics_on_hand_made_runs():
    data = {("fake", algo): hand_made(algo) for algo in ("cq", "indep", "loc")}
    data[("fake", "cq")]["collisions"][:, -20:] = np.array([[0], [1], [2]])  # tail means 0, 1, 2 per run
    metrics = compute_metrics(data, window=10)
    assert [m.algo for m in metrics] == ["indep", "loc", "cq"]  # the paper's order
    cq = metrics[-1]
    assert (cq.map, cq.runs, cq.episodes) == ("fake", RUNS, EPISODES)
    assert cq.collisions_tail == pytest.approx(1.0)
    assert cq.collisions_tail_std == pytest.approx(np.sqrt(2 / 3))
    assert cq.settled_episode is None
    assert cq.final_states == pytest.approx(26.0)
    assert cq.joint_plays_tail == cq.joint_plays_all == pytest.approx(4.0)
    assert cq.steps_tail == pytest.approx(20.0)
    assert cq.truncated == 3
    indep = metrics[0]
    assert (indep.collisions_tail, indep.collisions_tail_std, indep.settled_episode) == (0.0, 0.0, 59)
    assert indep.joint_plays_all == 0.0


def test_tables_have_a_row_per_algorithm(tmp_path):
    data = {("fake", algo): hand_made(algo) for algo in ("cq", "indep", "jsa", "loc")}
    markdown = summary_table(data, window=10)
    rows = [line for line in markdown.splitlines() if line.startswith("| fake |")]
    assert [row.split(" | ")[1] for row in rows] == ["indep", "jsa", "loc", "cq"]
    assert markdown.splitlines()[1].startswith("| --- | --- | ---: |")
    assert "| 59 |" in rows[0] and "| 26 |" in rows[-1]
    console = format_console_table(data, window=10)
    console_rows = [line.split() for line in console.splitlines() if line.startswith("fake")]
    assert [row[1] for row in console_rows] == ["indep", "jsa", "loc", "cq"]
    assert "|" not in console


# --- figures ------------------------------------------------------------------------------------------


def test_write_figures_draws_every_figure_of_a_result_directory(tmp_path):
    directory = write_result(tmp_path / "result")
    paths = plots.write_figures(directory, map_loader=lambda name: FakeMap(name=name))
    names = ["collisions.png", "collisions_log.png", "joint_plays.png", "state_space.png", "observe_map.png",
             "steps.png"]
    assert sorted(path.name for path in paths) == sorted(names)
    for path in paths:
        assert path.parent == directory
        width, height = png_size(path)
        assert width >= 700 and height >= 400
    assert png_size(directory / "collisions.png") == (1050, 630)  # 7 x 4.2 inches at 150 dpi
    # Fig. 3 twice: on the paper's linear axis, and on the linear-then-log one
    assert (directory / "collisions.png").read_bytes() != (directory / "collisions_log.png").read_bytes()


def test_write_figures_for_several_maps_prefixes_each_set(tmp_path):
    directory = write_result(tmp_path / "grid", maps=("alpha", "beta"), algos=("indep", "js"))
    loaded = []
    paths = plots.write_figures(directory, map_loader=lambda name: loaded.append(name) or FakeMap(name=name))
    # Without CQ or LoC there are no joint plays or state space; observe.csv still holds CQ rows.
    expected = {f"{m}_{figure}.png" for m in ("alpha", "beta")
                for figure in ("collisions", "collisions_log", "observe_map", "steps")}
    assert {path.name for path in paths} == expected
    assert loaded == ["alpha", "beta"]
    assert all(path.read_bytes()[:8] == PNG_MAGIC for path in paths)


@pytest.mark.slow
def test_state_space_of_a_map_the_manifest_does_not_describe_comes_from_the_map(tmp_path):
    directory = write_result(tmp_path / "grid", maps=("alpha", "beta"), algos=("cq",))
    loaded = []
    paths = plots.write_figures(directory, map_loader=lambda name: loaded.append(name) or FakeMap(name=name))
    assert "beta_state_space.png" in {path.name for path in paths}
    assert loaded.count("beta") == 2 and loaded.count("alpha") == 1  # alpha's sizes come from the manifest


def test_observe_map_shows_two_agents_in_one_cell(tmp_path):
    both = [Observation("fake", "cq", 0, agent, 1, 1, 3 - agent, 0, 0, 2.0) for agent in (1, 2)]
    path = plots.plot_observe_map(both, FakeMap(), tmp_path / "observe.png")
    pixels = imread(path)[..., :3]
    for colour in (plots._agent_colour(1), plots._agent_colour(2)):
        matching = np.all(np.abs(pixels - np.array(colour[:3])) < 0.02, axis=-1).sum()
        assert matching > 2000  # half a cell of 90 x 90 pixels, far more than a legend swatch


def test_observe_map_without_joint_states_still_draws_the_map(tmp_path):
    path = plots.plot_observe_map([], FakeMap(), tmp_path / "empty.png")
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_figures_need_a_map_name_when_the_data_holds_several(tmp_path):
    data = {(m, "cq"): hand_made("cq") for m in ("alpha", "beta")}
    with pytest.raises(ValueError, match="choose a map"):
        plots.plot_collisions(data, tmp_path / "c.png")
    assert plots.plot_collisions(data, tmp_path / "c.png", map_name="beta", smooth=10).exists()
    with pytest.raises(ValueError, match="joint plays"):
        plots.plot_joint_plays({("alpha", "js"): hand_made("js")}, tmp_path / "j.png")


def test_the_state_space_of_a_fleet_too_large_for_a_float_is_drawn_and_labelled(tmp_path):
    # 1,092 cells and 128 agents: a joint state count of 389 digits, which matplotlib's floats cannot hold
    data = load_episodes(write_result(tmp_path / "result") / "episodes.csv")
    path = plots.plot_state_space(data, tmp_path / "state_space.png", 1092, 128, "fake", 10)
    assert png_size(path)[0] >= 700
    assert plots._count(1092**128) == "7.81e+388" and plots._count(3025**2) == "9,150,625"


def test_a_figure_that_cannot_be_drawn_is_skipped_in_one_line_and_the_others_drawn(tmp_path, monkeypatch, capsys):
    directory = write_result(tmp_path / "result")

    def broken(*args, **kwargs):
        raise OverflowError("int too large to convert to float")

    monkeypatch.setattr(plots, "plot_state_space", broken)
    paths = plots.write_figures(directory, map_loader=lambda name: FakeMap(name=name))
    assert "state_space.png" not in {p.name for p in paths} and "steps.png" in {p.name for p in paths}
    [line] = capsys.readouterr().err.splitlines()
    assert line == f"figure state_space.png of {directory} skipped: OverflowError: int too large to convert to float"
    assert (directory / "episodes.csv").exists() and (directory / "manifest.json").exists()
