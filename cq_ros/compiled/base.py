"""What the kernel's learners share (cq_ros.learners.base's twin): the greedy and epsilon-greedy choices, the
max of a row, the distance, epsilon's schedule, the pools' growth, and IndependentQ's learning.

Each function of the kernel is the twin of a reference method (named in its docstring) and does its float
operations in the same order, so that a compiled run is the reference's byte for byte (tests/test_compiled.py
holds them one).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit import kernel
from .layout import A, ALPHA, DECAY, EPS0, GAMMA, LEARNING, PLAYED, S
from .mt import randbelow, random


@njit(cache=True, inline="always")
def _max(row):
    """Python's max(row): the first of the largest."""
    best = row[0]
    for k in range(1, row.shape[0]):
        if row[k] > best:
            best = row[k]
    return best


@njit(cache=True, inline="always")
def _qmax(q, k, s):
    """max(Q_k[s]), as _max."""
    best = q[k, s, 0]
    for a in range(1, q.shape[2]):
        if q[k, s, a] > best:
            best = q[k, s, a]
    return best


@njit(cache=True, inline="always")
def greedy(row, mt, g):
    """base.greedy: the largest value's index, ties broken by rng.choice (generator g)."""
    best = _max(row)
    count = 0
    first = -1
    for a in range(row.shape[0]):
        if row[a] == best:
            count += 1
            if first < 0:
                first = a
    if count == 1:
        return first
    pick = randbelow(mt, g, count)
    for a in range(row.shape[0]):
        if row[a] == best:
            if pick == 0:
                return a
            pick -= 1
    return -1


@njit(cache=True, inline="always")
def epsilon_greedy(row, epsilon, mt, g):
    if random(mt, g) < epsilon:
        return int(random(mt, g) * row.shape[0])
    return greedy(row, mt, g)


@kernel
def choose(row, epsilon, mt, g):
    """epsilon_greedy, called: near, LoC, JS, JSA and CQ's act where it waits or looks (_act_cq) share one
    compilation of it (each inlining costs seconds of the first compilation)."""
    return epsilon_greedy(row, epsilon, mt, g)


@njit(cache=True, inline="always")
def _distance(rows, cols, a, b):
    return abs(rows[a] - rows[b]) + abs(cols[a] - cols[b])


@njit(cache=True, inline="always")
def end_episode(k, fp, ip, ag, eps):
    """Learner.end_episode: one more episode played; epsilon on its schedule."""
    ag[k, PLAYED] += 1
    decay = ip[DECAY]
    if decay:
        fall = 1.0 - ag[k, PLAYED] / decay
        scaled = fp[EPS0] * (fall if fall > 0.0 else 0.0)
        if scaled < eps[k]:
            eps[k] = scaled


@njit(cache=True, inline="always")
def learn_indep(k, reward, next_cell, done, fp, ip, ag, q):
    """IndependentQ.learn."""
    if not ip[LEARNING]:
        return
    target = reward if done else reward + fp[GAMMA] * _qmax(q, k, next_cell)
    s, a = ag[k, S], ag[k, A]
    q[k, s, a] += fp[ALPHA] * (target - q[k, s, a])


@njit(cache=True)
def _grown(ints, floats, size):
    """A pool's (or the table's) int and float rows copied into `size` rows, the new ones -1 and 0."""
    ints2 = np.full((size, ints.shape[1]), -1, np.int64)
    ints2[:ints.shape[0]] = ints
    floats2 = np.zeros((size, floats.shape[1]))
    floats2[:floats.shape[0]] = floats
    return ints2, floats2
