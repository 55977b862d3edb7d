"""Gridworld maps: read and check the text format of ``cq_ros/maps`` (``cq_ros.mapgen.warehouse`` generates maps in it).

A map becomes plain integer tables (cell index -> the cell each action leads to) so that the world, the
learners and the ROS nodes all share one numbering of states and none of them re-derives the geometry.
The format is described in ``cq_ros/maps/README.md``; in short::

    agent 1: start ROW,COL  goal ROW,COL
    set reward_step=-1         optional: a default of this map for a cq_ros.settings.Settings field
    +-+-+
    |. .|      '.' a cell of the world, '#' not part of it,
    + +-+      '|' / '-' a wall between two cells, ' ' open, '+' a corner (means nothing)
    |. #|
    +-+-+
"""

from __future__ import annotations

import os
import re
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path

from .settings import Settings, SettingsError

ACTIONS = ("NORTH", "EAST", "SOUTH", "WEST")
_STEPS = ((-1, 0), (0, 1), (1, 0), (0, -1))  # (d_row, d_col) per action index

# Goals are drawn 'G', so agents past 9 use lower case to never be mistaken for one.
_AGENT_GLYPHS = "123456789abcdefghijklmnopqrstuvwxyz"

_DRAWING_CHARS = frozenset(" .#|-+")

_AGENT_SYNTAX = "agent K: start ROW,COL  goal ROW,COL"
_SET_SYNTAX = "set KEY=VALUE"
_SET_LINE = re.compile(r"set\s+(?P<key>[^=\s]+)\s*=\s*(?P<value>\S+)\s*$")
_COORD = r"(-?\d+)\s*,\s*(-?\d+)"  # a sign is accepted so that -1 is reported as off the grid
# Matched piece by piece so that an error can point at the first piece that is wrong.
_AGENT_PIECES = (
    (r"agent\s*", "'agent'"),
    (r"(\d+)", "the agent number K"),
    (r"\s*:\s*", "':' after the agent number"),
    (r"start\s+", "'start'"),
    (_COORD, "the start position ROW,COL"),
    (r"\s+goal\s+", "'goal'"),
    (_COORD, "the goal position ROW,COL"),
    (r"\s*$", "the end of the line"),
)


class MapError(ValueError):
    """A map text that cannot be used; the message reads "SOURCE:LINE:COL: what is wrong".

    LINE and COL are 1-based positions in the text; either is left out when the fault has none.
    """


def _error(source: str, what: str, line: int | None = None, col: int | None = None) -> MapError:
    where = ":".join(str(part) for part in (source, line, col) if part is not None)
    return MapError(f"{where}: {what}")


