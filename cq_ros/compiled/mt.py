"""CPython's Mersenne Twister (random.Random) in compiled form: the same words, the same draws.

A generator is an int64 array of 625 words, Random.getstate()'s tuple (624 words, then the index), so a
learner's or the world's stream passes between Python and the kernel with getstate/setstate. `random`,
`randbelow` and `choice` draw exactly as CPython 3.11's random(), _randbelow_with_getrandbits and choice do.
"""

from __future__ import annotations

from random import Random

import numpy as np
from numba import njit

N, M = 624, 397
_MASK = 0xFFFFFFFF


def state_of(rng: Random) -> np.ndarray:
    return np.array(rng.getstate()[1], dtype=np.int64)


def set_state(rng: Random, words: np.ndarray) -> None:
    rng.setstate((3, tuple(int(w) for w in words), None))


@njit(cache=True)
def _twist(mt):
    for kk in range(N):
        y = (mt[kk] & 0x80000000) | (mt[(kk + 1) % N] & 0x7FFFFFFF)
        v = mt[(kk + M) % N] ^ (y >> 1)
        if y & 1:
            v ^= 0x9908B0DF
        mt[kk] = v


@njit(cache=True)
def genrand_uint32(mt):
    """genrand_uint32 of _randommodule.c; mt[624] is the index."""
    if mt[N] >= N:
        _twist(mt)
        mt[N] = 0
    y = mt[mt[N]]
    mt[N] += 1
    y ^= y >> 11
    y ^= (y << 7) & 0x9D2C5680
    y ^= (y << 15) & 0xEFC60000
    y ^= y >> 18
    return y & _MASK


@njit(cache=True)
def random(mt):
    a = genrand_uint32(mt) >> 5
    b = genrand_uint32(mt) >> 6
    return (a * 67108864.0 + b) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def randbelow(mt, n):
    """An int in [0, n), n in [1, 2**32): getrandbits(n.bit_length()) until below n."""
    k = 0
    m = n
    while m:
        k += 1
        m >>= 1
    r = genrand_uint32(mt) >> (32 - k)
    while r >= n:
        r = genrand_uint32(mt) >> (32 - k)
    return r
