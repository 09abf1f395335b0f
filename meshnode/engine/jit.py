"""One decorator for every kernel: compiled once, cached on disk, GIL released."""

import numba

kernel = numba.njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
