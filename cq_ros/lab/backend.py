"""Where a grid's runs go (cq_ros.lab.runner's one loop serves them all): an executor on this process, on a local
process pool, or on a Dask cluster (cq_ros.lab.cluster), with what the loop needs to show progress and to say
where each run ran.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Backend:
    """Where the runs go: an executor, how many runs it takes at once, a reporter per run (a picklable
    `on_episode` for the worker), the episodes each run has reported so far, and where it ran (the manifest's
    `executed_on`; a run's result may name its worker)."""

    executor: Executor
    capacity: int
    reporter: Callable[[int], Callable[[], None]]
    reported: Callable[[], list[int]]
    executed_on: Callable[[list[Any]], dict]
    expected: dict | None = None  # the client's versions, checked by the worker before each run
    # Called by an in-process reporter after each episode, so progress moves while this process plays.
    heartbeat: list[Callable[[], None]] = field(default_factory=list)
