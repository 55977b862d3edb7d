"""MovingAI maps and scenarios (the MAPF benchmark format POGEMA, the MAPF literature and Open-RMF's tools use)
turned into our map text (cq_ros.gridmap), for `cq-ros import movingai`.

A `.map` file is a header (`type octile`, `height H`, `width W`, `map`) and H lines of W terrain characters:
`.` and `G` are passable, `@`, `O` and `T` are not; `S` (swamp) and `W` (water) have rules of passage we have no
meaning for, so a map holding them is rejected. A `.scen` file (`version 1`, then one task a line:
bucket, map, width, height, start x, start y, goal x, goal y, optimal length) gives each agent its start and
goal, x the column and y the row, 0-based from the top left. Our world moves in four directions where the
format's octile moves in eight; octile moves never cut a corner, so the cells reachable are the same. Every
fault is a MovingAIError naming the file, line and (where there is one) column.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

from ..gridmap import draw_cells

__all__ = ["MAX_CELLS", "MovingAIError", "MovingAIMap", "Task", "grid_text", "map_text", "read_map", "read_scenario"]

PASSABLE = frozenset(".G")
BLOCKED = frozenset("@OT")
_NO_MEANING = {"S": "swamp", "W": "water"}
# The learners keep a table row per cell and CQ two 60-sample reward windows per (cell, action), in Python
# objects: about 1 kB a cell and agent when made (measured with tracemalloc, 10,000 cells), about 12 kB once the
# windows fill (480 floats), so 0.8 GB per CQ agent at this size; our loader reads such a map in 2.6 s here.
MAX_CELLS = 65_536


class MovingAIError(ValueError):
    """A MovingAI file we cannot represent; the message reads "FILE:LINE[:COL]: what is wrong"."""


def _error(path: Path, line: int, what: str, col: int | None = None) -> MovingAIError:
    return MovingAIError(f"{path}:{line}{f':{col}' if col is not None else ''}: {what}")


@dataclass(frozen=True)
class MovingAIMap:
    path: Path
    height: int
    width: int
    passable: frozenset[tuple[int, int]]  # (row, col)


@dataclass(frozen=True)
class Task:
    line: int  # in the scenario file
    start: tuple[int, int]  # (row, col)
    goal: tuple[int, int]


def _read_lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="ascii").splitlines()
    except UnicodeDecodeError as e:
        raise MovingAIError(f"{path}: not a MovingAI file (a byte that is not ASCII at offset {e.start})") from None
    except OSError as e:
        raise MovingAIError(f"{path}: cannot read: {e.strerror or e}") from None


def read_map(path: str | Path) -> MovingAIMap:
    """The map of a MovingAI `.map` file; MovingAIError naming the line (and column) of the first fault."""
    path = Path(path)
    lines = _read_lines(path)
    header: dict[str, str] = {}
    number = 0
    for number, line in enumerate(lines, start=1):
        words = line.split()
        if words == ["map"]:
            break
        if len(words) != 2 or words[0] not in ("type", "height", "width"):
            raise _error(path, number, f"expected a header line `type octile`, `height H`, `width W` or `map`, "
                                       f"got {line.strip()!r}")
        header[words[0]] = words[1]
    else:
        raise _error(path, max(number, 1), "no `map` line: the grid must follow the header's `map` line")
    for key in ("type", "height", "width"):
        if key not in header:
            raise _error(path, number, f"the header has no `{key}` line before `map`")
    if header["type"] != "octile":
        raise _error(path, 1, f"map type {header['type']!r}: only `octile` grids are MovingAI maps we read")
    height, width = (_size(path, lines, key, header[key]) for key in ("height", "width"))
    grid = lines[number:number + height]
    if len(grid) < height:
        raise _error(path, number + len(grid) + 1, f"the grid ends after {len(grid)} rows; the header says {height}")
    passable = set()
    for row, text in enumerate(grid):
        at = number + 1 + row
        text = text.rstrip("\r")
        if len(text) != width:
            raise _error(path, at, f"row {row} has {len(text)} characters; the header says width {width}")
        for col, char in enumerate(text):
            if char in PASSABLE:
                passable.add((row, col))
            elif char in _NO_MEANING:
                raise _error(path, at, f"terrain {char!r} ({_NO_MEANING[char]}) has no meaning in cq_ros' world: "
                                       "a cell is passable (. G) or not (@ O T)", col + 1)
            elif char not in BLOCKED:
                raise _error(path, at, f"unknown terrain {char!r} (MovingAI maps use . G @ O T S W)", col + 1)
    extra = [n for n, text in enumerate(lines[number + height:], start=number + height + 1) if text.strip()]
    if extra:
        raise _error(path, extra[0], f"text after the {height} rows of the grid")
    if not passable:
        raise _error(path, number, "the grid has no passable cell")
    if len(passable) > MAX_CELLS:
        raise _error(path, number, f"{len(passable)} passable cells; cq_ros' learners take at most {MAX_CELLS} "
                                   "(a table row and, for CQ, two reward windows per cell and action)")
    return MovingAIMap(path, height, width, frozenset(passable))


def _size(path: Path, lines: list[str], key: str, value: str) -> int:
    line = next(n for n, text in enumerate(lines, start=1) if text.split()[:1] == [key])
    if not value.isdigit() or int(value) < 1:
        raise _error(path, line, f"{key} must be a whole number of at least 1, got {value!r}")
    return int(value)


def read_scenario(path: str | Path, gridmap: MovingAIMap, agents: int) -> list[Task]:
    """The first `agents` tasks of a MovingAI `.scen` file, checked against `gridmap`: on passable cells, starts
    distinct, each goal reachable from its start; MovingAIError naming the line otherwise."""
    path = Path(path)
    lines = _read_lines(path)
    if not lines or lines[0].split()[:1] != ["version"]:
        raise _error(path, 1, "expected `version 1` on the first line of a scenario")
    component = _components(gridmap.passable)
    tasks: list[Task] = []
    started: dict[tuple[int, int], int] = {}
    for number, line in enumerate(lines[1:], start=2):
        if len(tasks) == agents:
            break
        if not line.strip():
            continue
        fields = line.split("\t") if "\t" in line else line.split()
        if len(fields) != 9:
            raise _error(path, number, f"expected 9 fields (bucket, map, width, height, start x, start y, goal x, "
                                       f"goal y, optimal length), got {len(fields)}")
        try:
            width, height, sx, sy, gx, gy = (int(f) for f in fields[2:8])
        except ValueError:
            raise _error(path, number, "width, height and the x, y of start and goal must be whole numbers") from None
        if (width, height) != (gridmap.width, gridmap.height):
            raise _error(path, number, f"the task is for a {width}x{height} map; {gridmap.path} is "
                                       f"{gridmap.width}x{gridmap.height} (width x height)")
        task = Task(number, (sy, sx), (gy, gx))
        for role, (row, col) in (("start", task.start), ("goal", task.goal)):
            if not (0 <= row < height and 0 <= col < width):
                raise _error(path, number, f"{role} x={col} y={row} is off the {width}x{height} map")
            if (row, col) not in gridmap.passable:
                raise _error(path, number, f"{role} x={col} y={row} is on a blocked cell of {gridmap.path}")
        if task.start in started:
            raise _error(path, number, f"start x={sx} y={sy} is where the task on line {started[task.start]} starts: "
                                       "our agents start on distinct cells")
        if component[task.start] != component[task.goal]:
            raise _error(path, number, f"goal x={gx} y={gy} cannot be reached from start x={sx} y={sy}")
        started[task.start] = number
        tasks.append(task)
    if len(tasks) < agents:
        raise _error(path, len(lines), f"asked for {agents} agents, the scenario holds {len(tasks)} tasks")
    return tasks


def _components(passable: frozenset[tuple[int, int]]) -> dict[tuple[int, int], int]:
    """Each passable cell's connected component (four directions), as a number."""
    label: dict[tuple[int, int], int] = {}
    for seed in passable:
        if seed in label:
            continue
        label[seed] = len(label)
        frontier = deque([seed])
        while frontier:
            row, col = frontier.popleft()
            for there in ((row - 1, col), (row, col + 1), (row + 1, col), (row, col - 1)):
                if there in passable and there not in label:
                    label[there] = label[seed]
                    frontier.append(there)
    return label


def map_text(gridmap: MovingAIMap, tasks: list[Task], command: str, scenario: Path | None = None) -> str:
    """Our map text for `gridmap` with an agent per task (agent k: the k-th task), headed by where it came from
    and the `command` that made it."""
    source = f"{gridmap.path.name}" + (f", the first {len(tasks)} tasks of {scenario.name}" if scenario else "")
    return grid_text(gridmap.height, gridmap.width, gridmap.passable, tasks,
                     [f"# Imported from MovingAI {source} (x the column, y the row, 0-based from the top left).",
                      f"# Made by: {command}"])


def grid_text(height: int, width: int, passable: frozenset[tuple[int, int]], tasks: list[Task],
              header: list[str]) -> str:
    """Our map text of a cell grid (`passable` cells, four-way moves between neighbours), an agent per task."""
    lines = [*header, *(f"agent {k}: start {t.start[0]},{t.start[1]}  goal {t.goal[0]},{t.goal[1]}"
                        for k, t in enumerate(tasks, start=1))]
    lines += ["", *draw_cells(height, width, passable)]
    return "\n".join(lines) + "\n"
