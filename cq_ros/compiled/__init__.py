"""The compiled engine (numba): the reference engine's twin for the learners it covers (every one:
`algorithms.KERNEL_ALGORITHMS`), byte for byte, tens of times faster; `play` chooses the engine of a run and
says which played it.

The reference learners (cq_ros.learners) stay the statement of each algorithm, used by the ROS nodes; the kernel
is their compiled twin, kept one with them by tests/test_compiled.py. numba is imported only here, on first use:
where it cannot be, the reference engine plays, with one line on stderr saying so. Compiled code is cached on
disk (numba's cache, beside the package, or under the user's cache directory where the package is read-only);
the first compilation is shown on stderr ("compiling the engine: N s").
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

from .algorithms import KERNEL_ALGORITHMS

ENGINES = ("compiled", "reference")


def _cache_dir() -> None:
    """numba caches beside the sources; where the package is not writable, under the user's cache directory."""
    if "NUMBA_CACHE_DIR" not in os.environ and not os.access(Path(__file__).parent, os.W_OK):
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        os.environ["NUMBA_CACHE_DIR"] = str(base / "cq_ros" / "numba")


@lru_cache(maxsize=None)
def unavailable() -> str | None:
    """Why the compiled engine cannot run here (None: it can). Said once on stderr."""
    _cache_dir()
    try:
        from . import engine  # noqa: F401  (imports numba)
    except Exception as e:  # ImportError, or a numba that fails to load on this platform
        reason = f"{type(e).__name__}: {e}".splitlines()[0]
        print(f"the compiled engine cannot load ({reason}): the reference engine plays", file=sys.stderr, flush=True)
        return reason
    return None


@lru_cache(maxsize=None)
def prepare() -> bool:
    """Load (or, the first time on this machine, compile and cache) the kernel; whether it is there. Call it in
    the parent before handing runs to worker processes, so they load the cache rather than each compile."""
    if unavailable() is not None:
        return False
    from .engine import warm_up
    from .episode import play_many

    started = time.perf_counter()
    warm_up()
    if play_many.stats.cache_misses:
        print(f"compiling the engine: {time.perf_counter() - started:.0f} s (cached for the next runs)",
              file=sys.stderr, flush=True)
    return True


def engine_of(algo: str, engine: str = "compiled") -> str:
    """The engine that plays `algo` when `engine` is asked for: the reference for a learner the kernel does not
    play, or where numba cannot load."""
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; engines are: {', '.join(ENGINES)}")
    if engine == "compiled" and algo in KERNEL_ALGORITHMS and prepare():
        return "compiled"
    return "reference"


def play(algo, gridmap, settings, seed: int, run_index: int, episodes: int,
         on_episode: Callable[[], None] | None = None, engine: str = "compiled"):
    """cq_ros.engine.run on `engine` (engine_of says which plays it); the RunResult names it."""
    if engine_of(algo, engine) == "compiled":
        from .engine import run
    else:
        from ..engine import run
    return run(algo, gridmap, settings, seed, run_index, episodes, on_episode)