@dataclass(frozen=True)
class GridMap:
    """A parsed map: the world's cells in row-major order, their moves, and each agent's start and goal."""

    name: str
    source: str
    height: int
    width: int
    cells: tuple[tuple[int, int], ...]
    neighbours: tuple[tuple[int, int, int, int], ...]
    starts: tuple[int, ...]
    goals: tuple[int, ...]
    # The map's own defaults for cq_ros.settings.Settings fields (its `set` lines): settings name -> value.
    defaults: Mapping[str, int | float] = field(default_factory=dict, hash=False)

    @property
    def n_agents(self) -> int:
        return len(self.starts)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    @cached_property
    def _index(self) -> dict[tuple[int, int], int]:
        return {cell: i for i, cell in enumerate(self.cells)}

    def index(self, row: int, col: int) -> int:
        """The cell index of (row, col); KeyError if that is not a cell of the world."""
        try:
            return self._index[(row, col)]
        except KeyError:
            raise KeyError(f"({row}, {col}) is not a cell of the world of map {self.name}") from None

    def distance(self, a: int, b: int) -> int:
        """Manhattan distance between two cell indices, walls ignored."""
        (row_a, col_a), (row_b, col_b) = self.cells[a], self.cells[b]
        return abs(row_a - row_b) + abs(col_a - col_b)

    def draw(self, marks: Mapping[int, str] | None = None) -> str:
        """The map as text in the file's wall style: starts as agent numbers, goals as 'G'.

        ``marks`` (cell index -> one character) is drawn over both, e.g. to show where agents are now.
        """
        glyphs = {cell: "." for cell in self.cells}
        for goal in self.goals:
            glyphs[self.cells[goal]] = "G"
        for agent, start in enumerate(self.starts):
            glyphs[self.cells[start]] = agent_glyph(agent)
        for cell, mark in (marks or {}).items():
            if len(mark) != 1:
                raise ValueError(f"mark for cell {cell} must be one character, got {mark!r}")
            glyphs[self.cells[cell]] = mark
        return "\n".join(_render(self.height, self.width, glyphs, self._is_open))

    def reachable(self, start: int, parked: frozenset[int] = frozenset()) -> set[int]:
        """The cells an agent at ``start`` can reach while agents stand still on the cells ``parked``."""
        return _reachable(self.neighbours, start, parked)

    def walled_in(self) -> list[tuple[int, int]]:
        """Pairs (i, k) of agent indices: with agent k parked at its goal, agent i cannot reach its own goal
        from its start. Agents that share a goal cell do not block each other there."""
        return [(i, k) for i in range(self.n_agents) for k in range(self.n_agents)
                if k != i and self.goals[k] != self.goals[i]
                and self.goals[i] not in self.reachable(self.starts[i], frozenset({self.goals[k]}))]

    def goal_blocked_by_parked(self) -> list[int]:
        """The agents that cannot reach their goal from their start while every other agent stands parked
        at its own goal (agents sharing that goal cell excepted)."""
        return [i for i in range(self.n_agents)
                if self.goals[i] not in self.reachable(self.starts[i], frozenset(self.goals) - {self.goals[i]})]

    def _is_open(self, row: int, col: int, action: int) -> bool:
        cell = self._index[(row, col)]
        return self.neighbours[cell][action] != cell


def agent_glyph(agent: int) -> str:
    """How the drawings show agent `agent` (0-based): 1-9, then a-z, then '*' for every agent past the 35th."""
    return _AGENT_GLYPHS[agent] if agent < len(_AGENT_GLYPHS) else "*"


def _render(
    height: int,
    width: int,
    glyphs: Mapping[tuple[int, int], str],
    is_open: Callable[[int, int, int], bool],
) -> list[str]:
    """Draw a grid whose world cells are the keys of ``glyphs``; every other cell is drawn '#'.

    Walls are drawn wherever a world cell cannot move, so the drawing is canonical: it shows the moves,
    not how the original file happened to draw the edge of '#' areas.
    """
    canvas = [[" "] * (2 * width + 1) for _ in range(2 * height + 1)]
    for line in canvas[::2]:
        line[::2] = ["+"] * (width + 1)
    for row in range(height):
        for col in range(width):
            canvas[2 * row + 1][2 * col + 1] = glyphs.get((row, col), "#")
    for row, col in glyphs:
        for action, (d_row, d_col) in enumerate(_STEPS):
            if not is_open(row, col, action):
                canvas[2 * row + 1 + d_row][2 * col + 1 + d_col] = "-" if d_row else "|"
    return ["".join(line).rstrip() for line in canvas]


def draw_cells(height: int, width: int, cells: frozenset[tuple[int, int]] | set[tuple[int, int]]) -> list[str]:
    """The drawing (lines of the map format) of a height x width grid whose world is `cells` (row, col), a
    wall wherever a cell of it meets the edge or a cell outside it (a map importer's drawing)."""

    def is_open(row: int, col: int, action: int) -> bool:
        d_row, d_col = _STEPS[action]
        return (row + d_row, col + d_col) in cells

    return _render(height, width, {cell: "." for cell in cells}, is_open)


# --- parsing ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _AgentLine:
    line: int
    number: int
    start: tuple[int, int]
    goal: tuple[int, int]
    number_col: int
    start_col: int
    goal_col: int


@dataclass(frozen=True)
class _Drawing:
    lines: tuple[str, ...]  # padded to the full width
    height: int
    width: int

    def is_world(self, row: int, col: int) -> bool:
        return self.lines[2 * row + 1][2 * col + 1] == "."

    def is_open(self, row: int, col: int, d_row: int, d_col: int) -> bool:
        return self.lines[2 * row + 1 + d_row][2 * col + 1 + d_col] == " "


