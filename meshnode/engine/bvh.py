"""A bounding volume hierarchy over one node's objects: the engine's structure where the uniform
grid is weak (many small objects crowded unevenly: tetra, teapot, scanned meshes), chosen per
node by `Engine` (DESIGN.md 4).

A binary tree split by the surface area heuristic (built by `bvhbuild`), collapsed into a
4-wide tree (each node holds up to four children's boxes, as Embree's BVH4) stored as one
128-byte node each (`BvhArrays`), and its walk. The engine renumbers its objects in leaf
order, so a leaf is a run of local ids whose rows lie side by side. Each object sits in
exactly one leaf, so no mailbox is needed; equal distances go to the lower gid as in the grid
(`traverse.better`), so the first hit is the grid's and brute force's whatever the order of
tests, and whatever the tree's shape.

4-wide against the binary rows it replaced (`python -m bench.embree --only
tetra,teapot,mount_s1 --levels 9 --structures bvh`, in turns with the binary tree): the
million-triangle tetrahedron's eye rays (walked alone) 3.00 -> 4.56 M rays/s, Embree's 0.58 ->
0.87, its shadow rays 0.56 -> 0.72 of Embree's, tetra's 0.58 -> 0.76; SPD renders (`bench.spd`)
1.13-1.19x faster, node visits a ray halved (rings 21.8 -> 10.6), the structure half the bytes.
Half the visits, each testing four boxes in one set of vector instructions (`lanes.slab4`).
"""

import math
from typing import NamedTuple

import numpy as np
from numba import uint64

from meshnode.engine.counters import STEPS, TESTS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.lanes import LANES, slab4
from meshnode.engine.leaves import prefetch_entered, triangle_leaf
from meshnode.engine.traverse import TIE, better, hinted, test_object

LEAF_GROUP = (
    3  # triangles in a leaf from which they are tested four at a time (a leaf holds one kind)
)
LEAF_BITS = 4  # a leaf reference packs its first id and its count (< 16) in one int32
LEAF_CAP = (1 << LEAF_BITS) - 1
# Pending children of a walk: at most three per level of the 4-wide tree, which has at most
# as many levels as the binary one (whose build bounds its depth below 128).
STACK = 384
NEAR_ZERO = 1e-300  # direction components below this get a finite huge reciprocal
HUGE = 1e300
NODE_COLS = 32  # float32 columns of a node: 24 box planes, 4 references, 4 unused
HI = 12  # column of a node's first upper plane (lo x, lo y, lo z, hi x, ... four lanes each)
REF_COL = 24  # first reference column, read through the int32 view
ALIGN = 128  # bytes: a node is two whole cache lines


class BvhArrays(NamedTuple):
    """The hierarchy as the traversal kernels read it (`bvhbuild.Bvh.arrays`, its nodes
    written by `nodes_of`); None when the node uses the grid (a type: each structure has its
    own compiled variant, `variants.Variant`).

    One 128-byte node (two cache lines, aligned) per node of the 4-wide tree, the nodes
    flattened into one float32 vector (a load is one index, not a row and a column): its up
    to four children's boxes as planes of four lanes, lo x[4], lo y[4], lo z[4], hi x[4],
    hi y[4], hi z[4] (columns 0-23: a vector load gets one plane of all four boxes), and,
    read through the int32 view of the same memory, their references in columns 24-27: > 0
    a node; < 0 a leaf, ~ref packing (first local id << LEAF_BITS) | count; an unused lane
    has an empty box (lo inf, hi -inf), never entered. Box planes are moved outward to the
    next float32 step beyond them, a margin that lets a ray lying in an object's bounding
    plane (a tangent, a face in a wall) still enter. Leaves are runs of consecutive local ids
    (the engine renumbers its objects in leaf order, `Tables.permuted`). A visit tests the
    four boxes at once and goes to the nearest child entered: a missed child is never
    visited. (float64 planes, 256-byte nodes, measured no faster.)"""

    box: np.ndarray  # (N * NODE_COLS,) float32 nodes: box planes, four lanes each
    ref: np.ndarray  # (N * NODE_COLS,) int32 view of `box`: columns 24-27 the references


