"""The runner's Dask backend (`--cluster tcp://HOST:PORT`): the runs of a grid on a running Dask scheduler's
workers, through `Client.get_executor()`, so cq_ros.lab.runner's concurrent.futures loop serves it unchanged.

A worker whose Python, cq_ros, numpy, scipy, dask, distributed or cloudpickle differs from the client's is
refused with one line, when the grid starts and again before each run (a worker may join mid-grid): Dask's
own `Client.get_versions(check=True)` only warns on a mismatch (distributed 2026.8), and it reads installed
metadata, not the modules a worker has loaded. Episodes played reach the client as worker events (at most
two a second per run); a worker lost mid-grid has its runs re-run elsewhere by the scheduler, and as every
run is seeded, the results are the same. `distributed` is the optional extra `cluster`; nothing here imports
it before a cluster is asked for.
"""

from __future__ import annotations

import argparse
import platform
import re
import socket
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

from .backend import Backend

CONNECT_S = 30.0  # to reach the scheduler
WORKERS_S = 120.0  # for a first worker to join it
EVENT_EVERY_S = 0.5  # between two progress events of one run
CHECKED = ("python", "cq_ros", "numpy", "scipy", "dask", "distributed", "cloudpickle")
ADDRESS = re.compile(r"(tcp|tls)://(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.-]+):(\d{1,5})")


class ClusterError(RuntimeError):
    """The cluster cannot run the grid (out of reach, no worker, a worker refused); the message is one line."""


def scheduler_address(text: str) -> str:
    """`tcp://HOST:PORT` (or tls://), as Dask's scheduler prints it: an argparse type (`--cluster`)."""
    match = ADDRESS.fullmatch(text)
    if not match or not 0 < int(match.group(3)) < 65536:
        raise argparse.ArgumentTypeError(f"expected a Dask scheduler address tcp://HOST:PORT, got {text!r}")
    return text


def local_versions() -> dict:
    """This process's host and the versions that must agree, from the modules loaded (what the runs use)."""
    import cloudpickle
    import dask
    import distributed
    import numpy
    import scipy

    import cq_ros

    return {"host": socket.gethostname(), "python": platform.python_version(), "cq_ros": cq_ros.__version__,
            "numpy": numpy.__version__, "scipy": scipy.__version__, "dask": dask.__version__,
            "distributed": distributed.__version__, "cloudpickle": cloudpickle.__version__}


def _differences(theirs: dict, ours: dict) -> str:
    return "; ".join(f"{pkg} {theirs.get(pkg)} where this client has {ours[pkg]}"
                     for pkg in CHECKED if theirs.get(pkg) != ours[pkg])


def _refusal(address: str, theirs: dict, ours: dict) -> str | None:
    differ = _differences(theirs, ours)
    return differ and f"worker {address} on {theirs.get('host')} refused: {differ}"


def refuse_other_versions(expected: dict) -> dict:
    """On a worker, before a run: its address and versions; ClusterError if they are not `expected`."""
    from distributed import get_worker

    address, mine = get_worker().address, local_versions()
    if refusal := _refusal(address, mine, expected):
        raise ClusterError(refusal)
    return {"address": address, **mine}


class EpisodeEvents:
    """On a worker: `on_episode` of one run, telling the client how many episodes it has played."""

    def __init__(self, topic: str, index: int):
        self.topic, self.index, self.done, self.sent = topic, index, 0, 0.0

    def __call__(self) -> None:
        self.done += 1
        now = time.monotonic()
        if now - self.sent >= EVENT_EVERY_S:
            from distributed import get_worker

            self.sent = now
            get_worker().log_event(self.topic, [self.index, self.done])


@contextmanager
def dask_backend(address: str, runs: int, label: str) -> Iterator[Backend]:
    """A Backend on the scheduler at `address` for `runs` runs: connected, with a worker at least, every
    worker's versions checked; closed after (the scheduler and workers are left running)."""
    try:
        from distributed import Client
    except ImportError:
        raise ClusterError("--cluster needs Dask's distributed: pip install 'cq-ros[cluster]'") from None
    try:
        client = Client(address, timeout=CONNECT_S, set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise ClusterError(f"cannot reach the Dask scheduler at {address}: {e}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=WORKERS_S)
        except TimeoutError:
            raise ClusterError(f"no worker joined the Dask scheduler at {address} within {WORKERS_S:.0f} s") from None
        ours = local_versions()
        try:
            workers = client.run(local_versions)
        except Exception as e:
            raise ClusterError(f"a worker of {address} cannot run cq_ros: {type(e).__name__}: {e}") from None
        for worker, theirs in sorted(workers.items()):
            if refusal := _refusal(worker, theirs, ours):
                raise ClusterError(refusal)
        threads = {w: info["nthreads"] for w, info in client.scheduler_info()["workers"].items()}
        print(f"{label}: on the Dask cluster at {address}: {len(workers)} workers, {sum(threads.values())} "
              "threads, versions checked", file=sys.stderr, flush=True)
        if any(n > 1 for n in threads.values()):
            print(f"{label}: warning: workers with more than one thread play their runs under one GIL; start them "
                  "with `dask worker ... --nthreads 1 --nworkers N`", file=sys.stderr, flush=True)

        reported = [0] * runs
        topic = f"cq_ros-episodes-{uuid.uuid4().hex}"

        def on_event(event) -> None:  # on the client's event loop
            try:
                index, done = event[1]
                if 0 <= index < runs:
                    reported[index] = max(reported[index], int(done))
            except (TypeError, ValueError):
                pass  # not a message of ours: the topic is this grid's own, so nothing to count

        def executed_on(where: list[dict]) -> dict:
            seen = {w: {"address": w, **v} for w, v in workers.items()} | {w["address"]: w for w in where}
            return {"where": "dask", "scheduler": address,
                    "workers": [{**seen[w], "runs": sum(x["address"] == w for x in where)} for w in sorted(seen)]}

        client.subscribe_topic(topic, on_event)
        executor = client.get_executor(pure=False)
        try:
            yield Backend(executor, runs, lambda index: EpisodeEvents(topic, index), lambda: list(reported),
                          executed_on, expected=ours)
        finally:
            executor.shutdown(wait=False)  # cancels what is left after a failure
            client.unsubscribe_topic(topic)
    finally:
        client.close()
