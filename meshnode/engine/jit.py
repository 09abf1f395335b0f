"""Decorators for every kernel: compiled once, cached on disk, GIL released.

`leaf` kernels allocate nothing, so they are compiled without numba's reference counting:
a call between jitted functions otherwise touches the count of every array argument, which
costs more than a whole ray-sphere test when made once per ray segment.
"""

import numba

kernel = numba.njit(cache=True, nogil=True, error_model="numpy")
leaf = numba.njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
