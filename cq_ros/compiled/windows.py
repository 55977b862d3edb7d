"""CQ's reward windows and t-tests (cq_ros.stats) in compiled form, float operation for float operation.

The windows of every (agent, cell, action) are rows of a few arrays (`new_windows`); the samples a window holds
(W1's until it is full, then W2's ring) live in a shared pool of rows allocated at a window's first reward,
so a large map costs only the windows its agents visit. A sample is stored as its kind, a byte: its index in
`vals`, the world's four rewards (cq_ros.compiled.world's kinds: a reward is always one of them) and any other
value a learner handed over held (engine._take_over): the pool is an eighth of a table of floats, and so stays
in the cache where that one did not (2026-12-06, warehouse_16, 20 episodes, 5.9 MB of floats: compiled CQ
37.4 ns per agent-step with them, 32.2 with kinds). `fsum` is CPython's math.fsum (Shewchuk's partials and
the final correct rounding), so the exact sums, and every decision made from them, are the reference's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..stats import _ROUNDING
from .jit import kernel

# per window: columns of the int table and of the float table
N1, N2, HEAD, EXACT2, BUF = 0, 1, 2, 3, 4
SUM1, SQ1, SUM2, SQ2 = 0, 1, 2, 3


@kernel
def fsum(values, row, n, square, p):
    """math.fsum(values[row, :n]) (of their squares if `square`), for finite values; `p` holds the partials
    (n + 1 values)."""
    m = 0
    for k in range(n):
        x = values[row, k] * values[row, k] if square else values[row, k]
        i = 0
        for j in range(m):
            y = p[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            yr = hi - x
            lo = y - yr
            if lo != 0.0:
                p[i] = lo
                i += 1
            x = hi
        m = i
        if x != 0.0:
            p[m] = x
            m += 1
    hi = 0.0
    lo = 0.0
    if m > 0:
        m -= 1
        hi = p[m]
        while m > 0:
            x = hi
            m -= 1
            y = p[m]
            hi = x + y
            yr = hi - x
            lo = y - yr
            if lo != 0.0:
                break
        if m > 0 and ((lo < 0.0 and p[m - 1] < 0.0) or (lo > 0.0 and p[m - 1] > 0.0)):
            y = lo * 2.0
            x = hi + y
            yr = x - hi
            if y == yr:
                hi = x
    return hi


def new_windows(shape: tuple[int, ...], size: int, rewards):
    """The windows of `shape` (agents, cells * actions), empty; an empty sample pool of rows of `size` (kinds),
    its rows used, fsum's partials, the values of the kinds (the world's `rewards`: step, wall, collision, goal)
    and a row of `size` floats, a pool row's values."""
    ints = np.zeros((*shape, 5), np.int64)
    ints[..., EXACT2] = 1
    ints[..., BUF] = -1
    return (ints, np.zeros((*shape, 4)), np.zeros((16, size), np.uint8), np.zeros(1, np.int64), np.zeros(size + 1),
            np.array(rewards, np.float64), np.zeros((1, size)))


MAX_KINDS = 256  # the values a pool's bytes can name


