"""Tests of cq_ros.gridmap: the reference maps' shapes, move tables, parser errors, map defaults (`set`
lines) and reachability (unreachable goals rejected, agents walled in by an early arrival reported)."""

import dataclasses

import pytest

from cq_ros.gridmap import (
    ACTIONS,
    GridMap,
    MapError,
    available_maps,
    load_map,
    map_text,
    parse_map,
)

NORTH, EAST, SOUTH, WEST = range(4)
REFERENCE_CELLS = {
    "grid_game_2": 9,
    "tunnel_to_goal": 25,
    "tunnel_to_goal_3": 55,
    "isr": 43,
    "cit": 69,
    "cmu": 133,
}


def reachable(grid: GridMap, start: int) -> set[int]:
    seen, todo = {start}, [start]
    while todo:
        for nxt in grid.neighbours[todo.pop()]:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def reparse_drawing(grid: GridMap) -> GridMap:
    """Parse the agent lines of ``grid`` with its own draw() (marks cleared back to '.')."""
    agent_lines = [
        f"agent {k}: start {grid.cells[s][0]},{grid.cells[s][1]}  goal {grid.cells[g][0]},{grid.cells[g][1]}"
        for k, (s, g) in enumerate(zip(grid.starts, grid.goals), start=1)
    ]
    plain = grid.draw(marks={i: "." for i in range(grid.n_cells)})
    parsed = parse_map("\n".join(agent_lines) + "\n\n" + plain)
    return dataclasses.replace(parsed, name=grid.name, source=grid.source, defaults=grid.defaults)


# --- shipped maps ------------------------------------------------------------------------------------


def test_actions_order():
    assert ACTIONS == ("NORTH", "EAST", "SOUTH", "WEST")


@pytest.mark.parametrize(("name", "n_cells"), REFERENCE_CELLS.items())
def test_reference_map_sizes(name, n_cells):
    grid = load_map(name)
    assert (grid.name, grid.n_cells, grid.n_agents) == (name, n_cells, 2)
    assert len(grid.neighbours) == n_cells
    assert list(grid.cells) == sorted(grid.cells)


def test_available_maps_lists_the_shipped_maps():
    assert available_maps() == sorted(REFERENCE_CELLS) + ["warehouse_16", "warehouse_16_delayed", "warehouse_32",
                                                        "warehouse_8", "warehouse_8_delayed"]


@pytest.mark.parametrize("name", available_maps())
def test_neighbours_are_symmetric(name):
    grid = load_map(name)
    opposite = {NORTH: SOUTH, SOUTH: NORTH, EAST: WEST, WEST: EAST}
    for cell, moves in enumerate(grid.neighbours):
        for action, target in enumerate(moves):
            if target != cell:
                assert grid.neighbours[target][opposite[action]] == cell
                assert grid.distance(cell, target) == 1


@pytest.mark.parametrize("name", available_maps())
def test_every_goal_reachable_and_drawing_round_trips(name):
    grid = load_map(name)
    for start, goal in zip(grid.starts, grid.goals):
        assert goal in reachable(grid, start)
    assert reparse_drawing(grid) == grid


def test_tunnel_to_goal_by_hand():
    grid = load_map("tunnel_to_goal")
    assert (grid.height, grid.width) == (5, 5)
    assert grid.starts == (grid.index(0, 0), grid.index(4, 0))
    assert grid.goals == (grid.index(2, 0),) * 2

    def move(row, col, action):
        return grid.cells[grid.neighbours[grid.index(row, col)][action]]

    assert move(2, 0, WEST) == (2, 0)  # grid edge
    assert move(2, 0, NORTH) == (2, 0)  # the tunnel's walls
    assert move(2, 0, SOUTH) == (2, 0)
    assert move(2, 0, EAST) == (2, 1)
    assert move(1, 0, SOUTH) == (1, 0)  # wall under row 1
    assert move(1, 4, SOUTH) == (2, 4)  # the tunnel's mouth
    assert move(3, 4, NORTH) == (2, 4)
    assert move(3, 3, NORTH) == (3, 3)
    assert move(0, 0, NORTH) == (0, 0)
    assert move(0, 0, EAST) == (0, 1)
    assert move(0, 0, SOUTH) == (1, 0)


