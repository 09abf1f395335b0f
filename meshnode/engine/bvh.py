"""A bounding volume hierarchy over one node's objects: the engine's structure where the uniform
grid is weak (many small objects crowded unevenly: tetra, teapot, scanned meshes), chosen per
node by `Engine` (DESIGN.md 4).

A binary tree split by the surface area heuristic (built by `bvhbuild`), stored as one
128-byte row per inner node holding both children's boxes (`BvhArrays`), and its walk. The
engine renumbers its objects in leaf order, so a leaf is a run of local ids whose rows lie
side by side. Each object sits in exactly one leaf, so no mailbox is needed; equal distances
go to the lower gid as in the grid (`traverse.better`), so the first hit is the grid's and
brute force's whatever the order of tests, and whatever the tree's shape.
"""

import math
from typing import NamedTuple

import numpy as np

from meshnode.engine.counters import STEPS, TESTS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.traverse import TIE, better, hinted, test_object

LEAF_BITS = 4  # a leaf reference packs its first id and its count (< 16) in one int32
LEAF_CAP = (1 << LEAF_BITS) - 1
STACK = 128  # pending children: at most one per level (the build's depth is bounded so)
NEAR_ZERO = 1e-300  # direction components below this get a finite huge reciprocal
HUGE = 1e300
ROW_COLS = 16  # float64 columns of a row: two boxes, two references, two unused
SLACK = 1.0 + 1e-12  # box exits are widened by this: round-off never loses a hit on a face


class BvhArrays(NamedTuple):
    """The hierarchy as the traversal kernels read it (`bvhbuild.Bvh.arrays`, its rows written
    by `rows_of`); None when the node uses the grid (a type: each structure has its own
    compiled variant, `variants.Variant`).

    One 128-byte row per inner node (two cache lines), the rows flattened into one vector (a
    load is one index, not a row and a column: 9% faster walks, interleaved A/B): its two
    children's boxes in columns 0-11 and, read through the int64 view of the same memory, their
    references in columns 12 and 13: >= 0 an inner node; < 0 a leaf, ~ref packing (first local
    id << LEAF_BITS) | count. Box planes are moved outward to the next float32 step beyond them,
    a margin that lets a ray lying in an object's bounding plane (a tangent, a face in a wall)
    still enter. Leaves are runs of consecutive local ids (the engine renumbers its objects in
    leaf order, `Tables.permuted`). A visit tests both boxes and goes to the nearer child: a
    missed child is never visited. (float32 rows of one cache line measured no faster, within
    this machine's noise, and slower on the million-triangle tetrahedron.)"""

    box: np.ndarray  # (N * ROW_COLS,) float64 rows: lo xyz, hi xyz of child 0, then child 1
    ref: np.ndarray  # (N * ROW_COLS,) int64 view of `box`: columns 12, 13 of a row the refs


@kernel
def rows_of(box, meta, first_id):
    """The depth-first tree (box, meta) as 128-byte inner-node rows (see `BvhArrays`); a leaf
    starting at prims position p refers to the run of new local ids from first_id[p]. A tree
    that is one leaf gets an inner root whose second child is an empty leaf in an empty box."""
    n = box.shape[0]
    inner_id = np.full(n, -1, np.int64)
    n_inner = 0
    for k in range(n):
        if meta[k, 2] >= 0:
            inner_id[k] = n_inner
            n_inner += 1
    rows = np.zeros((max(n_inner, 1), 16), np.float64)
    refs = rows.view(np.int64)
    if n_inner == 0:
        for a in range(3):
            rows[0, a] = _down(box[0, a])
            rows[0, 3 + a] = _up(box[0, 3 + a])
            rows[0, 6 + a] = np.inf
            rows[0, 9 + a] = -np.inf
        refs[0, 12] = ~((first_id[meta[0, 0]] << LEAF_BITS) | meta[0, 1]) if n else ~0
        refs[0, 13] = ~0
        return rows
    for k in range(n):
        if meta[k, 2] < 0:
            continue
        p = inner_id[k]
        for j in range(2):
            c = k + 1 if j == 0 else meta[k, 0]
            for a in range(3):
                rows[p, 6 * j + a] = _down(box[c, a])
                rows[p, 6 * j + 3 + a] = _up(box[c, 3 + a])
            if meta[c, 2] >= 0:
                refs[p, 12 + j] = inner_id[c]
            else:
                refs[p, 12 + j] = ~((first_id[meta[c, 0]] << LEAF_BITS) | meta[c, 1])
    return rows


@kernel
def _down(x):
    """A float32 below x by at least one float32 step: a ray lying exactly on an object's
    bounding plane (a tangent, a face in a wall) still enters the box (its span stays open)."""
    y = np.nextafter(np.float32(x), np.float32(-np.inf))
    if np.float64(y) >= x:
        y = np.nextafter(y, np.float32(-np.inf))
    return y


