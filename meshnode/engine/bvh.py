"""A bounding volume hierarchy over one node's objects: the engine's structure where the uniform
grid is weak (many small objects crowded unevenly: tetra, teapot, scanned meshes), chosen per
node by `Engine` (DESIGN.md 4).

Binary tree split by the surface area heuristic over 16 centroid bins per axis (a leaf that
would mix kinds becomes one child per kind), built depth-first as pbrt-v4 builds its
LinearBVHNode array, then stored as one 128-byte row per inner node holding both children's
boxes (`BvhArrays`). The
engine renumbers its objects in leaf order, so a leaf is a run of local ids whose rows lie
side by side. Each object sits in exactly one leaf, so no mailbox is needed; equal distances
go to the lower gid as in the grid (`traverse.better`), so the first hit is the grid's and
brute force's whatever the order of tests.

Over the 400 lines a module may have, on purpose: the build and the walk share the node row
layout, and the walk is a hot kernel inlined with its box tests; split, the layout would be
written twice.
"""

import math
import time
from typing import NamedTuple

import numpy as np

from meshnode.engine.counters import STEPS, TESTS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.traverse import TIE, better, hinted, test_object

N_BINS = 16
MAX_LEAF = 8  # beyond this a range is split even where the heuristic calls a leaf cheaper
LEAF_BITS = 4  # a leaf reference packs its first id and its count (< 16) in one int32
LEAF_CAP = (1 << LEAF_BITS) - 1
MAX_DEPTH = 64  # below this depth ranges are only halved (at most 27 more levels)
STACK = 128  # pending children: at most one per level
TRAVERSE_COST = 0.5  # one node visit against one object test, in the heuristic
NEAR_ZERO = 1e-300  # direction components below this get a finite huge reciprocal
HUGE = 1e300
ROW_COLS = 16  # float64 columns of a row: two boxes, two references, two unused
SLACK = 1.0 + 1e-12  # box exits are widened by this: round-off never loses a hit on a face


