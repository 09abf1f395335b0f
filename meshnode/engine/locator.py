"""Which cell holds the point where a ray goes on (`meshnode.engine.routing` regroups batches by
it).

A ray's owner is looked for first among the cells holding the point where it goes on, found
on the arrangement of the cells' faces (`Locator`): per axis the distinct face coordinates,
per box between them the cells covering it. Each axis's coordinate is searched within a
margin far above the round-off of the point and of the slab test (`_MARGIN`), so every cell
that can hold the point is looked at; the answer is the one a look at every cell gives
(`_owner`), which a point in no listed cell gets. Routing balls' passed rays, the same rays
and cells both ways (/tmp script over a simulated mesh): 3x3 75 -> 66 ns a ray, 4x4 104 -> 69
(a uniform grid over the scene listed 11.5 of 16 cells a voxel: cells cut by the objects are
narrow where objects crowd, and gained nothing).
"""

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from meshnode.engine.jit import inline, kernel
from meshnode.engine.traverse import box_span

_MARGIN = 1e-13  # of |o| + |t d| + |the scene's coordinates|: round-off is below 1e-15 of it
ARRANGEMENT_MAX = 1 << 22  # cells x boxes of the arrangement kept at most (else every cell)
LINEAR_MAX = 32  # face coordinates along an axis counted one by one, at most (`_below`)


class Locator(NamedTuple):
    """The cells' arrangement: per axis its sorted face coordinates, coords[at[a]:at[a] + n[a]];
    per box between them (x fastest) the cells covering it, members[first[v]:first[v + 1]];
    `scale` per axis: the cells' largest coordinate, for the margin."""

    coords: np.ndarray
    at: np.ndarray
    n: np.ndarray
    first: np.ndarray
    members: np.ndarray
    scale: np.ndarray


def cell_locator(los, his) -> Locator:
    """The `Locator` of cells los..his (n, 3); one for every engine routing to the same cells
    (the cost pre-pass builds hundreds of engines on one partition)."""
    los, his = (np.ascontiguousarray(a, float).reshape(-1, 3) for a in (los, his))
    return _locator(los.tobytes(), his.tobytes())


@lru_cache(maxsize=8)
def _locator(los: bytes, his: bytes) -> Locator:
    """`cell_locator` of the cells' bytes: each cell marks the boxes of the arrangement it
    covers (a mesh has at most a few hundred cells). An arrangement too large for that, or
    flat along an axis, lists nothing, and every ray looks at every cell."""
    los, his = (np.frombuffer(b, float).reshape(-1, 3) for b in (los, his))
    axes = [np.unique(np.concatenate([los[:, a], his[:, a]])) for a in range(3)]
    n = np.array([len(c) for c in axes], np.int64)
    dims = np.maximum(n - 1, 0)
    if not dims.all() or len(los) * int(np.prod(dims)) > ARRANGEMENT_MAX:
        return Locator(
            np.zeros(0),
            np.zeros(3, np.int64),
            np.zeros(3, np.int64),
            np.zeros(1, np.int64),
            np.zeros(0, np.int64),
            np.zeros(3),
        )
    # a cell flat along an axis marks the interval above its plane (below, at the top): a
    # point on the plane is looked up in both
    lo_i = [np.minimum(np.searchsorted(axes[a], los[:, a]), dims[a] - 1) for a in range(3)]
    hi_i = [np.maximum(np.searchsorted(axes[a], his[:, a]), lo_i[a] + 1) for a in range(3)]
    cover = np.zeros((len(los), dims[2], dims[1], dims[0]), bool)
    for b in range(len(los)):  # once per cell
        cover[b, lo_i[2][b] : hi_i[2][b], lo_i[1][b] : hi_i[1][b], lo_i[0][b] : hi_i[0][b]] = 1
    flat = cover.reshape(len(los), -1)
    box, cell = np.nonzero(flat.T)  # by arrangement box, then cell
    first = np.zeros(flat.shape[1] + 1, np.int64)
    np.cumsum(np.bincount(box, minlength=flat.shape[1]), out=first[1:])
    at = np.array([0, n[0], n[0] + n[1]], np.int64)
    scale = np.maximum(np.abs(los).max(axis=0), np.abs(his).max(axis=0))
    return Locator(np.concatenate(axes), at, n, first, cell.astype(np.int64), scale)


@inline
def _cell_span(ox, oy, oz, irx, iry, irz, t, t_max, los, his, b):
    """`box_span` of the ray from t on cell b of los..his (indexed, no row views made)."""
    x0, y0, z0, x1, y1, z1 = los[b, 0], los[b, 1], los[b, 2], his[b, 0], his[b, 1], his[b, 2]
    return box_span(ox, oy, oz, irx, iry, irz, t, t_max, x0, y0, z0, x1, y1, z1)