@kernel
def nodes_of(box, meta, first_id):
    """The depth-first binary tree (box, meta) as 4-wide nodes (see `BvhArrays`): each node
    takes its binary node's two children and opens the inner child of largest surface area
    into its two until it has four (or only leaves); a leaf starting at prims position p
    refers to the run of new local ids from first_id[p]. A tree that is one leaf is a node
    of that leaf and three empty lanes. (n, NODE_COLS) float32."""
    n = box.shape[0]
    nodes = np.zeros((max(n, 1), NODE_COLS), np.float32)
    refs = nodes.view(np.int32)
    todo = np.empty((max(n, 1), 2), np.int64)  # binary node, its 4-wide node
    lane = np.empty(LANES, np.int64)
    todo[0, 0], todo[0, 1] = 0, 0
    top = 1
    count = 1
    while top > 0:
        top -= 1
        k, q = todo[top, 0], todo[top, 1]
        m = 1
        lane[0] = k
        if meta[k, 2] >= 0:
            lane[0], lane[1], m = k + 1, meta[k, 0], 2
        while m < LANES:
            m = _open_largest(box, meta, lane, m)
            if m < 0:
                m = -m
                break
        for j in range(LANES):
            if j >= m:
                for a in range(3):
                    nodes[q, 4 * a + j] = np.inf
                    nodes[q, HI + 4 * a + j] = -np.inf
                refs[q, REF_COL + j] = ~0
                continue
            c = lane[j]
            for a in range(3):
                nodes[q, 4 * a + j] = _down(box[c, a])
                nodes[q, HI + 4 * a + j] = _up(box[c, 3 + a])
            if meta[c, 2] >= 0:
                refs[q, REF_COL + j] = count
                todo[top, 0], todo[top, 1] = c, count
                top += 1
                count += 1
            else:
                refs[q, REF_COL + j] = ~((first_id[meta[c, 0]] << LEAF_BITS) | meta[c, 1])
    return nodes[:count]  # a view: the caller copies it into aligned memory (`aligned`)


@kernel
def _open_largest(box, meta, lane, m):
    """Replace the inner node of largest surface area among lane[:m] by its two children:
    m + 1; -m when all m are leaves (the node is as wide as it gets). Opening the largest
    first keeps the boxes a ray is most likely to enter one level up (Embree's rule)."""
    best = -1
    best_area = -1.0
    for j in range(m):
        c = lane[j]
        if meta[c, 2] < 0:
            continue
        x = box[c, 3] - box[c, 0]
        y = box[c, 4] - box[c, 1]
        z = box[c, 5] - box[c, 2]
        area = x * y + y * z + z * x
        if area > best_area:
            best, best_area = j, area
    if best < 0:
        return -m
    c = lane[best]
    lane[best] = c + 1
    lane[m] = meta[c, 0]
    return m + 1


def aligned(nodes: np.ndarray) -> np.ndarray:
    """A copy of `nodes` whose first byte is ALIGN-aligned: no node straddles three lines."""
    raw = np.empty(nodes.nbytes + ALIGN, np.uint8)
    start = (-raw.ctypes.data) % ALIGN
    out = raw[start : start + nodes.nbytes].view(nodes.dtype).reshape(nodes.shape)
    out[...] = nodes
    return out


def empty_nodes() -> np.ndarray:
    """One node of four empty lanes: a hierarchy of no objects (`structure.stand_in`)."""
    nodes = np.zeros((1, NODE_COLS), np.float32)
    nodes[0, :HI] = np.inf
    nodes[0, HI:REF_COL] = -np.inf
    nodes.view(np.int32)[0, REF_COL : REF_COL + LANES] = ~0
    return nodes


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
def sort4(a0, a1, a2, a3):
    """Lanes 0-3 ordered by their entry t a0..a3, nearest first (a sorting network of five
    exchanges): (t, lane) x 4."""
    i0, i1, i2, i3 = 0, 1, 2, 3
    if a1 < a0:
        a0, a1, i0, i1 = a1, a0, i1, i0
    if a3 < a2:
        a2, a3, i2, i3 = a3, a2, i3, i2
    if a2 < a0:
        a0, a2, i0, i2 = a2, a0, i2, i0
    if a3 < a1:
        a1, a3, i1, i3 = a3, a1, i3, i1
    if a2 < a1:
        a1, a2, i1, i2 = a2, a1, i2, i1
    return a0, i0, a1, i1, a2, i2, a3, i3