def parse_map(text: str, name: str = "<text>", source: str = "<text>") -> GridMap:
    """Parse a map text; any fault raises MapError pointing at its line and column in ``source``."""
    agents, defaults, drawing_lines, first_line = _split(text, source)
    if not drawing_lines:
        raise _error(source, "no drawing (expected lines of '+', '-', '|', '.' and '#')")
    drawing = _read_drawing(drawing_lines, first_line, source)
    if not agents:
        raise _error(source, f"no agents (expected lines '{_AGENT_SYNTAX}')")
    _check_agents(agents, drawing, source)

    grid = [(row, col) for row in range(drawing.height) for col in range(drawing.width)]
    cells = tuple(cell for cell in grid if drawing.is_world(*cell))
    index = {cell: i for i, cell in enumerate(cells)}
    neighbours = tuple(_moves(drawing, index, row, col) for row, col in cells)
    starts = tuple(index[agent.start] for agent in agents)
    goals = tuple(index[agent.goal] for agent in agents)
    gridmap = GridMap(name, source, drawing.height, drawing.width, cells, neighbours, starts, goals, defaults)
    regions: list[set[int]] = []  # an edge is open both ways, so agents starting in one region share its search
    for agent, start, goal in zip(agents, starts, goals):
        region = next((r for r in regions if start in r), None)
        if region is None:
            region = gridmap.reachable(start)
            regions.append(region)
        if goal not in region:
            raise _error(
                source,
                f"agent {agent.number}'s goal {_at(agent.goal)} is unreachable from its start {_at(agent.start)}",
                agent.line,
                agent.goal_col,
            )
    return gridmap


def _split(text: str, source: str) -> tuple[list[_AgentLine], dict[str, int | float], list[str], int]:
    """Agent lines, the `set` lines' defaults, the drawing's lines and the drawing's first line number;
    comments and blank lines go."""
    agents: list[_AgentLine] = []
    defaults: dict[str, int | float] = {}
    drawing: list[str] = []
    first_line = 0
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        if line.startswith("agent"):
            agents.append(_parse_agent_line(line, number, source))
            continue
        if line.startswith("set"):
            defaults.update(_parse_set_line(line, number, source, defaults))
            continue
        if drawing and number != first_line + len(drawing):
            raise _error(source, "a second drawing starts here (a map has one drawing, without blank lines)", number, 1)
        if not drawing:
            first_line = number
        drawing.append(line)
    return agents, defaults, drawing, first_line


def _parse_agent_line(line: str, number: int, source: str) -> _AgentLine:
    values: list[int] = []
    columns: list[int] = []
    pos = 0
    for pattern, expected in _AGENT_PIECES:
        match = re.compile(pattern).match(line, pos)
        if match is None:
            raise _error(source, f"expected {expected} (agent lines read '{_AGENT_SYNTAX}')", number, pos + 1)
        values += [int(group) for group in match.groups()]
        columns += [match.start() + 1] if match.groups() else []
        pos = match.end()
    agent, start_row, start_col, goal_row, goal_col = values
    return _AgentLine(number, agent, (start_row, start_col), (goal_row, goal_col), *columns)


def _parse_set_line(line: str, number: int, source: str, earlier: Mapping[str, int | float]) -> dict:
    """A `set KEY=VALUE` line as {key: value}, checked as the settings it makes with the earlier lines."""
    match = _SET_LINE.match(line)
    if match is None:
        raise _error(source, f"expected '{_SET_SYNTAX}' (KEY a setting, `cq-ros settings` lists them)", number, 1)
    key, value = match["key"], match["value"]
    where = {"line": number, "col": match.start("key") + 1}
    if key in earlier:
        raise _error(source, f"setting {key} is set twice in this map", **where)
    if key not in Settings.__dataclass_fields__:
        raise _error(source, f"unknown setting {key!r}; `cq-ros settings` lists them", **where)
    try:
        settings = Settings().with_overrides({**earlier, key: value})
    except SettingsError as e:
        raise _error(source, str(e), number, match.start("value") + 1) from None
    return {key: getattr(settings, key)}