def test_bumps_at_hash_cells_and_missing_edge_walls():
    # No wall drawn anywhere: the '#' cell and the grid edge still stop a move.
    grid = parse_map("agent 1: start 0,0  goal 1,1\n\n+ + +\n . # \n+ + +\n . . \n+ + +\n")
    assert grid.cells == ((0, 0), (1, 0), (1, 1))
    top, bottom_left, bottom_right = range(3)
    assert grid.neighbours[top] == (top, top, bottom_left, top)
    assert grid.neighbours[bottom_left] == (top, bottom_right, bottom_left, bottom_left)
    assert grid.neighbours[bottom_right] == (bottom_right, bottom_right, bottom_right, bottom_left)


def test_shared_goal_and_start_on_other_agents_goal_are_allowed():
    assert load_map("tunnel_to_goal").goals[0] == load_map("tunnel_to_goal").goals[1]
    isr = load_map("isr")
    assert isr.starts == isr.goals[::-1]


def test_index_distance_and_draw():
    grid = load_map("grid_game_2")
    assert grid.index(1, 2) == 5
    with pytest.raises(KeyError, match=r"\(3, 0\)"):
        grid.index(3, 0)
    assert grid.distance(grid.index(0, 0), grid.index(2, 2)) == 4
    assert grid.draw() == "+-+-+-+\n|. G .|\n+ + + +\n|. . .|\n+-+ +-+\n|1 . 2|\n+-+-+-+"
    assert grid.draw(marks={grid.index(0, 1): "*", grid.starts[0]: "."}).splitlines()[1] == "|. * .|"
    with pytest.raises(ValueError):
        grid.draw(marks={0: "ab"})


def test_load_by_name_and_by_path(tmp_path):
    by_name = load_map("isr")
    assert by_name.source.endswith("isr.txt")
    path = tmp_path / "my_isr.txt"
    path.write_text(map_text("isr"))
    for how in (path, str(path)):
        by_path = load_map(how)
        assert (by_path.name, by_path.source) == ("my_isr", str(path))
        assert dataclasses.replace(by_path, name="isr", source=by_name.source) == by_name


