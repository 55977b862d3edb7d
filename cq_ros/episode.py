"""What the engine measures of one episode: the record, its columns' names, meanings and order.

This is the one statement of an episode's columns. The engine returns `Episode` records and tables of them
(`table`: a numpy structured array with one named float64 column per field, so a column is read by its name,
`result.episodes["collisions"]`); the result files (cq_ros.lab.results: episodes.csv and greedy.csv), the
summary, the plots and a ROS launch's statistics all take the columns from here, in this order.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, fields

import numpy as np


def _column(meaning: str, name: str | None = None):
    return field(metadata={"meaning": meaning, "column": name})


@dataclass(frozen=True)
class Episode:
    steps: int = _column("joint steps the episode took (the step cap if truncated)")
    collisions: int = _column("collisions over the episode's steps")
    joint_plays: int = _column("times a learner acted on its peers' positions, summed over the learners")
    states: int = _column("states the learners condition on at the episode's end (local plus joint), summed")
    ret: float = _column("rewards summed over the agents and steps", name="return")  # `return` is a keyword
    truncated: bool = _column("1 if the step cap ended the episode before every agent reached its goal")
    heard: int = _column("peer positions the learners' decisions took in (their communication cost), summed over "
                         "the learners")

    def values(self) -> tuple[float, ...]:
        """The fields in COLUMNS' order, as floats (the table's type)."""
        return tuple(float(getattr(self, f.name)) for f in fields(self))


COLUMNS: tuple[str, ...] = tuple(f.metadata["column"] or f.name for f in fields(Episode))
MEANINGS: dict[str, str] = {name: f.metadata["meaning"] for name, f in zip(COLUMNS, fields(Episode))}
# Result files written before `heard` was a column end at `truncated`; the readers take them too.
KEPT_COLUMNS: tuple[str, ...] = COLUMNS[:COLUMNS.index("heard")]
INTEGER = tuple(name for name, f in zip(COLUMNS, fields(Episode)) if f.type != "float")  # written as whole numbers
# float64 throughout: a JS state space past 2**53 (cells**N) goes through the same rounding in every writer, so it
# is written alike offline and by a launch, which hears it exactly.
DTYPE = np.dtype([(name, "f8") for name in COLUMNS])


def table(episodes: Iterable[Episode]) -> np.ndarray:
    """Episodes as a structured array with DTYPE's named columns, one element per episode."""
    return np.array([e.values() for e in episodes], dtype=DTYPE)