@inline
def _lane_of(mask):
    """The one lane set in a one-bit mask."""
    return 0 if mask == 1 else (1 if mask == 2 else (2 if mask == 4 else 3))


@inline
def _pend(stack, top, ref, bit):
    """Child ref pending on an any-hit walk's stack when bit is 1 (written either way: no
    branch); the new top. Its entry is stored as -inf: an any-hit walk ends at its first
    hit, so its bound never falls below an entered child's entry, and the entry, a read of
    the vector slab4 stored, is never needed."""
    stack[2 * top] = ref
    stack[2 * top + 1] = -math.inf
    return top + bit


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
    scratch of 2 * STACK, one per thread: the four boxes' entries in its first LANES, then
    the pending (reference, entry t) pairs. All four boxes of a node are tested at once;
    the nearest entered is visited next, the others kept on the stack nearer on top, each
    dropped when popped if a hit nearer than its entry was found meanwhile. An any-hit walk
    (a shadow ray, nine in ten of which find nothing and visit every box they enter in any
    order) goes to the lowest entered lane, unsorted (`bench.spd`: rings 0.541 -> 0.488 s,
    gears 0.622 -> 0.592, balls 0.207 -> 0.201; teapot, tetra, tree within the noise).
    A visit asks for its entered children's lines in a large tree, and a leaf of
    triangles is tested four at a time (`leaves`)."""
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
    # unsigned columns: numba adds no negative-index wraparound, and the loads stay adjacent
    nx = uint64(0) if rx >= 0.0 else uint64(HI)
    ny = uint64(0) if ry >= 0.0 else uint64(HI)
    nz = uint64(0) if rz >= 0.0 else uint64(HI)
    best_t = t_hi
    best_u = -1
    bound = t_hi
    tests = 0
    visits = 0
    top = LANES // 2  # pairs from stack[LANES]: the entries come first
    ref = 0
    while True:
        if ref >= 0:
            visits += 1
            at = uint64(ref) * uint64(NODE_COLS)
            mask = slab4(flat, at, nx, ny, nz, ox, oy, oz, rx, ry, rz, t_lo, bound, stack)
            refs_at = at + uint64(REF_COL)
            if mask != 0:  # their lines come while the nearest is walked
                prefetch_entered(
                    flat, flat_refs, at, mask, NODE_COLS, REF_COL, LEAF_BITS, tri, off[1]
                )
            if mask != 0 and mask & (mask - 1) == 0:  # one box entered: no ordering
                ref = flat_refs[refs_at + uint64(_lane_of(mask))]
                continue
            if mask != 0 and any_hit:  # any blocker ends the walk: no order, lowest lane first
                low = mask & -mask
                rest = mask ^ low
                top = _pend(stack, top, flat_refs[refs_at + uint64(3)], rest >> 3)
                top = _pend(stack, top, flat_refs[refs_at + uint64(2)], (rest >> 2) & 1)
                top = _pend(stack, top, flat_refs[refs_at + uint64(1)], (rest >> 1) & 1)
                ref = flat_refs[refs_at + uint64(_lane_of(low))]
                continue
            if mask != 0:
                a0, i0, a1, i1, a2, i2, a3, i3 = sort4(stack[0], stack[1], stack[2], stack[3])
                for a, i in ((a3, i3), (a2, i2), (a1, i1)):
                    if a < math.inf:
                        stack[2 * top] = flat_refs[refs_at + uint64(i)]
                        stack[2 * top + 1] = a
                        top += 1
                ref = flat_refs[refs_at + uint64(i0)]
                continue
        else:
            packed = ~ref
            first = packed >> LEAF_BITS
            end = first + (packed & LEAF_CAP)
            if tri is not None and off[1] <= first < off[2] and end - first >= LEAF_GROUP:
                best_t, best_u, bound, n = triangle_leaf(
                    tri,
                    off[1],
                    first,
                    end,
                    (ox, oy, oz),
                    (dx, dy, dz),
                    t_lo,
                    bound,
                    (best_t, best_u),
                    origin,
                    any_hit,
                    gid,
                    stack,
                )
                tests += n
                end = first
            for u in range(first, end):
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
        while top > LANES // 2:
            top -= 1
            if stack[2 * top + 1] < bound:
                ref = int(stack[2 * top])
                break
        if ref == 0:
            break
    counters[TESTS] += tests
    counters[STEPS] += visits
    return best_t, best_u
