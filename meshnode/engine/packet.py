"""Rays walked through the hierarchy (`bvh`) in packets of PACKET neighbours: each visit tests a
node's four children's boxes for every ray of the packet, each box in a few vector instructions
(`rows`), and a leaf's triangles likewise; the packet goes where any of its rays enters. Each
ray gets exactly the hit a walk of its own finds (`bvh.bvh_walk`: the same box and object
arithmetic, ties to the lower gid whatever the order of tests), in less time while neighbouring
rays take the same path: one node's eye and camera rays (Wald et al., "Interactive Rendering
with Coherent Ray Tracing", 2001). A batch stops using packets when they stop paying
(`keep_packets`).
"""

import math

import numpy as np

from meshnode.engine.bvh import (
    LEAF_BITS,
    LEAF_CAP,
    NODE_COLS,
    REF_COL,
    sort4,
)
from meshnode.engine.bvh import STACK as BVH_STACK
from meshnode.engine.counters import PACKET_IDLE, STEPS, TESTS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.leaves import PREFETCH_FROM, prefetch_entered
from meshnode.engine.rows import (
    PACKET,
    copy_row,
    count_below,
    packet_slabs,
    packet_triangle,
    reciprocals,
)
from meshnode.engine.traverse import TIE, better, test_object

# Packets pay while neighbouring rays take the same path: a batch walks its first PROBE
# packets, then goes on in packets only if at least COHERENT of the rays tested at each node
# had entered it (tetra: 0.84, teapot 0.90), COHERENT_FAR in a hierarchy too large for the
# cache (`leaves.PREFETCH_FROM`), where one node load serves eight rays: the
# million-triangle tetrahedron (0.55) was 1.2x slower in packets of scalar loops and no
# faster in vector ones (`rows`), but once a visit asks for its entered children's lines
# (`leaves.prefetch_entered`) its packets were 1.06x faster than its rays alone (189.5
# against 201.0 ns a ray).
PROBE = 32
COHERENT = 0.65
COHERENT_FAR = 0.5
# Rows of a packet's float64 scratch (`packet_walk`): the rays, then what the walk keeps.
# P_E .. P_E + 3: each ray's entry into each of a node's four boxes.
P_O, P_D, P_R, P_LO, P_BOUND, P_BEST, P_A, P_CUR, P_E, P_ROWS = 0, 3, 6, 9, 10, 11, 12, 13, 14, 18


@inline
def _entry(flat, at, f, lane):
    """Lane `lane`'s box (planes from flat[at]) against the packet: each ray's entry into
    f[P_E + lane], and the nearest of them (inf when no ray enters): the key the packet
    orders a node's children by."""
    return packet_slabs(flat, at, f, P_E + lane, P_O, P_R, P_LO, P_BOUND)


@inline
def _pad(f, origin, n):
    """Columns n.. of a packet of n < PACKET rays as rays that enter nothing (span (0, -inf),
    the first ray's finite origin and direction): the vector row operations (`rows`) work on
    all PACKET columns."""
    for k in range(n, PACKET):
        for r in range(P_LO):
            f[r, k] = f[r, 0]
        f[P_LO, k], f[P_BOUND, k] = 0.0, -math.inf
        origin[k] = -1


@inline
def load_ray(f, origin, k, ox, oy, oz, dx, dy, dz, t_lo, t_hi, org):
    """Ray k of a packet's scratch (`packet_walk`): origin, direction, span, and the gid of
    the surface it leaves."""
    f[P_O, k], f[P_O + 1, k], f[P_O + 2, k] = ox, oy, oz
    f[P_D, k], f[P_D + 1, k], f[P_D + 2, k] = dx, dy, dz
    f[P_LO, k], f[P_BOUND, k] = t_lo, t_hi
    origin[k] = org


@kernel
def packet_scratch():
    """A packet's scratch: float rows, origins, hits, pending children and their refs, and
    which ray of the batch each column holds."""
    return (
        np.empty((P_ROWS, PACKET)),
        np.empty(PACKET, np.int64),
        np.empty(PACKET, np.int64),
        np.empty((BVH_STACK, PACKET)),
        np.empty(BVH_STACK, np.int64),
        np.empty(PACKET, np.int64),
    )


