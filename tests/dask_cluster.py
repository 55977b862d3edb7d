"""Test helper: a real Dask cluster, `dask scheduler` and `dask worker` processes, on 127.0.0.1 or on hosts made by
`cq-ros hosts` (a command prefix `ip netns exec ...`). Each process is a process group of its own, killed on
leaving the `with` block, even on failure; the scheduler also stops itself when idle and the workers when the
scheduler is gone, should the test process itself be killed. Every wait is for a line a process writes, bounded.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from helpers import wait_for_line, wait_until

DASK = str(Path(sys.executable).with_name("dask"))
START_S = 120.0  # for a process to be up: 3-8 s each on 2 cores shared with other sessions
REGISTERED = "Registered to:"  # a worker's log line once the scheduler has it


class DaskCluster:
    def __init__(self, folder: Path, host: str = "127.0.0.1", on: list[str] | None = None):
        self.folder, self.host, self.on = Path(folder), host, list(on or [])
        self.folder.mkdir(parents=True, exist_ok=True)
        self.processes: list[subprocess.Popen] = []
        self.address = ""

    def __enter__(self) -> DaskCluster:
        try:
            self._start_scheduler()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _spawn(self, name: str, command: list[str], env: dict | None = None) -> subprocess.Popen:
        log = open(self.folder / f"{name}.log", "w")
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                   start_new_session=True, cwd=self.folder, env={**os.environ, **(env or {})})
        log.close()
        process.log_name = name
        self.processes.append(process)
        return process

    def _start_scheduler(self) -> None:
        file = self.folder / "scheduler.json"
        process = self._spawn("scheduler", [*self.on, DASK, "scheduler", "--host", self.host, "--port", "0",
                                            "--no-dashboard", "--scheduler-file", str(file), "--idle-timeout", "600"])
        self.scheduler = process

        def address() -> str | None:  # the file appears once the scheduler listens; it may be read while written
            try:
                return json.loads(file.read_text())["address"]
            except (FileNotFoundError, ValueError, KeyError):
                return None

        self.address = wait_until(address, START_S, "no Dask scheduler", ended=lambda: process.poll() is not None,
                                  detail=lambda: self.log("scheduler")[-2000:])

    def add_worker(self, *options: str, on: list[str] | None = None, wait: bool = True) -> subprocess.Popen:
        """A worker of one thread (as docs/cluster.md says to start them), with no nanny, so that killing it is
        losing it; returned once it has registered (unless not `wait`)."""
        name = f"worker{len(self.processes)}"
        process = self._spawn(name, [*(self.on if on is None else on), DASK, "worker", self.address,
                                     "--nthreads", "1", "--no-nanny", "--no-dashboard", "--death-timeout", "60",
                                     "--local-directory", str(self.folder / name), *options])
        if wait:
            wait_for_line(self.folder / f"{name}.log", REGISTERED, START_S, process)
        return process

    def worker_address(self, worker: subprocess.Popen) -> str:
        return re.search(r"Start worker at:\s+(\S+)", self.log(worker.log_name)).group(1)

    def log(self, name: str) -> str:
        try:
            return (self.folder / f"{name}.log").read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def remove(self, worker: subprocess.Popen) -> None:
        """Kill a worker and return once the scheduler has let it go."""
        address = self.worker_address(worker)
        self.kill(worker)
        wait_for_line(self.folder / "scheduler.log", f"Remove worker addr: {address}", START_S, self.scheduler)

    def kill(self, process: subprocess.Popen) -> None:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait(timeout=30)

    def close(self) -> None:
        for process in reversed(self.processes):
            self.kill(process)