@inline
def _owner(ox, oy, oz, irx, iry, irz, t, t_max, los, his):
    """(box, t) of one ray for `owners`: the box that takes it on from t, and t, moved to
    that box's entry where the ray is in none at t."""
    best, best_exit = -1, t
    next_entry, next_box = math.inf, -1
    for b in range(los.shape[0]):
        b0, b1 = _cell_span(ox, oy, oz, irx, iry, irz, t, t_max, los, his, b)
        if b0 <= t and b1 > best_exit:
            best_exit = b1
            best = b
        elif t < b0 < b1 and b0 < next_entry:
            next_entry = b0
            next_box = b
    if best < 0 and next_box >= 0:
        return next_box, next_entry
    return best, t


@inline
def _below(coords, at, n, v, right):
    """How many of coords[at:at + n] (sorted) lie below v (with `right`, at or below): counted
    one by one with no branch up to LINEAR_MAX coordinates, where a binary search's branches,
    taken as the point falls, cost more than the compares (balls 3x3's passed rays, the
    lookup alone: 111 ns a ray on the search, 49-57 counted, /tmp script over a simulated
    mesh); searched past."""
    if n <= LINEAR_MAX:
        count = 0
        if right:
            for k in range(n):
                count += coords[at + k] <= v
        else:
            for k in range(n):
                count += coords[at + k] < v
        return count
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) >> 1
        c = coords[at + mid]
        if c < v or (right and c == v):
            lo = mid + 1
        else:
            hi = mid
    return lo


@inline
def _span_of(coords, at, n, p, m):
    """(first, last) arrangement intervals along one axis that [p - m, p + m] meets (last <
    first: none)."""
    first = max(_below(coords, at, n, p - m, False) - 1, 0)
    last = min(_below(coords, at, n, p + m, True), n - 1) - 1
    return first, last


@inline
def located_owner(
    ox, oy, oz, dx, dy, dz, irx, iry, irz, t, t_max, los, his, coords, at, n, first, members, scale
):
    """`_owner`'s answer, looking first only at the cells the arrangement `loc` lists near
    the ray's point at t (ties, as there, to the lower cell); every cell where none of those
    holds it (the cell it enters next, or none). The `Locator`'s arrays come one by one,
    unpacked once a batch. An empty arrangement spans no interval, so it needs no test of
    its own: with one (`if n[0] > 1`), numba's code for the counted lookup (`_below`) ran no
    faster than the search's (118-121 ns a ray on balls 3x3's passed rays, /tmp script)."""
    best, best_exit = -1, t
    px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
    x0, x1 = _span_of(coords, at[0], n[0], px, _MARGIN * (abs(ox) + abs(t * dx) + scale[0]))
    y0, y1 = _span_of(coords, at[1], n[1], py, _MARGIN * (abs(oy) + abs(t * dy) + scale[1]))
    z0, z1 = _span_of(coords, at[2], n[2], pz, _MARGIN * (abs(oz) + abs(t * dz) + scale[2]))
    for z in range(z0, z1 + 1):
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                v = x + (n[0] - 1) * (y + (n[1] - 1) * z)
                for k in range(first[v], first[v + 1]):
                    b = members[k]
                    b0, b1 = _cell_span(ox, oy, oz, irx, iry, irz, t, t_max, los, his, b)
                    if b0 <= t and (b1 > best_exit or (b1 == best_exit and 0 <= b < best)):
                        best_exit = b1
                        best = b
    if best >= 0:
        return best, t
    return _owner(ox, oy, oz, irx, iry, irz, t, t_max, los, his)


@kernel
def owners(rays, los, his):
    """Index of the box that takes each ray on from its t_min: it must hold the point at t_min
    and let the ray advance (exit beyond t_min); among those the one the ray crosses farthest,
    so overlapping boxes mean fewer hops. Where round-off leaves the point just outside every
    box, the ray goes to the box it enters next and its t_min moves to that entry (the sliver
    between holds no object). -1 where no box lies ahead at all."""
    n = rays.shape[0]
    out = np.full(n, -1, np.int64)
    for i in range(n):
        r = rays[i]
        irx = 1.0 / r.d[0] if r.d[0] != 0.0 else math.inf
        iry = 1.0 / r.d[1] if r.d[1] != 0.0 else math.inf
        irz = 1.0 / r.d[2] if r.d[2] != 0.0 else math.inf
        out[i], r.t_min = _owner(r.o[0], r.o[1], r.o[2], irx, iry, irz, r.t_min, r.t_max, los, his)
    return out