class BvhArrays(NamedTuple):
    """The hierarchy as the traversal kernels read it (`Bvh.arrays`); None when the node uses
    the grid (a type: each structure has its own compiled variant, `variants.Variant`).

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
def _area(lo0, lo1, lo2, hi0, hi1, hi2):
    """Half the surface area of a box (the heuristic only compares ratios)."""
    x = hi0 - lo0
    y = hi1 - lo1
    z = hi2 - lo2
    return x * y + y * z + z * x


@kernel
def _bin(c, cmin, scale):
    """Bin of centroid coordinate c: clamped, and 0 for NaN, so no product of extreme
    coordinates can index outside the bins."""
    x = (c - cmin) * scale
    if not x >= 0.0:
        return 0
    if x >= N_BINS - 1:
        return N_BINS - 1
    return int(x)


@kernel
def _split(lo, hi, cen, prims, start, end, cmin, cmax):
    """Best binned SAH split of prims[start:end]: (axis, bin boundary, cost) or axis -1."""
    best_axis = -1
    best_bin = 0
    best_cost = math.inf
    cnt = np.zeros(N_BINS, np.int64)
    blo = np.empty((N_BINS, 3))
    bhi = np.empty((N_BINS, 3))
    right_area = np.empty(N_BINS)
    right_cnt = np.empty(N_BINS, np.int64)
    for a in range(3):
        ext = cmax[a] - cmin[a]
        scale = N_BINS / ext if ext > 0.0 else math.inf
        if not scale < math.inf:  # no extent (or a subnormal one): nothing to split by
            continue
        cnt[:] = 0
        blo[:] = math.inf
        bhi[:] = -math.inf
        for k in range(start, end):
            u = prims[k]
            b = _bin(cen[u, a], cmin[a], scale)
            cnt[b] += 1
            for c in range(3):
                blo[b, c] = min(blo[b, c], lo[u, c])
                bhi[b, c] = max(bhi[b, c], hi[u, c])
        # Sweep from the right: area and count of bins b .. N_BINS - 1.
        r0 = r1 = r2 = math.inf
        s0 = s1 = s2 = -math.inf
        n = 0
        for b in range(N_BINS - 1, 0, -1):
            n += cnt[b]
            r0, r1, r2 = min(r0, blo[b, 0]), min(r1, blo[b, 1]), min(r2, blo[b, 2])
            s0, s1, s2 = max(s0, bhi[b, 0]), max(s1, bhi[b, 1]), max(s2, bhi[b, 2])
            right_cnt[b] = n
            right_area[b] = _area(r0, r1, r2, s0, s1, s2) if n else 0.0
        r0 = r1 = r2 = math.inf
        s0 = s1 = s2 = -math.inf
        n = 0
        for b in range(N_BINS - 1):
            n += cnt[b]
            r0, r1, r2 = min(r0, blo[b, 0]), min(r1, blo[b, 1]), min(r2, blo[b, 2])
            s0, s1, s2 = max(s0, bhi[b, 0]), max(s1, bhi[b, 1]), max(s2, bhi[b, 2])
            if n == 0 or right_cnt[b + 1] == 0:
                continue
            cost = n * _area(r0, r1, r2, s0, s1, s2) + right_cnt[b + 1] * right_area[b + 1]
            if cost < best_cost:
                best_cost = cost
                best_axis = a
                best_bin = b
    return best_axis, best_bin, best_cost


@kernel
def _build(lo, hi, off):
    """Flattened tree over the boxes lo, hi (n, 3): (box, meta, prims), depth-first. A leaf
    that would hold several kinds (local ids `off`) becomes one child per kind, so each leaf,
    renumbered kind by kind, is a run of ids; no leaf holds more than LEAF_CAP objects."""
    n = lo.shape[0]
    cen = 0.5 * (lo + hi)
    prims = np.arange(n).astype(np.int32)
    cap = max(2 * n, 1)
    box = np.empty((cap, 6))
    meta = np.zeros((cap, 3), np.int32)
    # Pending nodes: start, end, depth, parent whose second-child index this node is (or -1).
    todo = np.empty((2 * STACK + 8, 4), np.int64)
    todo[0, 0], todo[0, 1], todo[0, 2], todo[0, 3] = 0, n, 0, -1
    top = 1
    count = 0
    cmin = np.empty(3)
    cmax = np.empty(3)
    while top > 0:
        top -= 1
        start, end, depth, parent = todo[top, 0], todo[top, 1], todo[top, 2], todo[top, 3]
        k = count
        count += 1
        if parent >= 0:
            meta[parent, 0] = k
        for c in range(3):
            box[k, c] = math.inf
            box[k, 3 + c] = -math.inf
            cmin[c] = math.inf
            cmax[c] = -math.inf
        for j in range(start, end):
            u = prims[j]
            for c in range(3):
                box[k, c] = min(box[k, c], lo[u, c])
                box[k, 3 + c] = max(box[k, 3 + c], hi[u, c])
                cmin[c] = min(cmin[c], cen[u, c])
                cmax[c] = max(cmax[c], cen[u, c])
        size = end - start
        axis = -1
        b = 0
        mid = start
        if size > 2 and depth < MAX_DEPTH:
            axis, b, cost = _split(lo, hi, cen, prims, start, end, cmin, cmax)
            area = _area(box[k, 0], box[k, 1], box[k, 2], box[k, 3], box[k, 4], box[k, 5])
            # Leaf cost: test all; split cost: one visit plus the children's expected tests.
            if axis >= 0 and size <= MAX_LEAF and area > 0.0:
                if TRAVERSE_COST + cost / area >= size:
                    axis = -1
        elif size == 2 and depth < MAX_DEPTH:
            # Two objects: split along the axis their centres differ most (if they do).
            axis = int(np.argmax(cmax - cmin))
            b = -1 if not cmax[axis] > cmin[axis] else N_BINS // 2 - 1
            if b < 0:
                axis = -1
        if axis < 0 and size <= LEAF_CAP:
            mid = _kind_split(prims, start, end, off)
            if mid == end:
                meta[k, 0], meta[k, 1], meta[k, 2] = start, size, -1
                continue
            axis = 0  # a leaf of mixed kinds: one child per kind instead
        elif axis < 0:  # too many for a leaf and nothing to split by: halves
            axis = 0
            mid = (start + end) // 2
        else:
            # Partition prims[start:end] by bin; a side left empty falls back to halves.
            scale = N_BINS / (cmax[axis] - cmin[axis])
            i = start
            j = end - 1
            while i <= j:
                if _bin(cen[prims[i], axis], cmin[axis], scale) <= b:
                    i += 1
                else:
                    prims[i], prims[j] = prims[j], prims[i]
                    j -= 1
            mid = i
            if mid == start or mid == end:
                mid = (start + end) // 2
        meta[k, 0], meta[k, 1], meta[k, 2] = -1, 0, axis
        # Second child first onto the stack: the first is built next, at index k + 1.
        todo[top, 0], todo[top, 1], todo[top, 2], todo[top, 3] = mid, end, depth + 1, k
        todo[top + 1, 0], todo[top + 1, 1], todo[top + 1, 2], todo[top + 1, 3] = (
            start,
            mid,
            depth + 1,
            -1,
        )
        top += 2
    return box[:count].copy(), meta[:count].copy(), prims


@kernel
def _kind_split(prims, start, end, off):
    """Sort the few prims[start:end] by kind (insertion sort) and return where the first
    kind ends: `end` when they are all of one kind."""
    for i in range(start + 1, end):
        u = prims[i]
        j = i
        while j > start and prims[j - 1] > u:  # local ids are grouped by kind
            prims[j] = prims[j - 1]
            j -= 1
        prims[j] = u
    first = prims[start]
    limit = end
    for c in range(1, 4):
        if off[c] > first:
            limit = off[c]
            break
    for i in range(start + 1, end):
        if prims[i] >= limit:
            return i
    return end


@kernel
def _rows(box, meta, first_id):
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


class Bvh:
    """The hierarchy of one node's objects and what the engine reports of it. `order` lists
    the local ids in leaf order: the engine renumbers its tables by it (`Tables.permuted`)
    before tracing, since the leaves refer to runs of the new ids."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, offsets: np.ndarray):
        start = time.perf_counter()
        offsets = np.asarray(offsets, np.int64)
        box, meta, prims = _build(
            np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64), offsets
        )
        # New ids: kind by kind (the tables' layout), leaf order within a kind (stable sort),
        # so a leaf, which holds one kind, is a run of consecutive new ids.
        kind = np.searchsorted(offsets, prims, side="right") - 1
        self.order = prims[np.argsort(kind, kind="stable")].astype(np.int64)
        new_id = np.empty(len(prims), np.int64)
        new_id[self.order] = np.arange(len(prims))
        self.rows = _rows(box, meta, new_id[prims] if len(prims) else np.zeros(1, np.int64))
        leaves = meta[:, 2] < 0
        counts = meta[leaves, 1]
        ext = np.maximum(box[:, 3:] - box[:, :3], 0.0)
        area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
        root = area[0] if len(area) and area[0] > 0.0 else 1.0
        self.stats = {
            # The surface area heuristic's forecast for a ray crossing the whole box: objects
            # tested and inner nodes visited (nested or long thin objects drive tests up).
            "expected_tests": float((area[leaves] * counts).sum() / root),
            "expected_visits": float(area[~leaves].sum() / root),
            "inner_nodes": int(len(self.rows)),
            "leaves": int(leaves.sum()),
            "objects_per_leaf": float(counts.mean()) if len(counts) else 0.0,
            "max_leaf": int(counts.max()) if len(counts) else 0,
            "structure_bytes": int(self.rows.nbytes),
            "build_seconds": time.perf_counter() - start,
        }

    def arrays(self) -> BvhArrays:
        """The hierarchy as the traversal kernels take it."""
        flat = self.rows.reshape(-1)  # one index per load, not a row and a column
        return BvhArrays(flat, flat.view(np.int64))


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
