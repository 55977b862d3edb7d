"""The gridworld's joint step (cq_ros.world.GridWorld.step_joint) in compiled form: walls, collisions resolved as
`resolve_moves` resolves them, absorbing goals, and the delays drawn from the world's generator in the
reference's order.

The world is a few arrays: `cells`, `done`, `hold` (each agent's start hold left) and `mt` (the world's
Mersenne Twister, cq_ros.compiled.mt, as a table of one generator). Arrays are indexed, never sliced into views,
in the step's loops: a view counts a reference, an atomic operation that cost more than the step itself.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit import kernel
from .mt import randbelow, random


# rows of the step's per-agent scratch (`ai`) and per-cell scratch (`ci`); KIND: which of `rw` the agent's reward
# is (an agent at its goal, none: its reward 0.0 is learnt by no one), so that a reward window can store the kind
TARGET, FINAL, NEXT, BACK, FRESH, BUMPED, DELAYED, COLLIDED, KIND = range(9)
STEP, WALL, COLLISION, GOAL = range(4)  # the kinds
STAMP, OWNER, CSTAMP, HEAD, TAIL = range(5)


def new_scratch(n: int, n_cells: int):
    """The step's scratch, so that a step allocates nothing and makes no array views (each would count a
    reference): per agent its rows `ai` (TARGET...) and the rewards; per cell its rows `ci` (STAMP...); two
    clocks; the pairs found, as a matrix and as the list that clears it."""
    return (np.zeros((9, n), np.int64), np.zeros(n), np.zeros((5, n_cells), np.int64), np.zeros(2, np.int64),
            np.zeros((n, n), np.bool_), np.zeros((2, n * (n - 1) // 2 + 1), np.int64))


@kernel
def reset(starts, goals, cells, done, hold, mt, start_hold):
    """GridWorld.reset_joint: every agent at its start; the start holds drawn, in index order."""
    n = starts.shape[0]
    for i in range(n):
        cells[i] = starts[i]
        done[i] = starts[i] == goals[i]
    for i in range(n):
        hold[i] = randbelow(mt, 0, start_hold + 1) if start_hold else 0


@njit(cache=True, inline="always")
def _chain(ai, ci, clock):
    """Each cell's agents (by where they end now) as a chain in index order: ci[HEAD, cell] where stamped,
    ai[NEXT, agent]."""
    clock[1] += 1
    epoch = clock[1]
    for i in range(ai.shape[1]):
        c = ai[FINAL, i]
        ai[NEXT, i] = -1
        if ci[CSTAMP, c] != epoch:
            ci[CSTAMP, c] = epoch
            ci[HEAD, c] = i
        else:
            ai[NEXT, ci[TAIL, c]] = i
        ci[TAIL, c] = i


@njit(cache=True, inline="always")
def _pair(a, b, ai, pair, listed, found):
    """Record the colliding pair (a, b), a < b; how many distinct pairs are found now."""
    ai[COLLIDED, a] = ai[COLLIDED, b] = 1
    if not pair[a, b]:
        pair[a, b] = True
        listed[0, found], listed[1, found] = a, b
        found += 1
    return found


@njit(cache=True, inline="always")
def _resolve(cells, goals, ai, ci, clock, pair, listed):
    """resolve_moves: ai[FINAL] holds the targets and becomes where each agent ends; the colliding pairs found
    (ai[COLLIDED] flags them). The common step (all ends distinct, no swap) is found in linear time; otherwise
    each cell's agents are chained, and after the first pass only the cells gone back to are looked at."""
    n = cells.shape[0]
    clock[0] += 2
    tick = clock[0]
    easy = True
    for i in range(n):  # movers by the cell they leave, to find swaps
        ai[COLLIDED, i] = 0
        if cells[i] != ai[FINAL, i]:
            ci[STAMP, cells[i]] = tick
            ci[OWNER, cells[i]] = i
    for i in range(n):
        t = ai[FINAL, i]
        if cells[i] != t and ci[STAMP, t] == tick and ai[FINAL, ci[OWNER, t]] == cells[i]:
            easy = False
    if easy:
        for i in range(n):
            t = ai[FINAL, i]
            if ci[STAMP, t] == tick + 1:
                easy = False
                break
            ci[STAMP, t] = tick + 1
    if easy:
        return 0
    found = 0
    _chain(ai, ci, clock)
    for i in range(n):  # same end: the pairs of each cell's chain
        j = ai[NEXT, i]
        while j >= 0:
            if not (goals[i] == goals[j] and goals[j] == ai[FINAL, i]):
                found = _pair(i, j, ai, pair, listed, found)
            j = ai[NEXT, j]
    for i in range(n):  # swaps
        t = ai[FINAL, i]
        if cells[i] != t and ci[STAMP, t] >= tick:
            k = ci[OWNER, t]
            if cells[k] == t and ai[FINAL, k] != t and ai[FINAL, k] == cells[i]:
                found = _pair(min(i, k), max(i, k), ai, pair, listed, found)
    for i in range(n):
        ai[BACK, i] = ai[COLLIDED, i] and ai[FINAL, i] != cells[i]
    while True:
        moved = False
        for i in range(n):
            ai[FRESH, i] = 0
            if ai[BACK, i]:
                ai[FINAL, i] = cells[i]
                moved = True
        if not moved:
            break
        _chain(ai, ci, clock)
        for r in range(n):
            if not ai[BACK, r]:
                continue
            c = cells[r]
            o = ci[HEAD, c] if ci[CSTAMP, c] == clock[1] else -1
            while o >= 0:
                if o != r and not (goals[o] == goals[r] and goals[r] == c):
                    a, b = (o, r) if o < r else (r, o)
                    found = _pair(a, b, ai, pair, listed, found)
                    ai[FRESH, a] = ai[FRESH, b] = 1
                o = ai[NEXT, o]
        for i in range(n):
            ai[BACK, i] = ai[FRESH, i] and ai[FINAL, i] != cells[i]
    for m in range(found):
        pair[listed[0, m], listed[1, m]] = False
    return found