def kinds_of(vals: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The kinds of `values` (floats) among `vals`, bit for bit (0.0 is not -0.0), and `vals` with the values
    new to it appended: a learner handed over from the reference may hold rewards the world here does not pay
    (a checkpoint of other settings)."""
    known = vals.view(np.uint64).tolist()
    unique, inverse = np.unique(np.asarray(values, np.float64).view(np.uint64), return_inverse=True)
    first: dict[int, int] = {}
    for i, bits in enumerate(known):
        first.setdefault(bits, i)
    new = [bits for bits in unique.tolist() if bits not in first]
    if len(known) + len(new) > MAX_KINDS:
        raise ValueError(f"the compiled engine keeps at most {MAX_KINDS} distinct rewards in its windows")
    for j, bits in enumerate(new):
        first[bits] = len(known) + j
    vals = np.concatenate([vals, np.array(new, np.uint64).view(np.float64)])
    kinds = np.array([first[bits] for bits in unique.tolist()], np.uint8)[inverse.reshape(-1)]
    return kinds, vals


@njit(cache=True)
def room(pool, used, rows):
    """The pool with `rows` rows free from `used[0]`: the same array, or one doubled as often as that needs."""
    size = pool.shape[0]
    while used[0] + rows > size:
        size *= 2
    if size == pool.shape[0]:
        return pool
    bigger = np.zeros((size, pool.shape[1]), np.uint8)
    bigger[:pool.shape[0]] = pool
    return bigger


@kernel
def _decode(pool, b, vals, row):
    """Pool row b's values into row[0]."""
    for i in range(row.shape[1]):
        row[0, i] = vals[pool[b, i]]


@njit(cache=True, inline="always")
def add(wi, wf, k, w, pool, used, part, vals, row, reward, kind):
    """RewardWindows.add to window w of agent k: store a reward (vals[kind]); True once both windows are full.
    The pool has a row free (`room`); `row` is a row of floats (new_windows)."""
    size = pool.shape[1]
    if wi[k, w, BUF] < 0:
        wi[k, w, BUF] = used[0]
        used[0] += 1
    b = wi[k, w, BUF]
    if wi[k, w, N1] < size:
        pool[b, wi[k, w, N1]] = kind
        wi[k, w, N1] += 1
        wf[k, w, SUM1] += reward
        wf[k, w, SQ1] += reward * reward
        if wi[k, w, N1] == size:
            _decode(pool, b, vals, row)
            wf[k, w, SUM1] = fsum(row, 0, size, False, part)
            wf[k, w, SQ1] = fsum(row, 0, size, True, part)
        return False
    if wi[k, w, N2] < size:
        pool[b, wi[k, w, N2]] = kind
        wi[k, w, N2] += 1
        wf[k, w, SUM2] += reward
        wf[k, w, SQ2] += reward * reward
        if wi[k, w, N2] < size:
            return False
        _resum(wi, wf, k, w, pool, part, vals, row)
        return True
    head = wi[k, w, HEAD]
    old = vals[pool[b, head]]
    pool[b, head] = kind
    wi[k, w, HEAD] += 1
    if wi[k, w, HEAD] == size:
        wi[k, w, HEAD] = 0
        _resum(wi, wf, k, w, pool, part, vals, row)
    elif reward != old:
        wf[k, w, SUM2] += reward - old
        wf[k, w, SQ2] += reward * reward - old * old
        wi[k, w, EXACT2] = 0
    return True


@njit(cache=True, inline="always")
def _resum(wi, wf, k, w, pool, part, vals, row):
    n = pool.shape[1]
    _decode(pool, wi[k, w, BUF], vals, row)
    wf[k, w, SUM2] = fsum(row, 0, n, False, part)
    wf[k, w, SQ2] = fsum(row, 0, n, True, part)
    wi[k, w, EXACT2] = 1


@njit(cache=True, inline="always")
def _spread(total, squares, n):
    ss = squares - total * total / n
    return 0.0 if ss <= _ROUNDING * squares else ss


@njit(cache=True, inline="always")
def _spread2(wi, wf, k, w, pool, part, vals, row):
    n = pool.shape[1]
    ss = _spread(wf[k, w, SUM2], wf[k, w, SQ2], n)
    if ss == 0.0 and not wi[k, w, EXACT2]:
        _resum(wi, wf, k, w, pool, part, vals, row)
        ss = _spread(wf[k, w, SUM2], wf[k, w, SQ2], n)
    return ss


@njit(cache=True, inline="always")
def _t_or_inf(a, b, se2):
    if se2 > 0.0:
        return (a - b) / math.sqrt(se2)
    if abs(a - b) <= _ROUNDING * (abs(a) + abs(b)):
        return math.nan
    return math.copysign(math.inf, a - b)


@njit(cache=True, inline="always")
def drop_t(wi, wf, k, w, pool, part, vals, row):
    n = pool.shape[1]
    ss = _spread(wf[k, w, SUM1], wf[k, w, SQ1], n) + _spread2(wi, wf, k, w, pool, part, vals, row)
    return _t_or_inf(wf[k, w, SUM2] / n, wf[k, w, SUM1] / n, ss / (n - 1) / n)


@njit(cache=True, inline="always")
def above_t(wi, wf, k, w, pool, part, vals, row, reward):
    n = pool.shape[1]
    ss = _spread2(wi, wf, k, w, pool, part, vals, row)
    return _t_or_inf(wf[k, w, SUM2] / n, reward, ss / (n - 1) / n)
