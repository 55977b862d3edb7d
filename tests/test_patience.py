"""node_runtime.patience: a wait counts the time between the node's own timer calls, a stall at most
STALL_PERIODS periods (counted when longer than the timeout), and a wait run out is judged one call later."""

from __future__ import annotations

from node_runtime.patience import STALL_PERIODS, Patience


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def calls(patience, clock, n, period):
    """n timer calls, `period` apart: how many said the wait had run out."""
    fired = 0
    for _ in range(n):
        clock.now += period
        fired += patience.expired()
    return fired


def test_a_wait_runs_out_after_its_timeout_and_one_more_call():
    clock = Clock()
    p = Patience(1.05, 0.1, clock)
    assert calls(p, clock, 11, 0.1) == 0  # 1.1 s waited: run out, judged at the next call
    assert calls(p, clock, 1, 0.1) == 1 and p.stalls == 0


def test_a_stall_counts_at_most_stall_periods_and_is_counted():
    clock = Clock()
    p = Patience(2.0, 0.1, clock)
    calls(p, clock, 3, 0.1)
    clock.now += 1.9  # starved for less than the timeout: not counted as a stall
    assert not p.expired() and p.stalls == 0
    clock.now += 60.0  # stopped for a minute
    assert not p.expired() and p.stalls == 1
    assert abs(p.waited - (0.3 + 2 * STALL_PERIODS * 0.1)) < 1e-9
    assert calls(p, clock, 1, 0.1) == 0  # what waited in the queues is handled before the wait runs out


def test_restart_starts_the_wait_again():
    clock = Clock()
    p = Patience(1.05, 0.1, clock)
    calls(p, clock, 9, 0.1)
    p.restart()
    assert calls(p, clock, 11, 0.1) == 0
    assert calls(p, clock, 1, 0.1) == 1


def test_a_stall_is_counted_when_what_waited_came_first():
    clock = Clock()
    p = Patience(1.0, 0.1, clock)
    calls(p, clock, 3, 0.1)
    clock.now += 5.0
    p.restart()  # the executor handed over the message waiting in the queue before the timer call
    clock.now += 0.01
    assert not p.expired() and p.stalls == 1 and abs(p.waited - 0.01) < 1e-9
