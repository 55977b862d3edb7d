"""Running many independent seeded runs and gathering their results, for `cq-ros experiment`, `cq-ros reproduce`
and benchmarks/bench_warehouse.py alike: in this process, on a local process pool (`--jobs N`), or on a Dask
cluster (`--cluster ADDRESS`, cq_ros.lab.cluster), through one concurrent.futures loop, one progress display and
one report of a failing run.

A run is any object with `map_name`, `algo`, `run` and `episodes`, played by `play(run, on_episode)`, which
calls `on_episode()` after each episode. Each run's result depends on its own seed only, so where and in which
order the runs finish changes nothing but the wall time.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol

from tqdm import tqdm

from .backend import Backend


class Run(Protocol):
    map_name: str
    algo: str
    run: int
    episodes: int


class RunFailed(RuntimeError):
    """A run raised: the message names its map, algorithm and run; `details` is its traceback (the worker's
    frames included, wherever it ran)."""

    def __init__(self, run: Run, error: BaseException):
        super().__init__(f"run failed: {describe(run)}: {type(error).__name__}: {error}")
        self.details = "".join(traceback.format_exception(error))


def describe(run: Run) -> str:
    return f"map {run.map_name}, algo {run.algo}, run {run.run}"


class Progress:
    """Episodes and runs done, with the rate and the time left, on stderr: a tqdm bar on a terminal;
    elsewhere (a log, CI, a pipe) a plain line at the start, then every `interval` seconds and as a run finishes
    (at most once a second), and at the end."""

    def __init__(self, label: str, episodes: int, runs: int, interval: float = 30.0):
        self.label, self.episodes, self.runs, self.interval = label, episodes, runs, interval
        self.tty = sys.stderr.isatty()
        self.bar = tqdm(total=episodes, desc=label, unit="episode", disable=not self.tty)
        self.started = self.shown_at = time.monotonic()
        self.done = self.runs_done = 0
        if not self.tty:
            self._line()

    def update(self, episodes_done: int, runs_done: int) -> None:
        if self.tty:
            self.bar.set_postfix_str(f"runs {runs_done}/{self.runs}", refresh=False)
            self.bar.update(episodes_done - self.done)
        finished, self.done, self.runs_done = runs_done > self.runs_done, episodes_done, runs_done
        since = time.monotonic() - self.shown_at
        # a run finished is news (what Ctrl-C would keep), shown at most once a second
        if not self.tty and (since >= self.interval or (finished and since >= 1.0)):
            self._line()

    def close(self) -> None:
        self.bar.close()
        if not self.tty:
            self._line()

    def _line(self) -> None:
        now = time.monotonic()
        self.shown_at, elapsed = now, now - self.started
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = f"{(self.episodes - self.done) / rate:.0f} s left" if rate > 0 else "time left unknown"
        print(f"{self.label}: runs {self.runs_done}/{self.runs}, episodes {self.done:,}/{self.episodes:,}, "
              f"{rate:,.0f} episodes/s, {elapsed:.0f} s elapsed, {left}", file=sys.stderr, flush=True)


@dataclass
class Ran:
    """What run_all gives back: each run's result (in the order given) and where they ran, for the manifest."""

    results: list[Any]
    executed_on: dict = field(default_factory=dict)


def run_all(runs: Iterable[Run], play: Callable[[Any, Callable[[], None]], Any], workers: int | None = None,
            cluster: str | None = None, label: str = "runs", progress_interval: float = 30.0,
            fresh_process: bool = False, on_result: Callable[[int, Any], None] | None = None) -> Ran:
    """Play every run: on the Dask scheduler at `cluster`, else on `workers` local processes (default one per
    core; one: in this process), or each in a fresh process if `fresh_process`. Progress on stderr (Progress);
    `on_result(i, result)` as each run ends (in the order they end), so a caller can keep what is done before the
    rest is; the first run that fails stops the rest and raises RunFailed; a worker refused or a cluster out of
    reach raises cq_ros.lab.cluster.ClusterError."""
    runs = list(runs)
    with _backend(runs, workers, cluster, label, fresh_process) as backend:
        progress = Progress(label, sum(r.episodes for r in runs), len(runs), progress_interval)
        try:
            outcomes = _gather(runs, play, backend, progress, on_result)
        finally:
            progress.close()
        return Ran([result for result, _ in outcomes], backend.executed_on([where for _, where in outcomes]))