def test_a_file_in_the_working_directory_loads_whatever_its_extension(tmp_path, monkeypatch):
    """`cq-ros generate warehouse --out wh.map` then `--map wh.map`: a bare name that is a file, not a shipped map."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "wh.map").write_text(map_text("isr"))
    assert load_map("wh.map").source == "wh.map"
    (tmp_path / "isr").write_text(map_text("cit"))
    assert load_map("isr").source.endswith("isr.txt")  # a shipped map's name stays the shipped map


def test_unknown_name_lists_available_maps():
    with pytest.raises(MapError, match="no_such_map") as caught:
        load_map("no_such_map")
    for name in available_maps():
        assert name in str(caught.value)
    with pytest.raises(MapError, match="no_such_map"):
        map_text("no_such_map")


def test_missing_map_file(tmp_path):
    with pytest.raises(MapError, match="cannot read"):
        load_map(tmp_path / "absent.txt")


# --- parser errors -----------------------------------------------------------------------------------

AGENTS = "agent 1: start 0,0  goal 0,2\nagent 2: start 1,0  goal 1,2\n"  # lines 1-2
OPEN = "+-+-+-+\n|. . .|\n+ + + +\n|. . .|\n+-+-+-+\n"  # lines 3-7 after AGENTS
HOLE = OPEN.replace("|. . .|\n+-", "|. # .|\n+-")
SPLIT = OPEN.replace("+ + + +", "+-+-+-+")
ROW_0 = "|. . .|\n+ +"  # line 4 with the start of line 5, which makes it unique


def drawing_with(old, new, drawing=OPEN):
    return AGENTS + drawing.replace(old, new, 1)


def agents_with(old, new, drawing=OPEN):
    return AGENTS.replace(old, new) + drawing


@pytest.mark.parametrize(
    ("text", "where", "phrase"),
    [
        pytest.param(drawing_with(ROW_0, "|. x .|\n+ +"), "4:4", "unknown character 'x'", id="unknown"),
        pytest.param(drawing_with(ROW_0, "|.\t. .|\n+ +"), "4:3", "unknown character '\\t'", id="tab"),
        pytest.param(drawing_with(ROW_0, "|. - .|\n+ +"), "4:4", "cannot stand at cell 0,1", id="misplaced-cell"),
        pytest.param(drawing_with("+ + + +", "+ +|+ +"), "5:4", "between up/down", id="misplaced-wall"),
        pytest.param(drawing_with(ROW_0, "|. .\n+ +"), "4:6", "too short: it ends before cell 0,2", id="short"),
        pytest.param(drawing_with("+ + + +", "+ + + + +"), "5:8", "longer than", id="long"),
        pytest.param(AGENTS + OPEN.rsplit("+-+-+-+", 1)[0] + "+-+-+\n", "7:6",
                     "too short: it ends before the wall below cell 1,2", id="ragged-bottom-border"),
        pytest.param(AGENTS + OPEN.rsplit("+-+-+-+", 1)[0] + "+-+-+-\n", "7:7",
                     "too short: it ends before the corner", id="ragged-bottom-corner"),
        pytest.param(drawing_with(ROW_0, "|. . .\n+ +"), "4:7", "too short: it ends before the wall right of cell 0,2",
                     id="ragged-right-border"),
        pytest.param(AGENTS + OPEN.rsplit("+-+-+-+", 1)[0], "6", "even number of lines", id="even-lines"),
        pytest.param(drawing_with("+-+-+-+", "+-+-+-"), "3", "drawing size inconsistent", id="even-width"),
        pytest.param(AGENTS + "+-+-+-+\n", "3", "drawing size inconsistent", id="one-line"),
        pytest.param(AGENTS + OPEN + "\n" + OPEN, "9:1", "second drawing", id="two-drawings"),
        pytest.param(agents_with("start 0,0", "start 0;0"), "1:16", "expected the start position", id="bad-start"),
        pytest.param(agents_with("1: start", "1: begin"), "1:10", "expected 'start'", id="bad-keyword"),
        pytest.param(agents_with("agent 2:", "agent two:"), "2:7", "expected the agent number", id="bad-number"),
        pytest.param(agents_with("goal 1,2", "goal 1,2 x"), "2:29", "expected the end of the line", id="trailing"),
        pytest.param(agents_with("agent 2:", "agent 3:"), "2:7", "out of order", id="order"),
        pytest.param(agents_with("start 1,0", "start 5,0"), "2:16", "off the grid", id="start-off"),
        pytest.param(agents_with("goal 0,2", "goal 0,-1"), "1:26", "off the grid", id="goal-off"),
        pytest.param(agents_with("goal 1,2", "goal 1,1", HOLE), "2:26", "'#' cell", id="goal-on-hash"),
        pytest.param(agents_with("start 1,0", "start 0,0"), "2:16", "where agent 1 starts", id="same-start"),
        pytest.param("# just a comment\n" + OPEN, None, "no agents", id="no-agents"),
        pytest.param(AGENTS, None, "no drawing", id="no-drawing"),
        pytest.param(agents_with("goal 1,2", "goal 0,1", SPLIT),
                     "2:26", "agent 2's goal 0,1 is unreachable", id="unreachable"),
        pytest.param(AGENTS + "set alhpa=0.2\n" + OPEN, "3:5", "unknown setting 'alhpa'", id="set-unknown"),
        pytest.param(AGENTS + "set  window = 2.5\n" + OPEN, "3:15", "window takes an integer", id="set-type"),
        pytest.param(AGENTS + "set gamma=1.5\n" + OPEN, "3:11", "gamma must be in [0, 1)", id="set-range"),
        pytest.param(AGENTS + "set gamma\n" + OPEN, "3:1", "expected 'set KEY=VALUE'", id="set-syntax"),
        pytest.param(AGENTS + "set alpha=0.2 x\n" + OPEN, "3:1", "expected 'set KEY=VALUE'", id="set-trailing"),
        pytest.param(AGENTS + "set alpha=0.2\nset alpha=0.3\n" + OPEN, "4:5", "alpha is set twice", id="set-twice"),
        pytest.param(AGENTS + "set conf_max=0.5\n" + OPEN, "3:14", "conf_max must be at least CONF_INIT",
                     id="set-order"),
    ],
)
def test_parse_errors(text, where, phrase):
    with pytest.raises(MapError) as caught:
        parse_map(text, source="bad.txt")
    message = str(caught.value)
    assert message.startswith(f"bad.txt:{where}: " if where else "bad.txt: ")
    assert phrase in message


def test_good_texts_parse():
    for drawing in (OPEN, HOLE):
        assert parse_map(AGENTS + drawing).n_agents == 2
    open_edge = "+-+-+-+\n|. . .|\n+ + + +\n|. . .|\n+-+-+-+".replace("|\n", " \n")  # east edge drawn open
    assert parse_map("# c\n" + AGENTS + "\n" + open_edge + "\n\n").n_cells == 6
    # A line may end early beside '#' cells and the outside only (cit's right edge): here, above a '#' cell.
    assert parse_map(AGENTS.replace("goal 1,2", "goal 1,1") + "+-+-+-+\n|. . .|\n+ + + +\n|. .|#\n+-+-+\n").n_cells == 5
    assert parse_map(AGENTS.replace("\n", "\r\n") + OPEN).n_cells == 6


# --- map defaults ------------------------------------------------------------------------------------


def test_set_lines_become_the_maps_defaults():
    text = AGENTS + "set reward_step=-1\n# a comment\nset window = 30\nset conf_max=20\nset conf_up=1.5\n" + OPEN
    grid = parse_map(text)
    assert grid.defaults == {"reward_step": -1.0, "window": 30, "conf_max": 20.0, "conf_up": 1.5}
    assert type(grid.defaults["window"]) is int and type(grid.defaults["reward_step"]) is float
    assert parse_map(AGENTS + OPEN).defaults == {}
    assert dataclasses.replace(grid, defaults={}) != grid  # the defaults are part of the map


@pytest.mark.parametrize("name", ["grid_game_2", "tunnel_to_goal", "tunnel_to_goal_3", "isr", "cit", "cmu"])
def test_the_papers_maps_carry_no_defaults(name):
    assert load_map(name).defaults == {}


# --- reachability ------------------------------------------------------------------------------------

# Agent 2 parked at its goal 0,1 is the only way from agent 1's start to agent 1's goal 0,2.
CORNER = "+-+-+-+\n|. . .|\n+ +-+-+\n|. . #\n+-+-+-+\n"
WALLED = "agent 1: start 1,0  goal 0,2\nagent 2: start 1,1  goal 0,1\n" + CORNER


def test_an_agent_walled_in_by_an_early_arrival_is_reported_not_rejected():
    grid = parse_map(WALLED)
    assert grid.walled_in() == [(0, 1)]
    assert grid.goal_blocked_by_parked() == [0]
    assert grid.reachable(grid.starts[0], frozenset({grid.goals[1]})) == {grid.index(1, 0), grid.index(1, 1),
                                                                          grid.index(0, 0)}


def test_agents_sharing_a_goal_do_not_wall_each_other_in():
    shared = parse_map("agent 1: start 1,0  goal 0,2\nagent 2: start 1,1  goal 0,2\n" + CORNER)
    assert shared.walled_in() == [] and shared.goal_blocked_by_parked() == []
    for name in ("tunnel_to_goal", "tunnel_to_goal_3"):
        grid = load_map(name)
        assert grid.goals[0] == grid.goals[1] and grid.walled_in() == []


def test_walled_in_takes_one_parked_agent_at_a_time_the_generators_check_all_of_them():
    # Two ways round the shelf to agent 1's goal 1,4; agents 2 and 3 each park on one of them.
    ring = ("agent 1: start 1,0  goal 1,4\nagent 2: start 0,1  goal 0,2\nagent 3: start 2,1  goal 2,2\n"
            "+-+-+-+-+-+\n|. . . . .|\n+ +-+-+-+ +\n|.|# # #|.|\n+ +-+-+-+ +\n|. . . . .|\n+-+-+-+-+-+\n")
    grid = parse_map(ring)
    assert grid.walled_in() == []
    assert grid.goal_blocked_by_parked() == [0]
