"""Reading the wire as the drivers do: the bounds a map sets on every message, a cell index that counts what
it refuses, and a stamp's gap named as msgs_spec names it (stale_*, future_*)."""

from __future__ import annotations

from cq_ros.gridmap import GridMap
from msgs_spec import Bounds, DropCounter, WireError, check_sequence

__all__ = ["bounds_of", "cell_of", "record_sequence"]


def bounds_of(gridmap: GridMap) -> Bounds:
    return Bounds(gridmap.n_agents, gridmap.height, gridmap.width)


def cell_of(gridmap: GridMap, drops: DropCounter, row: int, col: int, source: str) -> int | None:
    """The cell index of (row, col); a '#' square inside the grid is refused like one outside it."""
    try:
        return gridmap.index(row, col)
    except KeyError:
        drops.record(WireError("cell_out_of_range", f"({row}, {col}) is not a cell of map {gridmap.name}"),
                     source)
        return None


def record_sequence(drops: DropCounter, stamp: tuple[int, int], expected: tuple[int, int], source: str) -> None:
    """Count a message stamped `stamp` where `expected` was due, as msgs_spec names the gap (stale_*, future_*)."""
    try:
        check_sequence(*stamp, *expected)
    except WireError as e:
        drops.record(e, source)