@njit(cache=True, inline="always")
def step(nbr, goals, cells, done, hold, mt, actions, slip, start_hold, rw, ai, rewards, ci, clock, pair, listed):
    """GridWorld.step_joint for `actions` (-1: no action: at the goal): the rewards into `rewards` (their kinds
    into ai[KIND]); the colliding pairs. `rw` is (step, wall, collision, goal); `ai` ... `listed` the scratch
    (new_scratch)."""
    n = cells.shape[0]
    if slip or start_hold:
        for i in range(n):
            ai[DELAYED, i] = 0
            if done[i]:
                continue
            if hold[i]:
                hold[i] -= 1
                ai[DELAYED, i] = 1
            elif slip:
                ai[DELAYED, i] = random(mt, 0) < slip
    for i in range(n):
        ai[TARGET, i] = cells[i]
        ai[BUMPED, i] = 0
        if done[i] or actions[i] < 0 or ((slip or start_hold) and ai[DELAYED, i]):
            continue
        t = nbr[cells[i], actions[i]]
        ai[TARGET, i] = t
        ai[BUMPED, i] = t == cells[i]
    for i in range(n):
        ai[FINAL, i] = ai[TARGET, i]
    collisions = _resolve(cells, goals, ai, ci, clock, pair, listed)
    for i in range(n):
        rewards[i] = 0.0
        if done[i]:
            continue
        t = ai[TARGET, i]
        if ai[COLLIDED, i]:
            kind = COLLISION
        elif t == cells[i] and not ai[BUMPED, i]:
            kind = STEP
        else:
            if t == cells[i]:
                kind = WALL
            elif t == goals[i]:
                kind = GOAL
            else:
                kind = STEP
            if t == goals[i]:
                done[i] = True
        rewards[i] = rw[kind]
        ai[KIND, i] = kind
    for i in range(n):
        cells[i] = ai[FINAL, i]
    return collisions
