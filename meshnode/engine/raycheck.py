"""Whether rays a neighbour sent are rays the engine can trace, in one pass over the batch.

A node checks every RAYS message before its rays join a batch (a NaN would poison every batch
it joins). In NumPy that was five passes over each message's records: a sum over the float
columns, a NaN test of t_max, a minimum of depth and a maximum of kind (7.6% of a budgeted
balls 3x3 render's time under the nodes' GIL, py-spy). Here it is one pass that stops at the
first bad ray, which the error then names.
"""

import math

from meshnode.engine.jit import leaf
from protocols.dtypes import SHADOW


@leaf
def first_untraceable(rays) -> int:
    """Index of the first of `rays` (RAY records) the engine cannot trace, -1 if none: an
    origin, direction, weight or t_min not finite, a t_max that is NaN (it may be infinite),
    depth 0, or a kind past SHADOW. Extreme finite numbers are traceable
    (tests/test_trace.py)."""
    for i in range(rays.shape[0]):
        r = rays[i]
        if r.depth < 1 or r.kind > SHADOW or math.isnan(r.t_max) or not math.isfinite(r.t_min):
            return i
        for k in range(3):
            if not (math.isfinite(r.o[k]) and math.isfinite(r.d[k]) and math.isfinite(r.w[k])):
                return i
    return -1
