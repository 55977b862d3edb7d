"""How the kernel's functions that are called (not inlined) compile: without numba's reference counts.

numba counts a reference, an atomic operation, each time an array is bound to a name, handed to a function or
unpacked from a tuple; in the kernel's inner loops those counts took three times the CPU of the learning itself
(perf: NRT_incref and NRT_decref). A function compiled with `_nrt=False` counts none, and so may not allocate:
`play_many` (counted, once an episode) allocates the scratch and grows the pools; everything it calls takes the
arrays it works in.
"""

from numba import njit

kernel = njit(cache=True, _nrt=False)
