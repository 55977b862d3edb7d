"""`cq-ros import movingai`: MovingAI maps and scenarios (files the tests write) become maps our loader reads,
with x the column and y the row; what we cannot represent is one line naming the file and line, exit 2."""

import pytest

from cq_ros.cli.main import main
from cq_ros.gridmap import load_map
from cq_ros.mapgen.movingai import MAX_CELLS
from cq_ros.mapf.planner import distances_to

# 5 wide, 4 high: a wall of trees (T) in column 2 with a gap in row 3; '@' out of bounds at the top right.
GRID = ["..T.@",
        ".GT..",
        "..T..",
        "....."]


def write_map(path, rows=GRID, header=None):
    header = header or ["type octile", f"height {len(rows)}", f"width {len(rows[0])}", "map"]
    path.write_text("\n".join(header + rows) + "\n")
    return path


def write_scen(path, tasks, width=5, height=4):
    lines = ["version 1"] + [f"0\tgrid.map\t{width}\t{height}\t{sx}\t{sy}\t{gx}\t{gy}\t7.0" for sx, sy, gx, gy in tasks]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_map_and_its_first_tasks_become_our_map(tmp_path, capsys):
    grid = write_map(tmp_path / "grid.map")
    # Three tasks; two are taken. Task 1: from x=0 y=0 to x=3 y=0, through the gap in row 3.
    scen = write_scen(tmp_path / "grid.scen", [(0, 0, 3, 0), (4, 3, 1, 1), (1, 0, 0, 3)])
    out = tmp_path / "grid.txt"
    assert main(["import", "movingai", str(grid), "--scen", str(scen), "--agents", "2", "--out", str(out)]) == 0
    m = load_map(out)
    assert (m.height, m.width, m.n_agents) == (4, 5, 2)
    passable = {(r, c) for r, row in enumerate(GRID) for c, ch in enumerate(row) if ch in ".G"}
    assert set(m.cells) == passable
    assert [m.cells[s] for s in m.starts] == [(0, 0), (3, 4)]  # (row, col) = (y, x)
    assert [m.cells[g] for g in m.goals] == [(0, 3), (1, 1)]
    # The trees are walls: from (0,1) east is blocked, and the way from agent 1's start to its goal is 9 moves.
    assert m.neighbours[m.index(0, 1)][1] == m.index(0, 1)
    assert distances_to(m, m.goals[0])[m.starts[0]] == 9
    assert "grid.map, the first 2 tasks of grid.scen" in out.read_text()


def test_without_a_scenario_the_drawing_is_printed_and_the_missing_agents_said(tmp_path, capsys):
    assert main(["import", "movingai", str(write_map(tmp_path / "grid.map"))]) == 0
    captured = capsys.readouterr()
    assert "+-+-+-+-+-+" in captured.out and "agent" not in captured.out.replace("# ", "")
    assert "no agents yet" in captured.err


@pytest.mark.parametrize("rows, header, where, what", [
    (["..S..", ".....", ".....", "....."], None, "grid.map:5:3", "terrain 'S' (swamp)"),
    (["....", ".....", ".....", "....."], ["type octile", "height 4", "width 5", "map"], "grid.map:5",
     "row 0 has 4 characters"),
    (GRID[:3], ["type octile", "height 4", "width 5", "map"], "grid.map:8", "the grid ends after 3 rows"),
    (GRID, ["type hex", "height 4", "width 5", "map"], "grid.map:1", "only `octile`"),
    (GRID, ["type octile", "height four", "width 5", "map"], "grid.map:2", "height must be a whole number"),
    (["..x..", ".....", ".....", "....."], None, "grid.map:5:3", "unknown terrain 'x'"),
])
def test_a_map_we_cannot_represent_is_one_line_with_its_place(tmp_path, capsys, rows, header, where, what):
    grid = write_map(tmp_path / "grid.map", rows, header)
    with pytest.raises(SystemExit) as stop:
        main(["import", "movingai", str(grid)])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and len(err.strip().splitlines()) == 1
    assert f"{tmp_path}/{where}: " in err and what in err


def test_a_map_too_big_for_the_learners_is_refused(tmp_path, capsys):
    side = int(MAX_CELLS ** 0.5) + 1
    grid = write_map(tmp_path / "big.map", ["." * side] * side)
    with pytest.raises(SystemExit) as stop:
        main(["import", "movingai", str(grid)])
    assert stop.value.code == 2 and f"{side * side} passable cells" in capsys.readouterr().err