def _read_drawing(raw: list[str], first_line: int, source: str) -> _Drawing:
    lines = [line.rstrip() for line in raw]  # trailing spaces are open edges: they count for the length only
    last_line = first_line + len(lines) - 1
    if len(lines) % 2 == 0:
        raise _error(source, f"the drawing has an even number of lines ({len(lines)}); it needs 2*H+1", last_line)
    full = len(lines[0])
    if len(lines) < 3 or full < 3 or full % 2 == 0:
        raise _error(
            source,
            f"drawing size inconsistent: its first line is {full} characters and it has {len(lines)} line(s); "
            "a drawing is 2*W+1 characters wide (set by its first line) and 2*H+1 lines high, W and H >= 1",
            first_line,
        )
    for offset, line in enumerate(lines):
        _check_drawing_line(line, full, first_line + offset, offset, source)
    drawing = _Drawing(tuple(line.ljust(full) for line in lines), len(lines) // 2, full // 2)
    for offset, line in enumerate(raw):
        _check_not_cut_off(drawing, len(line), first_line + offset, offset, source)
    return drawing


def _check_not_cut_off(drawing: _Drawing, length: int, number: int, offset: int, source: str) -> None:
    """A line may end early only beside '#' cells and the outside: cut off next to a cell of the world, it
    would be a ragged border read as if the missing part were there."""
    for col in range(length, len(drawing.lines[0])):
        rows = {offset // 2} if offset % 2 else {offset // 2 - 1, offset // 2}
        cols = {col // 2} if col % 2 else {col // 2 - 1, col // 2}
        for row, cell_col in sorted((r, c) for r in rows for c in cols):
            if 0 <= row < drawing.height and 0 <= cell_col < drawing.width and drawing.is_world(row, cell_col):
                if offset % 2 == 0 and col % 2:
                    what = f"the wall {'below' if row < offset // 2 else 'above'} cell {row},{cell_col}"
                elif offset % 2:
                    what = f"the wall {'right' if cell_col < col // 2 else 'left'} of cell {row},{cell_col}"
                else:
                    what = f"the corner next to cell {row},{cell_col}"
                raise _error(source, f"line too short: it ends before {what} (draw the border in full)", number,
                             col + 1)


def _check_drawing_line(line: str, full: int, number: int, offset: int, source: str) -> None:
    if len(line) > full:
        what = f"line is {len(line)} characters, longer than the drawing's width {full}"
        raise _error(source, what, number, full + 1)
    for col, char in enumerate(line.ljust(full)):
        what, allowed = _position(offset, col)
        if char in allowed:
            continue
        if char not in _DRAWING_CHARS:
            raise _error(source, f"unknown character {char!r} in the drawing", number, col + 1)
        if col >= len(line):
            raise _error(source, f"line too short: it ends before {what} (expected '.' or '#')", number, col + 1)
        expected = " or ".join(repr(c) for c in allowed)
        raise _error(source, f"{char!r} cannot stand at {what} (expected {expected})", number, col + 1)


def _position(offset: int, col: int) -> tuple[str, str]:
    """What stands at a drawing position and the characters allowed there (' ' means open, or cut off)."""
    if offset % 2 and col % 2:
        return f"cell {offset // 2},{col // 2}", ".#"
    if offset % 2:
        return "a wall between left/right cells", "| "
    if col % 2:
        return "a wall between up/down cells", "- "
    return "a corner", "+ "


def _check_agents(agents: list[_AgentLine], drawing: _Drawing, source: str) -> None:
    started_by: dict[tuple[int, int], int] = {}
    for expected, agent in enumerate(agents, start=1):
        if agent.number != expected:
            raise _error(
                source,
                f"agent {agent.number} out of order: expected agent {expected} (agents are numbered 1..N in order)",
                agent.line,
                agent.number_col,
            )
        for role, place, col in (("start", agent.start, agent.start_col), ("goal", agent.goal, agent.goal_col)):
            _check_place(drawing, f"agent {agent.number}'s {role} {_at(place)}", place, source, agent.line, col)
        if agent.start in started_by:
            raise _error(
                source,
                f"agent {agent.number} starts at {_at(agent.start)}, where agent {started_by[agent.start]} starts",
                agent.line,
                agent.start_col,
            )
        started_by[agent.start] = agent.number


def _check_place(drawing: _Drawing, what: str, place: tuple[int, int], source: str, line: int, col: int) -> None:
    row, column = place
    if not (0 <= row < drawing.height and 0 <= column < drawing.width):
        raise _error(source, f"{what} is off the grid ({drawing.height} rows x {drawing.width} columns)", line, col)
    if not drawing.is_world(row, column):
        raise _error(source, f"{what} is a '#' cell, not part of the world", line, col)


def _at(place: tuple[int, int]) -> str:
    return f"{place[0]},{place[1]}"


def _moves(drawing: _Drawing, index: Mapping[tuple[int, int], int], row: int, col: int) -> tuple[int, int, int, int]:
    """The cell each action leads to from (row, col); the cell itself on a wall bump."""
    here = index[(row, col)]
    targets = []
    for d_row, d_col in _STEPS:
        there = (row + d_row, col + d_col)
        blocked = there not in index or not drawing.is_open(row, col, d_row, d_col)
        targets.append(here if blocked else index[there])
    return tuple(targets)


def _reachable(neighbours: tuple[tuple[int, ...], ...], start: int, blocked: frozenset[int]) -> set[int]:
    seen = {start}
    frontier = deque([start])
    while frontier:
        for nxt in neighbours[frontier.popleft()]:
            if nxt not in seen and nxt not in blocked:
                seen.add(nxt)
                frontier.append(nxt)
    return seen


# --- shipped maps ----------------------------------------------------------------------------------


def _maps_dir() -> Traversable:
    return resources.files("cq_ros") / "maps"


def available_maps() -> list[str]:
    """Names of the maps shipped with the package, sorted."""
    return sorted(entry.name.removesuffix(".txt") for entry in _maps_dir().iterdir() if entry.name.endswith(".txt"))


def map_text(name: str) -> str:
    """The text of a shipped map; MapError listing the available names if there is none by that name."""
    names = available_maps()
    if name not in names:
        raise _error(name, f"no such map; available: {', '.join(names)} (or give a path to a map file)")
    return (_maps_dir() / f"{name}.txt").read_text(encoding="utf-8")


def load_map(name_or_path: str | os.PathLike) -> GridMap:
    """A shipped map by name (``"tunnel_to_goal_3"``), or a map file by path (a PathLike, or a str with a
    directory separator, ending in .txt, or naming a file that is not a shipped map's name, as `cq-ros generate
    --out wh.map` writes)."""
    if isinstance(name_or_path, os.PathLike) or _looks_like_path(name_or_path):
        path = Path(name_or_path)
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise _error(str(path), f"cannot read map file: {exc.strerror or exc}") from exc
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = raw.count(b"\n", 0, exc.start) + 1
            col = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
            raise _error(str(path), f"not a UTF-8 text file (byte 0x{raw[exc.start]:02x}): a map file is UTF-8 "
                                    "text (re-save it as UTF-8; Latin-1 or a binary file is not one)",
                         line, col) from None
        return parse_map(text, name=path.stem, source=str(path))
    text = map_text(name_or_path)
    return parse_map(text, name=name_or_path, source=str(_maps_dir() / f"{name_or_path}.txt"))


def _looks_like_path(name: str) -> bool:
    return (name.endswith(".txt") or "/" in name or os.sep in name
            or (name not in available_maps() and Path(name).is_file()))


def lattice(gridmap: GridMap) -> tuple[tuple[bool, ...], ...]:
    """The map's occupancy lattice, True = occupied: (2H+1) x (2W+1) elements, cell (row, col) at
    (2 row + 1, 2 col + 1), the edge between two cells between them (free where an agent can cross it), and
    a corner free only where the four edges around it are."""
    rows, cols = 2 * gridmap.height + 1, 2 * gridmap.width + 1
    occupied = [[True] * cols for _ in range(rows)]
    for index, (row, col) in enumerate(gridmap.cells):
        occupied[2 * row + 1][2 * col + 1] = False
        moves = gridmap.neighbours[index]
        if moves[1] != index:  # EAST leads on: the edge to the right is open
            occupied[2 * row + 1][2 * col + 2] = False
        if moves[2] != index:  # SOUTH
            occupied[2 * row + 2][2 * col + 1] = False
    for i in range(2, rows - 1, 2):
        for j in range(2, cols - 1, 2):
            occupied[i][j] = any(occupied[i + di][j + dj] for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)))
    return tuple(map(tuple, occupied))
