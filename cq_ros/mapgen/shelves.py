"""A warehouse on a plain cell grid, in the shape and size of the MovingAI benchmark's warehouse maps (blocks of
shelves between two-cell corridors, open docking floor left and right; about 160 x 60 cells), written as a
MovingAI `.map` and `.scen` pair for `cq-ros import movingai`.

Where ``cq_ros.mapgen.warehouse`` draws walls between cells (bays open to one lane only), a MovingAI grid has
only passable and blocked cells, so this layout needs none: shelves are blocks of `@` two cells deep and
``SHELF_LENGTH`` long, the corridors around them two cells wide. Starts are distinct cells of the docking floor;
goals are distinct pick faces, the corridor cells just below a shelf. The corridor lane next to the shelf below
holds no goal, so it stays free whatever agents are parked, and every goal is reachable from every start with
the others parked at theirs (checked on the map as imported, not assumed).

Sizes (rows from the top): a corridor of 2 rows, then per shelf row 2 rows of shelves and 2 of corridor, so
height = 4 * shelf_rows + 2; width = 2 * DOCK_WIDTH + shelf_cols * SHELF_LENGTH + 2 * (shelf_cols + 1). The
defaults, 15 shelf rows of 11 shelves, give 160 x 62 (MovingAI's warehouse-10-20-10-2-1 is 161 x 63).
"""

from __future__ import annotations

from collections import deque

from ..gridmap import parse_map
from .draw import check_sizes, draw_starts_and_goals
from .movingai import Task, grid_text

__all__ = ["DEFAULT_SHELF_COLS", "DEFAULT_SHELF_ROWS", "shelves_files", "shelves_layout"]

SHELF_LENGTH = 10
DOCK_WIDTH = 13
CORRIDOR = 2
DEFAULT_SHELF_ROWS = 15
DEFAULT_SHELF_COLS = 11

Cell = tuple[int, int]


def shelves_layout(shelf_rows: int, shelf_cols: int) -> tuple[int, int, frozenset[Cell], list[Cell], list[Cell]]:
    """Height, width, the passable cells (row, col), the docks and the pick faces."""
    height = 4 * shelf_rows + CORRIDOR
    width = 2 * DOCK_WIDTH + shelf_cols * SHELF_LENGTH + CORRIDOR * (shelf_cols + 1)
    shelf, faces = set(), []
    for r in range(shelf_rows):
        top = CORRIDOR + 4 * r
        for c in range(shelf_cols):
            left = DOCK_WIDTH + CORRIDOR + c * (SHELF_LENGTH + CORRIDOR)
            for col in range(left, left + SHELF_LENGTH):
                shelf.update(((top, col), (top + 1, col)))
                faces.append((top + 2, col))
    passable = frozenset((row, col) for row in range(height) for col in range(width) if (row, col) not in shelf)
    docks = [(row, col) for row in range(height) for col in (*range(DOCK_WIDTH), *range(width - DOCK_WIDTH, width))]
    return height, width, passable, sorted(docks), sorted(faces)


def shelves_files(agents: int, shelf_rows: int = DEFAULT_SHELF_ROWS, shelf_cols: int = DEFAULT_SHELF_COLS,
                  seed: int = 0, name: str = "shelves") -> tuple[str, str]:
    """(the `.map` text, the `.scen` text) of a generated grid warehouse whose map file is called `name`.map;
    the scenario's tasks are the agents, in order, its last field each one's shortest path alone (four moves,
    our world's; MovingAI's own files give the eight-way length). ValueError names what does not fit."""
    check_sizes(agents=agents, shelf_rows=shelf_rows, shelf_cols=shelf_cols)
    height, width, passable, docks, faces = shelves_layout(shelf_rows, shelf_cols)
    starts, goals = draw_starts_and_goals(agents, seed, ("dock cells", docks), ("pick faces", faces),
                                          f"{shelf_rows} x {shelf_cols} shelves", "give more shelf rows or columns")
    grid = ["".join("." if (row, col) in passable else "@" for col in range(width)) for row in range(height)]
    map_file = "\n".join(["type octile", f"height {height}", f"width {width}", "map", *grid]) + "\n"
    tasks = []
    for start, goal in zip(starts, goals):
        length = _moves(passable, start, goal)
        tasks.append(f"0\t{name}.map\t{width}\t{height}\t{start[1]}\t{start[0]}\t{goal[1]}\t{goal[0]}\t{length}")
    _check_parked(height, width, passable, starts, goals, seed)
    return map_file, "\n".join(["version 1", *tasks]) + "\n"


def _moves(passable: frozenset[Cell], start: Cell, goal: Cell) -> int:
    """Fewest four-way moves from start to goal (breadth first)."""
    seen, frontier = {start: 0}, deque([start])
    while frontier:
        row, col = here = frontier.popleft()
        if here == goal:
            return seen[here]
        for there in ((row - 1, col), (row, col + 1), (row + 1, col), (row, col - 1)):
            if there in passable and there not in seen:
                seen[there] = seen[here] + 1
                frontier.append(there)
    raise RuntimeError(f"generated grid warehouse: {goal} cannot be reached from {start}")


def _check_parked(height: int, width: int, passable: frozenset[Cell], starts: list[Cell], goals: list[Cell],
                  seed: int) -> None:
    """The layout's promise, checked on our map of it (what `cq-ros import movingai` makes)."""
    tasks = [Task(line, s, g) for line, (s, g) in enumerate(zip(starts, goals), start=2)]
    blocked = parse_map(grid_text(height, width, passable, tasks, [])).goal_blocked_by_parked()
    if blocked:
        raise RuntimeError(f"generated grid warehouse (seed {seed}) breaks its promise: agent(s) "
                           f"{', '.join(str(i + 1) for i in blocked)} cannot reach their goal with the others parked")