def _gather(runs: list, play, backend: Backend, progress: Progress, on_result) -> list:
    queue = iter(enumerate(runs))
    outcomes: dict[int, Any] = {}
    pending: dict[Future, int] = {}
    ended = [0] * len(runs)  # episodes of runs finished: a run that stops early counts as played out

    last = [time.monotonic()]

    def shown() -> None:
        last[0] = time.monotonic()
        reported = backend.reported()
        progress.update(sum(max(e, r) for e, r in zip(ended, reported)), len(outcomes))

    def beat() -> None:  # the sum above is over every run: not after each episode
        if time.monotonic() - last[0] >= min(0.1, progress.interval):
            shown()

    backend.heartbeat.append(beat)
    while True:
        while len(pending) < backend.capacity and (item := next(queue, None)) is not None:
            index, run = item
            future = backend.executor.submit(_play_one, play, run, backend.reporter(index), backend.expected)
            pending[future] = index
        if not pending:
            return [outcomes[i] for i in range(len(runs))]
        done, _ = wait(pending, timeout=min(1.0, progress.interval), return_when=FIRST_COMPLETED)
        for future in done:
            index = pending.pop(future)
            outcomes[index] = _outcome(future, runs[index])
            ended[index] = runs[index].episodes
            if on_result is not None:
                on_result(index, outcomes[index][0])
        shown()


def _outcome(future: Future, run: Run):
    from .cluster import ClusterError

    try:
        return future.result()
    except ClusterError:
        raise  # a worker refused: the one line says why, no run is at fault
    except Exception as e:
        raise RunFailed(run, e) from e


def _play_one(play, run, on_episode: Callable[[], None], expected: dict | None):
    """On the worker: (the run's result, the worker's address and versions, or None off a cluster)."""
    where = None
    if expected is not None:
        from .cluster import refuse_other_versions

        where = refuse_other_versions(expected)
    return play(run, on_episode), where


@contextmanager
def _backend(runs: list, workers: int | None, cluster: str | None, label: str, fresh_process: bool):
    if cluster is not None:
        from .cluster import dask_backend

        with dask_backend(cluster, len(runs), label) as backend:
            yield backend
        return
    workers = max(1, min(workers or os.cpu_count() or 1, len(runs)))
    if workers == 1 and not fresh_process:
        yield _in_process(len(runs))
        return
    context = multiprocessing.get_context("spawn" if fresh_process else None)
    slots = context.Array("q", len(runs), lock=False)  # one writer per slot: the process playing that run
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_share_slots, initargs=(slots,),
                               max_tasks_per_child=1 if fresh_process else None)
    try:
        yield Backend(pool, len(runs), _SharedSlot, lambda: list(slots),
                      lambda _: {"where": "local processes", "workers": workers})
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


class _InProcess(Executor):
    """Runs each call at once, in this process, as it is submitted (so a failure stops the runs after it)."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future: Future = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as e:
            future.set_exception(e)
        return future


def _in_process(n: int) -> Backend:
    counts = [0] * n

    def reporter(index: int):
        def played() -> None:
            counts[index] += 1
            for beat in backend.heartbeat:
                beat()
        return played

    backend = Backend(_InProcess(), 1, reporter, lambda: counts, lambda _: {"where": "this process"})
    return backend


# In a pool's worker process: the episodes played so far by each run, in memory shared with the parent.
_slots = None


def _share_slots(slots) -> None:
    global _slots
    _slots = slots


class _SharedSlot:
    def __init__(self, index: int):
        self.index = index

    def __call__(self) -> None:
        _slots[self.index] += 1
