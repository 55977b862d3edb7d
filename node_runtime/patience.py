"""Waits judged on the time a node was awake to hear the answer, not on wall time (no ROS here).

A process that was stopped (SIGSTOP, a suspended VM, a machine starved for seconds) resumes with its timers
overdue and the messages sent meanwhile waiting in its queues; its first timer callback may run before them.
Judged on wall time, everyone it waits for looks late, and the answers already there are dropped as stale
(seen: the world timed out both agents after a 5 s stop whose actions were waiting for it). So a
`Patience` counts the time between the calls of its node's periodic timer (`expired()`, every `period`),
each gap at most `STALL_PERIODS` periods: a longer one is a stall, which does not count as waiting (one
longer than the timeout itself, which on wall time would have run the wait out alone, is counted in
`stalls`; a busy machine's shorter gaps are not, nor is the time before `start()`, a wait for peers at
start-up). And a wait that has run out is judged at the next call, not this one: the executor hands over
whatever came in between (a message is queued before that next timer event), so what was waiting in the
queues is always handled before anyone is judged late. Both only ever lengthen a wait, and by at most one
period beside the time the node was not running.
"""

from __future__ import annotations

import time
from typing import Callable

__all__ = ["STALL_PERIODS", "Patience"]

# A gap between two timer calls longer than this many periods is a stall (the process did not run): counted
# as this many periods of waiting. Callers keep period <= timeout / 10, so a stall alone never runs a wait out.
STALL_PERIODS = 5


class Patience:
    """How long a node has waited for something, in the time it was awake to hear it."""

    def __init__(self, timeout: float, period: float, clock: Callable[[], float] = time.monotonic):
        self.timeout, self.period, self._clock = timeout, period, clock
        self.stalls = 0  # timer gaps longer than the timeout: the node was stopped (or starved that long)
        self._tick = clock()  # the last timer call
        self.restart()

    def start(self) -> None:
        """The node's timer starts calling now (its first wait begins): the time before, a start-up wait for
        peers, say, is no stall."""
        self._tick = self._clock()
        self.restart()

    def restart(self) -> None:
        """The wait starts now (something was heard, or a new wait begins)."""
        self.waited = 0.0
        self._since = self._clock()
        self._due = False

    def expired(self) -> bool:
        """Call every `period` (the node's timer): True once `timeout` of awake time has passed and one more
        call has come since (so the executor has handed over what came meanwhile)."""
        now = self._clock()
        # a stall is seen even when what waited in the queues came first and restarted the wait
        if now - self._tick > self.timeout:
            self.stalls += 1
        self.waited += min(now - max(self._tick, self._since), STALL_PERIODS * self.period)
        self._tick = now
        if self.waited < self.timeout:
            self._due = False
            return False
        due, self._due = self._due, True
        return due