@kernel
def _up(x):
    """A float32 above x by at least one float32 step (see `_down`)."""
    y = np.nextafter(np.float32(x), np.float32(np.inf))
    if np.float64(y) <= x:
        y = np.nextafter(y, np.float32(np.inf))
    return y


@inline
def reciprocal(d):
    """1/d, finite even for d == 0 (then huge): slab products never meet inf * 0."""
    if abs(d) < NEAR_ZERO:
        return HUGE
    return 1.0 / d


@inline
def _slabs(flat, at, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound):
    """Entry t of the box at flat[at .. at + 5] (lo xyz, hi xyz), or inf when the ray misses
    it in (t_lo, bound). nx, ny, nz pick each axis's near plane (0: lo, 3: hi, by the sign of
    the direction), so each slab is two products and no min/max; the reciprocals are finite
    (`reciprocal`), so no product is inf * 0."""
    t0 = max(
        (flat[at + nx] - ox) * rx, max((flat[at + 1 + ny] - oy) * ry, (flat[at + 2 + nz] - oz) * rz)
    )
    t1 = min(
        (flat[at + 3 - nx] - ox) * rx,
        min((flat[at + 4 - ny] - oy) * ry, (flat[at + 5 - nz] - oz) * rz),
    )
    t1 *= SLACK
    if t0 <= t1 and t1 > t_lo and t0 < bound:
        return t0
    return math.inf


@leaf
def bvh_walk(
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    t_lo,
    t_hi,
    origin,
    any_hit,
    hint,
    stack,
    counters,
    gid,
    off,
    sph,
    tri,
    poly,
    pinfo,
    puv,
    pband,
    cone,
    bvh,
):
    """First hit (or, with any_hit, any hit) in (t_lo, t_hi) through the `BvhArrays` bvh:
    (t, local id or -1). Arguments as `traverse.walk`'s; `stack` is the caller's float64
    scratch of 2 * STACK (reference, entry t) pairs, one per thread. Both children's boxes
    are tested at each inner node; the nearer is visited first, the other kept on the stack
    and dropped when popped if a hit nearer than its entry was found meanwhile."""
    t = hinted(
        hint,
        ox,
        oy,
        oz,
        dx,
        dy,
        dz,
        t_lo,
        t_hi,
        origin,
        counters,
        gid,
        off,
        sph,
        tri,
        poly,
        pinfo,
        puv,
        pband,
        cone,
    )
    if t < t_hi:
        return t, hint
    flat, flat_refs = bvh
    rx = reciprocal(dx)
    ry = reciprocal(dy)
    rz = reciprocal(dz)
    nx = 0 if rx >= 0.0 else 3
    ny = 0 if ry >= 0.0 else 3
    nz = 0 if rz >= 0.0 else 3
    best_t = t_hi
    best_u = -1
    bound = t_hi
    tests = 0
    visits = 0
    top = 0
    ref = 0
    while True:
        if ref >= 0:
            visits += 1
            at = ref * ROW_COLS
            ta = _slabs(flat, at, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound)
            tb = _slabs(flat, at + 6, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound)
            ca = flat_refs[at + 12]
            cb = flat_refs[at + 13]
            if ta < math.inf:
                if tb < math.inf:
                    if tb < ta:
                        ca, cb = cb, ca
                        ta, tb = tb, ta
                    stack[2 * top] = cb
                    stack[2 * top + 1] = tb
                    top += 1
                ref = ca
                continue
            if tb < math.inf:
                ref = cb
                continue
        else:
            packed = ~ref
            first = packed >> LEAF_BITS
            for u in range(first, first + (packed & LEAF_CAP)):
                tests += 1
                t = test_object(
                    u,
                    ox,
                    oy,
                    oz,
                    dx,
                    dy,
                    dz,
                    t_lo,
                    bound,
                    origin,
                    gid,
                    off,
                    sph,
                    tri,
                    poly,
                    pinfo,
                    puv,
                    pband,
                    cone,
                )
                if t < math.inf and better(t, u, best_t, best_u, gid):
                    best_t = t
                    best_u = u
                    bound = best_t * TIE
                    if any_hit:
                        break
            if any_hit and best_u >= 0:
                break
        # Next: the nearest pending child whose entry still comes before the bound.
        ref = 0
        while top > 0:
            top -= 1
            if stack[2 * top + 1] < bound:
                ref = int(stack[2 * top])
                break
        if ref == 0:
            break
    counters[TESTS] += tests
    counters[STEPS] += visits
    return best_t, best_u