@pytest.mark.parametrize("tasks, agents, size, where, what", [
    ([(2, 0, 0, 0)], 1, (5, 4), "grid.scen:2", "start x=2 y=0 is on a blocked cell"),
    ([(0, 0, 4, 0)], 1, (5, 4), "grid.scen:2", "goal x=4 y=0 is on a blocked cell"),
    ([(0, 0, 9, 0)], 1, (5, 4), "grid.scen:2", "goal x=9 y=0 is off the 5x4 map"),
    ([(0, 0, 1, 1)], 1, (6, 4), "grid.scen:2", "the task is for a 6x4 map"),
    ([(0, 0, 1, 1), (0, 0, 3, 3)], 2, (5, 4), "grid.scen:3", "where the task on line 2 starts"),
    ([(0, 0, 1, 1)], 2, (5, 4), "grid.scen:2", "asked for 2 agents, the scenario holds 1 tasks"),
])
def test_a_task_we_cannot_represent_is_one_line_with_its_place(tmp_path, capsys, tasks, agents, size, where, what):
    grid = write_map(tmp_path / "grid.map")
    scen = write_scen(tmp_path / "grid.scen", tasks, *size)
    out = tmp_path / "out.txt"
    with pytest.raises(SystemExit) as stop:
        main(["import", "movingai", str(grid), "--scen", str(scen), "--agents", str(agents), "--out", str(out)])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and f"{tmp_path}/{where}: " in err and what in err
    assert not out.exists()


def test_an_unreachable_goal_is_refused(tmp_path, capsys):
    walled = ["..T..", "..T..", "..T..", "..T.."]  # no gap: the left and right halves never meet
    grid = write_map(tmp_path / "grid.map", walled)
    scen = write_scen(tmp_path / "grid.scen", [(0, 0, 4, 0)])
    with pytest.raises(SystemExit):
        main(["import", "movingai", str(grid), "--scen", str(scen), "--agents", "1"])
    assert "grid.scen:2: goal x=4 y=0 cannot be reached from start x=0 y=0" in capsys.readouterr().err


def test_agents_need_a_scenario(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["import", "movingai", str(write_map(tmp_path / "grid.map")), "--agents", "2"])
    assert stop.value.code == 2 and "--scen and --agents go together" in capsys.readouterr().err


def test_generated_shelves_are_a_movingai_warehouse_of_the_benchmarks_size(tmp_path, capsys):
    """`cq-ros generate shelves` writes a .map and .scen pair of 160 x 62 cells (MovingAI's warehouse-10-20-10-2-1
    is 161 x 63) that `cq-ros import movingai` reads: starts on the docking floor, goals on pick faces, all
    distinct, every goal reachable with the others parked."""
    assert main(["generate", "shelves", "--agents", "64", "--seed", "3", "--out", str(tmp_path / "shelves")]) == 0
    assert (tmp_path / "shelves.scen").read_text().splitlines()[1].startswith("0\tshelves.map\t160\t62\t")
    out = tmp_path / "shelves.txt"
    assert main(["import", "movingai", str(tmp_path / "shelves.map"), "--scen", str(tmp_path / "shelves.scen"),
                 "--agents", "64", "--out", str(out)]) == 0
    m = load_map(out)
    assert (m.height, m.width, m.n_agents) == (62, 160, 64)
    assert len(set(m.starts)) == len(set(m.goals)) == 64
    assert all(m.cells[s][1] < 13 or m.cells[s][1] >= 160 - 13 for s in m.starts)
    for goal in m.goals:  # a pick face: a shelf ('@', outside the world) just above it
        row, col = m.cells[goal]
        assert (row - 1, col) not in m.cells and 13 < col < 160 - 13
    assert m.goal_blocked_by_parked() == []
    lengths = [int(line.split("\t")[8]) for line in (tmp_path / "shelves.scen").read_text().splitlines()[1:]]
    assert lengths == [int(distances_to(m, g)[s]) for s, g in zip(m.starts, m.goals)]


def test_generate_shelves_says_what_does_not_fit(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["generate", "shelves", "--agents", "200", "--shelf-rows", "1", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "200 agents do not fit: 1 x 11 shelves have 110 pick faces" in err
    assert not (tmp_path / "s.map").exists()
