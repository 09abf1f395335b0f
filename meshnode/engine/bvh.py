"""A bounding volume hierarchy over one node's objects: the engine's structure where the uniform
grid is weak (many small objects crowded unevenly: tetra, teapot, scanned meshes), chosen per
node by `Engine` (DESIGN.md 4).

Binary tree split by the surface area heuristic over 16 centroid bins per axis (a leaf that
would mix kinds becomes one child per kind), built depth-first as pbrt-v4 builds its
LinearBVHNode array, then collapsed four children to a node, as Embree's BVH4 stores it, one
224-byte row per stored node with its children's boxes plane by plane (`BvhArrays`). The
engine renumbers its objects in leaf order, so a leaf is a run of local ids whose rows lie
side by side. Each object sits in exactly one leaf, so no mailbox is needed; equal distances
go to the lower gid as in the grid (`traverse.better`), so the first hit is the grid's and
brute force's whatever the order of tests.
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
LEVELS = 128  # levels of the binary tree at most (MAX_DEPTH, then at most 27 halvings)
WIDTH = 4  # children per stored node: the binary tree's nodes collapsed four at a time
HI, REF, ROW_COLS = 3 * WIDTH, 6 * WIDTH, 7 * WIDTH  # row columns: lo xyz, hi xyz, refs
STACK = (WIDTH - 1) * LEVELS + 1  # pending children in a walk: at most three per level
TRAVERSE_COST = 0.5  # one node visit against one object test, in the heuristic
NEAR_ZERO = 1e-300  # direction components below this get a finite huge reciprocal
HUGE = 1e300
SLACK = 1.0 + 1e-12  # box exits are widened by this: round-off never loses a hit on a face


class BvhArrays(NamedTuple):
    """The hierarchy as the traversal kernels read it (`Bvh.arrays`); empty when the node uses
    the grid (a value, not a type: both structures share a compiled variant).

    One 224-byte row per stored node, holding up to four children (the binary tree collapsed:
    a wide node takes its binary children, then splits its largest inner child until it has
    four). Columns by plane, child c at offset c, so one plane of all four children is four
    adjacent doubles: lo x 0-3, lo y 4-7, lo z 8-11, hi x 12-15, hi y 16-19, hi z 20-23; read
    through the int64 view of the same memory, columns 24-27 are the references: >= 0 a stored
    node; < 0 a leaf, ~ref packing (first local id << LEAF_BITS) | count. An unused slot has an
    inverted box (lo +inf, hi -inf) that no ray enters. Box planes are moved outward to the
    next float32 step beyond them, a margin that lets a ray lying in an object's bounding plane
    (a tangent, a face in a wall) still enter. Leaves are runs of consecutive local ids (the
    engine renumbers its objects in leaf order, `Tables.permuted`). A visit tests the four
    boxes and goes to the nearest child entered; a missed child is never visited. (float32
    rows measured no faster, within this machine's noise, and slower on the million-triangle
    tetrahedron.)"""

    box: np.ndarray  # (N, ROW_COLS) float64 child boxes by plane, then the references
    ref: np.ndarray  # (N, ROW_COLS) int64 view of `box`: columns REF .. REF + 3


def empty_arrays() -> BvhArrays:
    """The arrays of a node that walks its grid instead."""
    box = np.zeros((0, ROW_COLS), np.float64)
    return BvhArrays(box, box.view(np.int64))


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
    todo = np.empty((2 * LEVELS + 8, 4), np.int64)
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
            start, mid, depth + 1, -1)  # fmt: skip
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
    """The depth-first binary tree (box, meta) as wide rows (see `BvhArrays`), stored in depth
    first order; a leaf starting at prims position p refers to the run of new local ids from
    first_id[p]. A tree that is one leaf gets a root with that leaf as its only child."""
    n = box.shape[0]
    rows = np.zeros((max(n, 1), ROW_COLS), np.float64)
    refs = rows.view(np.int64)
    # Binary nodes that head a stored node, with the stored row they fill.
    todo = np.empty((WIDTH * LEVELS + 8, 2), np.int64)
    kids = np.empty(WIDTH, np.int64)
    todo[0, 0], todo[0, 1] = 0, 0
    top = 1
    n_rows = 1
    while top > 0:
        top -= 1
        k, p = todo[top, 0], todo[top, 1]
        if meta[k, 2] >= 0:
            kids[0], kids[1] = k + 1, meta[k, 0]
            m = 2
        else:  # the whole tree is one leaf
            kids[0] = k
            m = 1
        while m < WIDTH:  # open the inner child of largest area
            pick = -1
            best = -1.0
            for j in range(m):
                c = kids[j]
                if meta[c, 2] >= 0:
                    a = _area(box[c, 0], box[c, 1], box[c, 2], box[c, 3], box[c, 4], box[c, 5])
                    if a > best:
                        best = a
                        pick = j
            if pick < 0:
                break
            c = kids[pick]
            kids[pick] = c + 1
            kids[m] = meta[c, 0]
            m += 1
        for j in range(WIDTH):
            for a in range(3):
                rows[p, WIDTH * a + j] = _down(box[kids[j], a]) if j < m else np.inf
                rows[p, HI + WIDTH * a + j] = _up(box[kids[j], 3 + a]) if j < m else -np.inf
            if j >= m:
                refs[p, REF + j] = ~0
                continue
            c = kids[j]
            if meta[c, 2] >= 0:
                refs[p, REF + j] = n_rows
                todo[top, 0], todo[top, 1] = c, n_rows
                top += 1
                n_rows += 1
            else:
                refs[p, REF + j] = ~((first_id[meta[c, 0]] << LEAF_BITS) | meta[c, 1])
    if n == 0:
        refs[0, REF] = ~0
    return rows[:n_rows].copy()


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
        box, meta, prims = _build(np.ascontiguousarray(lo, np.float64),
                                  np.ascontiguousarray(hi, np.float64), offsets)  # fmt: skip
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
            "inner_nodes": int((~leaves).sum()),
            "stored_nodes": int(len(self.rows)),
            "leaves": int(leaves.sum()),
            "objects_per_leaf": float(counts.mean()) if len(counts) else 0.0,
            "max_leaf": int(counts.max()) if len(counts) else 0,
            "structure_bytes": int(self.rows.nbytes),
            "build_seconds": time.perf_counter() - start,
        }

    def arrays(self) -> BvhArrays:
        """The hierarchy as the traversal kernels take it."""
        return BvhArrays(self.rows, self.rows.view(np.int64))


@inline
def _reciprocal(d):
    """1/d, finite even for d == 0 (then huge): slab products never meet inf * 0."""
    if abs(d) < NEAR_ZERO:
        return HUGE
    return 1.0 / d


@inline
def _slabs(box, k, c, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound):
    """Entry t of child c's box in stored node k, or inf when the ray misses it in
    (t_lo, bound). nx, ny, nz are the columns of each axis's near planes (lo or hi, by the
    sign of the direction; the far ones are the others), so each slab is two products and no
    min/max; the reciprocals are finite (`_reciprocal`), so no product is inf * 0."""
    t0 = max((box[k, nx + c] - ox) * rx, max((box[k, ny + c] - oy) * ry,
                                             (box[k, nz + c] - oz) * rz))  # fmt: skip
    t1 = min((box[k, HI - nx + c] - ox) * rx,
             min((box[k, HI + 2 * WIDTH - ny + c] - oy) * ry,
                 (box[k, HI + 4 * WIDTH - nz + c] - oz) * rz))  # fmt: skip
    t1 *= SLACK
    if t0 <= t1 and t1 > t_lo and t0 < bound:
        return t0
    return math.inf


@inline
def _push(stack, top, ref, t):
    """Child `ref` entered at t onto the walk's stack, kept in decreasing t above `base`."""
    stack[2 * top] = ref
    stack[2 * top + 1] = t
    return top + 1


