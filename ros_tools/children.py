"""A launch's node processes: each started in a session of its own, with its output as its log, and stopped
SIGINT, then SIGTERM, then SIGKILL. A terminal's Ctrl-C reaches the launcher only, which stops them in that
order, and on Linux the kernel sends them SIGTERM if the launcher dies (PR_SET_PDEATHSIG): none outlives it.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from node_runtime.report import read_reports

__all__ = ["STOP_GRACE_S", "Child", "stop_children"]

STOP_GRACE_S = ((signal.SIGINT, 3.0), (signal.SIGTERM, 2.0), (signal.SIGKILL, 5.0))

if sys.platform.startswith("linux"):
    _PR_SET_PDEATHSIG = 1
    _prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up here: the child only calls it

    def _die_with_launcher() -> None:
        """Run in the child between fork and exec: the kernel sends it SIGTERM when the launcher dies."""
        _prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
else:
    _die_with_launcher = None


@dataclass
class Child:
    """One node process: its name (also its log file's), command line, log and, once started, its process."""

    name: str
    command: list[str]
    log: Path
    process: subprocess.Popen | None = None
    env: dict[str, str] = field(default_factory=dict)  # its own, over the launch's
    restarts: int = 0  # times the launch started it again after it died (`restart_agents`)
    stuck_starts: int = 0  # times the launch started it again because it never came up (launch_watch._unstick)
    started_at: float = 0.0  # time.monotonic() of its latest start
    logged_at_start: int = 0  # its log's size then
    reported_at: float | None = None  # time.monotonic() its report was first seen in its log
    looked_at: float = 0.0  # ... when its log was last looked at for it
    hung_at_exit: bool = False  # stopped by the launch after its report: its work was done

    def start(self, env: dict[str, str]) -> None:
        # the child keeps its own copy of the descriptor; a restarted one's log goes on after its first life's
        with open(self.log, "ab" if self.restarts or self.stuck_starts else "wb") as log:
            self.logged_at_start = log.tell()
            self.process = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, stdout=log,
                                            stderr=subprocess.STDOUT, env={**env, **self.env},
                                            start_new_session=True, preexec_fn=_die_with_launcher)
        self.started_at = time.monotonic()

    def said_anything(self) -> bool:
        """Whether its log has grown since its latest start: a node's first line comes once it is made."""
        try:
            return self.log.stat().st_size > self.logged_at_start
        except OSError:
            return False

    @property
    def exit_code(self) -> int | None:
        return None if self.process is None else self.process.poll()

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.process.pid, sig)  # its own session: the group is the child and anything it started
        except ProcessLookupError:
            pass

    def describe_exit(self) -> str:
        code = self.exit_code
        how = f" (killed by {signal.Signals(-code).name})" if code is not None and code < 0 else ""
        said = self.last_error()
        return f"{self.name} (pid {self.process.pid}) exited with code {code}{how}" + (f" ({said})" if said else "")

    def reports(self) -> dict[str, dict]:
        """The reports its nodes printed at their end since its latest start (node_runtime.report; none if it was
        killed, or still runs), by node name."""
        try:
            with open(self.log, "rb") as f:
                f.seek(self.logged_at_start)
                return read_reports(f.read().decode(errors="replace"))
        except OSError:
            return {}

    def last_error(self) -> str | None:
        """The node's last ERROR line, without rclpy's prefix (a refusal says why there), if its log has one."""
        try:
            with open(self.log, "rb") as f:
                f.seek(max(0, f.seek(0, os.SEEK_END) - 8192))
                lines = f.read().decode(errors="replace").splitlines()
        except OSError:
            return None
        errors = [line for line in lines if line.startswith("[ERROR]")]
        return errors[-1].split("]: ", 1)[-1] if errors else None


def stop_children(children: list[Child]) -> None:
    """SIGINT to every child still running, then SIGTERM, then SIGKILL, each with a bounded wait; reaps them."""
    running = [c for c in children if c.running]
    for sig, grace in STOP_GRACE_S:
        if not running:
            return
        for child in running:
            child.signal_group(sig)
        deadline = time.monotonic() + grace
        while running and time.monotonic() < deadline:
            time.sleep(0.02)
            running = [c for c in running if c.running]
