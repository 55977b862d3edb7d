"""The table of the states seen with peers (near's q_near, LoC's q_coord, JS's and JSA's q_joint) in the kernel.

One table for every agent: a state's key (`tk` row: agent, then every agent's cell, a peer out of range -1,
so (s, near) of the reference is the key's cells that are not -1), its row (`tq`), and an open-addressed
hash index (`th`: slot or -1, twice the slots, a power of two); `tm[0]` the slots used. JSA's one learner
(agent 0) keys every cell and its rows hold the 4^n joint actions. Slots are made in creation order and never
dropped, so an agent's slots in order are its dict's order (team_of).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .base import _distance, _grown
from .jit import kernel
from .layout import ALGO, LEARNING, LOC, NEAR


@njit(cache=True, inline="always")
def _hash(key):
    """A key's place in the index before probing: any mix that spreads keys will do, as probing finds them."""
    h = 0x345678
    for i in range(key.shape[0]):
        h = (h ^ key[i]) * 1000003  # wraps around, as int64 does in numba
    return h ^ (h >> 29)


@kernel
def _probe(tk, th, key):
    """Where `key` sits in the index `th`: its slot's place, or the empty place (-1) where it would go."""
    mask = th.shape[0] - 1
    p = _hash(key) & mask
    while th[p] >= 0:
        slot = th[p]
        i = 0
        while i < key.shape[0] and tk[slot, i] == key[i]:
            i += 1
        if i == key.shape[0]:
            return p
        p = (p + 1) & mask
    return p


@njit(cache=True)
def index_table(tk, th, used):
    """The hash index of the table's first `used` slots, into `th`."""
    th[:] = -1
    for slot in range(used):
        th[_probe(tk, th, tk[slot])] = slot


@njit(cache=True)
def grow_table(tk, tq, th, tm, slots):
    """The table with `slots` slots free: the same arrays, or ones doubled as often as that needs."""
    size = tk.shape[0]
    while tm[0] + slots > size:
        size *= 2
    if size == tk.shape[0]:
        return tk, tq, th
    tk2, tq2 = _grown(tk, tq, size)
    th2 = np.empty(2 * size, np.int64)
    index_table(tk2, th2, tm[0])
    return tk2, tq2, th2


@kernel
def _near_key(k, s, reach, rows, cols, cells, key):
    """The state (s, near) as a key (the table's layout): the peers within `reach` of s; how many there are."""
    key[0] = k
    count = 0
    for j in range(cells.shape[0]):
        if j == k:
            key[1 + j] = s
        elif _distance(rows, cols, s, cells[j]) <= reach:
            key[1 + j] = cells[j]
            count += 1
        else:
            key[1 + j] = -1
    return count


@kernel
def _table_row(k, s, ip, q, n_js, tk, tq, th, tm, key):
    """The slot of the state `key` (agent k in cell s), made if new and learning: a copy of Q_k[s]'s first moves
    (near, LoC) or zeros (JS, JSA); -1 for a new state while frozen (a row kept nowhere, as nothing changes:
    Q_k[s] for near and LoC, zeros for JS, whose Q_k stays zeros, and JSA)."""
    p = _probe(tk, th, key)
    if th[p] >= 0 or not ip[LEARNING]:
        return th[p]
    slot = tm[0]
    tm[0] += 1
    th[p] = slot
    for i in range(key.shape[0]):
        tk[slot, i] = key[i]
    copy = ip[ALGO] == NEAR or ip[ALGO] == LOC
    for a in range(tq.shape[1]):
        tq[slot, a] = q[k, s, a] if copy else 0.0
    n_js[k] += 1
    return slot


@njit(cache=True, inline="always")
def _q_at(k, ref, cell, a, q, tq):
    """Q_k[cell][a] (ref -1) or the table's row `ref`'s a."""
    return q[k, cell, a] if ref < 0 else tq[ref, a]


@njit(cache=True, inline="always")
def _q_update(k, ref, cell, a, target, alpha, q, tq):
    """base.q_update of Q_k[cell] (ref -1) or of the table's row `ref`."""
    if ref < 0:
        q[k, cell, a] += alpha * (target - q[k, cell, a])
    else:
        tq[ref, a] += alpha * (target - tq[ref, a])