@leaf
def packet_walk(
    f,
    origin,
    best_u,
    n,
    pstack,
    refs,
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
    any_hit=False,
):
    """First hits of n <= PACKET rays walked through the tree together: each visit tests the four
    children's boxes for every ray, a few vector instructions a box (`rows.packet_slabs`),
    and the packet goes where any ray enters, nearest child first (by its nearest ray's
    entry); a leaf's objects are tested for each ray that enters its box before its own
    bound. Each ray gets the hit `bvh_walk` finds for it (same box and object arithmetic,
    ties to the lower gid whatever the order of tests); neighbouring eye rays take much the
    same path, so a packet makes one walk's decisions for all of them (Wald et al.,
    "Interactive Rendering with Coherent Ray Tracing", 2001).

    f: float64 scratch (P_ROWS, PACKET): rows P_O.. origin, P_D.. unit direction, P_LO
    t_lo, P_BOUND t_hi in (P_R.. their `bvh.reciprocal`s are made here, for the whole
    packet at once); P_BEST best t out (t_hi if none); origin,
    best_u: int64 (PACKET,) gids of the surfaces left (-1 none) in, local ids hit (-1) out.
    pstack (STACK, PACKET) float64 and refs (STACK,) int64: the pending children. Returns
    how many of the rays tested at inner nodes had entered them (of n per visit): how
    coherent the packet was (`keep_packets`). With any_hit a ray leaves the packet at its
    first hit before its bound (its bound set below every box's entry): a shadow ray needs
    only to know it is blocked, and walked on to its nearest hit it kept the packet visiting
    nodes for nothing."""
    flat, flat_refs = bvh
    reciprocals(f, P_D, P_R)
    _pad(f, origin, n)
    for k in range(n):
        f[P_BEST, k] = f[P_BOUND, k]
        f[P_CUR, k] = f[P_LO, k]
        best_u[k] = -1
    tests = 0
    visits = 0
    entered = 0
    top = 0
    ref = 0
    while True:
        if ref >= 0:
            visits += n
            entered += count_below(f, P_CUR, f, P_BOUND)
            at = ref * NODE_COLS
            a0 = _entry(flat, at, f, 0)
            a1 = _entry(flat, at + 1, f, 1)
            a2 = _entry(flat, at + 2, f, 2)
            a3 = _entry(flat, at + 3, f, 3)
            if a0 < math.inf or a1 < math.inf or a2 < math.inf or a3 < math.inf:
                entered_lanes = (
                    (a0 < math.inf)
                    | ((a1 < math.inf) << 1)
                    | ((a2 < math.inf) << 2)
                    | ((a3 < math.inf) << 3)
                )
                prefetch_entered(
                    flat, flat_refs, at, entered_lanes, NODE_COLS, REF_COL, LEAF_BITS, tri, off[1]
                )
                a0, i0, a1, i1, a2, i2, a3, i3 = sort4(a0, a1, a2, a3)
                for a, i in ((a3, i3), (a2, i2), (a1, i1)):
                    if a < math.inf:
                        copy_row(pstack, top, f, P_E + i)
                        refs[top] = flat_refs[at + REF_COL + i]
                        top += 1
                copy_row(f, P_CUR, f, P_E + i0)
                ref = flat_refs[at + REF_COL + i0]
                continue
        else:
            packed = ~ref
            first = packed >> LEAF_BITS
            for u in range(first, first + (packed & LEAF_CAP)):
                if tri is not None and off[1] <= u < off[2]:
                    got = packet_triangle(
                        tri, u - off[1], gid[u], f, origin, P_O, P_D, P_LO, P_CUR, P_BOUND, P_A
                    )
                    tests += got & 0xFF
                    for k in range(n if got > 0xFF else 0):
                        t = f[P_A, k]
                        if t < math.inf and better(t, u, f[P_BEST, k], best_u[k], gid):
                            f[P_BEST, k] = t
                            best_u[k] = u
                            f[P_BOUND, k] = -math.inf if any_hit else t * TIE
                    continue
                for k in range(n):
                    if not f[P_CUR, k] < f[P_BOUND, k]:
                        continue
                    tests += 1
                    t = test_object(
                        u,
                        f[P_O, k],
                        f[P_O + 1, k],
                        f[P_O + 2, k],
                        f[P_D, k],
                        f[P_D + 1, k],
                        f[P_D + 2, k],
                        f[P_LO, k],
                        f[P_BOUND, k],
                        origin[k],
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
                    if t < math.inf and better(t, u, f[P_BEST, k], best_u[k], gid):
                        f[P_BEST, k] = t
                        best_u[k] = u
                        f[P_BOUND, k] = -math.inf if any_hit else t * TIE
        # Next: the nearest pending child still entered before some ray's bound.
        ref = 0
        while top > 0:
            top -= 1
            if count_below(pstack, top, f, P_BOUND) > 0:
                ref = refs[top]
                copy_row(f, P_CUR, pstack, top)
                break
        if ref == 0:
            break
    counters[TESTS] += tests
    counters[STEPS] += visits
    counters[PACKET_IDLE] += visits - entered
    return entered, visits


@inline
def keep_packets(packets, entered, tested, nodes):
    """Whether a batch goes on walking in packets after `packets` of them, in which
    `entered` of the `tested` ray-node tests were of rays that had entered the node, through
    the hierarchy whose flat float32 `nodes` are given (`bvh.BvhArrays.box`)."""
    far = nodes.shape[0] >= PREFETCH_FROM // 4
    return packets < PROBE or entered >= (COHERENT_FAR if far else COHERENT) * tested
