"""The gridworld's joint step (cq_ros.world.GridWorld.step_joint) in compiled form: walls, collisions resolved as
`resolve_moves` resolves them, absorbing goals, and the delays drawn from the world's generator in the
reference's order.

The world is a few arrays: `cells`, `done`, `hold` (each agent's start hold left) and `mt` (the world's
Mersenne Twister, cq_ros.compiled.mt). Scratch arrays of the step live in `scratch` so a step allocates nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .mt import randbelow, random


def new_scratch(n: int, n_cells: int):
    """The step's scratch: per agent targets, bumped, delayed, collided, rewards; per cell a stamp and an agent;
a clock; the pairs found; per agent where it ends."""
    return (np.zeros(n, np.int64), np.zeros(n, np.bool_), np.zeros(n, np.bool_), np.zeros(n, np.bool_),
            np.zeros(n), np.zeros(n_cells, np.int64), np.zeros(n_cells, np.int64), np.zeros(1, np.int64),
            np.zeros((n, n), np.bool_), np.zeros(n, np.int64))


@njit(cache=True)
def reset(starts, goals, cells, done, hold, mt, start_hold):
    """GridWorld.reset_joint: every agent at its start; the start holds drawn, in index order."""
    n = starts.shape[0]
    for i in range(n):
        cells[i] = starts[i]
        done[i] = starts[i] == goals[i]
    for i in range(n):
        hold[i] = randbelow(mt, start_hold + 1) if start_hold else 0


@njit(cache=True)
def _clashes(i, j, cell, goals):
    return not (goals[i] == goals[j] and goals[j] == cell)


@njit(cache=True)
def _resolve(cells, final, goals, scratch):
    """resolve_moves: `final` holds the targets and becomes where each agent ends; (colliding pairs found,
    collided flags in scratch). The common step (all ends distinct, no swap) is found in linear time."""
    n = cells.shape[0]
    collided, stamp, owner, clock, pair = scratch[3], scratch[5], scratch[6], scratch[7], scratch[8]
    clock[0] += 2
    tick = clock[0]
    easy = True
    for i in range(n):  # movers by cell they leave, to find swaps
        if cells[i] != final[i]:
            stamp[cells[i]] = tick
            owner[cells[i]] = i
    for i in range(n):
        collided[i] = False
        if cells[i] != final[i]:
            t = final[i]
            if stamp[t] == tick and final[owner[t]] == cells[i]:
                easy = False
    if easy:
        for i in range(n):
            t = final[i]
            if stamp[t] == tick + 1:
                easy = False
                break
            stamp[t] = tick + 1
    if easy:
        return 0
    # The rare step: pairwise, as the reference finds them (same end, or a swap), then agents go back round by
    # round and clash only in the cells gone back to.
    pair[:, :] = False
    found = 0
    for i in range(n):
        for j in range(i + 1, n):
            same = final[i] == final[j] and _clashes(i, j, final[i], goals)
            swap = (cells[i] != final[i] and cells[j] != final[j] and cells[i] == final[j]
                    and final[i] == cells[j])
            if same or swap:
                pair[i, j] = True
                found += 1
                collided[i] = collided[j] = True
    back = np.zeros(n, np.bool_)
    for i in range(n):
        back[i] = collided[i] and final[i] != cells[i]
    while True:
        moved = False
        for i in range(n):
            if back[i]:
                final[i] = cells[i]
                moved = True
        if not moved:
            return found
        fresh = np.zeros(n, np.bool_)
        for r in range(n):
            if not back[r]:
                continue
            c = cells[r]
            for o in range(n):
                if o != r and final[o] == c and _clashes(o, r, c, goals):
                    a, b = (o, r) if o < r else (r, o)
                    if not pair[a, b]:
                        pair[a, b] = True
                        found += 1
                    collided[a] = collided[b] = True
                    fresh[a] = fresh[b] = True
        for i in range(n):
            back[i] = fresh[i] and final[i] != cells[i]


@njit(cache=True)
def step(nbr, goals, cells, done, hold, mt, actions, slip, start_hold, rw, scratch):
    """GridWorld.step_joint for `actions` (-1: no action: at the goal); the rewards in scratch[4]; the colliding
    pairs. `rw` is (step, wall, collision, goal)."""
    n = cells.shape[0]
    targets, bumped, delayed, collided, rewards = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4]
    for i in range(n):
        delayed[i] = False
    if slip or start_hold:
        for i in range(n):
            if done[i]:
                continue
            if hold[i]:
                hold[i] -= 1
                delayed[i] = True
            elif slip:
                delayed[i] = random(mt) < slip
    for i in range(n):
        targets[i] = cells[i]
        bumped[i] = False
        if done[i] or actions[i] < 0 or delayed[i]:
            continue
        t = nbr[cells[i], actions[i]]
        targets[i] = t
        bumped[i] = t == cells[i]
    final = scratch[9]
    final[:] = targets
    collisions = _resolve(cells, final, goals, scratch)
    for i in range(n):
        rewards[i] = 0.0
        if done[i]:
            continue
        if collided[i]:
            rewards[i] = rw[2]
        elif targets[i] == cells[i] and not bumped[i]:
            rewards[i] = rw[0]
        else:
            if targets[i] == cells[i]:
                rewards[i] = rw[1]
            elif targets[i] == goals[i]:
                rewards[i] = rw[3]
            else:
                rewards[i] = rw[0]
            if targets[i] == goals[i]:
                done[i] = True
    cells[:] = final
    return collisions
