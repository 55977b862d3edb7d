"""CPython's Mersenne Twister (random.Random) in compiled form: the same words, the same draws.

A generator is a row of an int64 table of 625 words, Random.getstate()'s tuple (624 words, then the index), so a
learner's or the world's stream passes between Python and the kernel with getstate/setstate; the functions take
the table and the row (a row sliced out would be a view, which counts a reference at every draw). `random`,
`randbelow` and `choice` draw exactly as CPython 3.11's random(), _randbelow_with_getrandbits and choice do.
"""

from __future__ import annotations

from random import Random

import numpy as np
from numba import njit

from .jit import kernel

N, M = 624, 397
_MASK = 0xFFFFFFFF


def state_of(rng: Random) -> np.ndarray:
    return np.array(rng.getstate()[1], dtype=np.int64)


def set_state(rng: Random, words: np.ndarray) -> None:
    rng.setstate((3, tuple(int(w) for w in words), None))


@kernel
def _twist(mt, g):
    for kk in range(N):
        y = (mt[g, kk] & 0x80000000) | (mt[g, (kk + 1) % N] & 0x7FFFFFFF)
        v = mt[g, (kk + M) % N] ^ (y >> 1)
        if y & 1:
            v ^= 0x9908B0DF
        mt[g, kk] = v


@njit(cache=True, inline="always")
def _temper(y):
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y & _MASK


@njit(cache=True, inline="always")
def genrand_uint32(mt, g):
    """genrand_uint32 of _randommodule.c, generator g; mt[g, 624] is its index."""
    if mt[g, N] >= N:
        _twist(mt, g)
        mt[g, N] = 0
    y = mt[g, mt[g, N]]
    mt[g, N] += 1
    return _temper(y)


@njit(cache=True, inline="always")
def random(mt, g):
    """random(): two words; where both are left before the next twist, with one look at the index."""
    i = mt[g, N]
    if i < N - 1:
        mt[g, N] = i + 2
        a, b = _temper(mt[g, i]) >> 5, _temper(mt[g, i + 1]) >> 6
    else:
        a = genrand_uint32(mt, g) >> 5
        b = genrand_uint32(mt, g) >> 6
    return (a * 67108864.0 + b) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def randbelow(mt, g, n):
    """An int in [0, n), n in [1, 2**32): getrandbits(n.bit_length()) until below n."""
    k = 0
    m = n
    while m:
        k += 1
        m >>= 1
    r = genrand_uint32(mt, g) >> (32 - k)
    while r >= n:
        r = genrand_uint32(mt, g) >> (32 - k)
    return r