@inline
def _sort_top(stack, base, top):
    """Insertion sort of the entries base .. top - 1 (at most four) by decreasing entry t, so
    the nearest is popped first."""
    for a in range(base + 1, top):
        r = stack[2 * a]
        t = stack[2 * a + 1]
        b = a - 1
        while b >= base and stack[2 * b + 1] < t:
            stack[2 * b + 2] = stack[2 * b]
            stack[2 * b + 3] = stack[2 * b + 1]
            b -= 1
        stack[2 * b + 2] = r
        stack[2 * b + 3] = t


@leaf
def bvh_walk(ox, oy, oz, dx, dy, dz, t_lo, t_hi, origin, any_hit, hint, stack, counters,
             gid, off, sph, tri, poly, pinfo, puv, pband, cone, bvh):  # fmt: skip
    """First hit (or, with any_hit, any hit) in (t_lo, t_hi) through the `BvhArrays` bvh:
    (t, local id or -1). Arguments as `traverse.walk`'s; `stack` is the caller's float64
    scratch of 2 * STACK (reference, entry t) pairs, one per thread. All four children's boxes
    are tested at each stored node; those entered go onto the stack nearest on top, and one
    popped is dropped if a hit nearer than its entry was found meanwhile."""
    t = hinted(hint, ox, oy, oz, dx, dy, dz, t_lo, t_hi, origin, counters, gid, off,
               sph, tri, poly, pinfo, puv, pband, cone)  # fmt: skip
    if t < t_hi:
        return t, hint
    box, refs = bvh
    rx = _reciprocal(dx)
    ry = _reciprocal(dy)
    rz = _reciprocal(dz)
    nx = 0 if rx >= 0.0 else HI
    ny = WIDTH if ry >= 0.0 else HI + WIDTH
    nz = 2 * WIDTH if rz >= 0.0 else HI + 2 * WIDTH
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
            base = top
            for c in range(WIDTH):
                tc = _slabs(box, ref, c, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound)
                if tc < math.inf:
                    top = _push(stack, top, refs[ref, REF + c], tc)
            if top > base:
                if top > base + 1:
                    _sort_top(stack, base, top)
                top -= 1
                ref = int(stack[2 * top])
                continue
        else:
            packed = ~ref
            first = packed >> LEAF_BITS
            for u in range(first, first + (packed & LEAF_CAP)):
                tests += 1
                t = test_object(u, ox, oy, oz, dx, dy, dz, t_lo, bound, origin, gid, off,
                                sph, tri, poly, pinfo, puv, pband, cone)  # fmt: skip
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
