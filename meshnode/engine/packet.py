"""Rays walked through the hierarchy (`bvh`) in packets of PACKET neighbours: each visit
tests a node's four children's boxes for every ray of the packet, a vector loop a box, and a leaf's
triangles likewise; the packet goes where any of its rays enters. Each ray gets exactly the
hit a walk of its own finds (`bvh.bvh_walk`: the same box and object arithmetic, ties to the
lower gid whatever the order of tests), in less time while neighbouring rays take the same
path: one node's eye and camera rays (Wald et al., "Interactive Rendering with Coherent Ray
Tracing", 2001). A batch stops using packets when they stop paying (`keep_packets`).
"""

import math

import numpy as np

from meshnode.engine.bvh import (
    HI,
    LEAF_BITS,
    LEAF_CAP,
    NODE_COLS,
    REF_COL,
    reciprocal,
    sort4,
)
from meshnode.engine.bvh import STACK as BVH_STACK
from meshnode.engine.counters import STEPS, TESTS
from meshnode.engine.intersect import EDGE_SLACK
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.lanes import SLACK
from meshnode.engine.traverse import TIE, better, test_object

PACKET = 8  # rays `packet_walk` takes through the tree together (one or two vector registers)
# Packets pay while neighbouring rays take the same path: a batch walks its first PROBE
# packets, then goes on in packets only if at least COHERENT of the rays tested at each node
# had entered it (tetra: 0.81; a million-triangle tetrahedron, 0.52, is 1.2x slower in
# packets, so its rays walk alone).
PROBE = 32
COHERENT = 0.65
# Rows of a packet's float64 scratch (`packet_walk`): the rays, then what the walk keeps.
# P_E .. P_E + 3: each ray's entry into each of a node's four boxes.
P_O, P_D, P_R, P_LO, P_BOUND, P_BEST, P_A, P_CUR, P_E, P_ROWS = 0, 3, 6, 9, 10, 11, 12, 13, 14, 18


@inline
def _packet_slabs(flat, at, f, row, n):
    """`lanes.slab4` for each of the packet's n rays (scratch `f`, see `packet_walk`) against
    the box of lane at % 4 of a node (planes flat[at], flat[at + 4], ...): entry t or inf
    into f[row]; returns how many rays enter. The same arithmetic, ray by ray (the near
    plane chosen by the direction's sign), written as a loop the compiler turns into vector
    instructions."""
    lo0, lo1, lo2 = np.float64(flat[at]), np.float64(flat[at + 4]), np.float64(flat[at + 8])
    hi0 = np.float64(flat[at + HI])
    hi1, hi2 = np.float64(flat[at + HI + 4]), np.float64(flat[at + HI + 8])
    hits = 0
    for k in range(n):
        rx, ry, rz = f[P_R, k], f[P_R + 1, k], f[P_R + 2, k]
        ax = (lo0 - f[P_O, k]) * rx
        bx = (hi0 - f[P_O, k]) * rx
        ay = (lo1 - f[P_O + 1, k]) * ry
        by = (hi1 - f[P_O + 1, k]) * ry
        az = (lo2 - f[P_O + 2, k]) * rz
        bz = (hi2 - f[P_O + 2, k]) * rz
        t0 = max(ax if rx >= 0.0 else bx, max(ay if ry >= 0.0 else by, az if rz >= 0.0 else bz))
        t1 = min(bx if rx >= 0.0 else ax, min(by if ry >= 0.0 else ay, bz if rz >= 0.0 else az))
        t1 *= SLACK
        ok = t0 <= t1 and t1 > f[P_LO, k] and t0 < f[P_BOUND, k]
        f[row, k] = t0 if ok else math.inf
        hits += 1 if ok else 0
    return hits


@inline
def _packet_triangle(tr, i, self_gid, f, origin, n):
    """`intersect.hit_triangle` of triangle row i for each of the packet's rays that enter
    the leaf before their bound, as one vector loop: t or inf into f[P_A]; returns how many
    rays were tested. The same arithmetic and the same tests, ray by ray, so the same t;
    a ray leaving this very triangle (its origin gid is `self_gid`) misses it."""
    v0x, v0y, v0z = tr[i, 0], tr[i, 1], tr[i, 2]
    e1x, e1y, e1z = tr[i, 3], tr[i, 4], tr[i, 5]
    e2x, e2y, e2z = tr[i, 6], tr[i, 7], tr[i, 8]
    tested = 0
    for k in range(n):
        active = f[P_CUR, k] < f[P_BOUND, k]
        dx, dy, dz = f[P_D, k], f[P_D + 1, k], f[P_D + 2, k]
        px = dy * e2z - dz * e2y
        py = dz * e2x - dx * e2z
        pz = dx * e2y - dy * e2x
        det = e1x * px + e1y * py + e1z * pz
        inv = 1.0 / det
        sx = f[P_O, k] - v0x
        sy = f[P_O + 1, k] - v0y
        sz = f[P_O + 2, k] - v0z
        u = (sx * px + sy * py + sz * pz) * inv
        qx = sy * e1z - sz * e1y
        qy = sz * e1x - sx * e1z
        qz = sx * e1y - sy * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        t = (e2x * qx + e2y * qy + e2z * qz) * inv
        ok = (
            active
            and det != 0.0
            and not (u < -EDGE_SLACK or u > 1.0 + EDGE_SLACK)
            and not (v < -EDGE_SLACK or u + v > 1.0 + EDGE_SLACK)
            and f[P_LO, k] < t < f[P_BOUND, k]
            and origin[k] != self_gid
        )
        f[P_A, k] = t if ok else math.inf
        tested += 1 if active else 0
    return tested


@inline
def _nearest(f, row, n):
    """The smallest entry in f[row, :n]: which child a packet visits first."""
    m = math.inf
    for k in range(n):
        m = min(m, f[row, k])
    return m


@inline
def _entry(flat, at, f, lane, n):
    """Lane `lane`'s box (planes from flat[at]) against the packet: each ray's entry into
    f[P_E + lane], and the nearest of them (inf when no ray enters): the key the packet
    orders a node's children by."""
    if _packet_slabs(flat, at, f, P_E + lane, n) == 0:
        return math.inf
    return _nearest(f, P_E + lane, n)


@inline
def load_ray(f, origin, k, ox, oy, oz, dx, dy, dz, t_lo, t_hi, org):
    """Ray k of a packet's scratch (`packet_walk`): origin, direction, reciprocals, span, and
    the gid of the surface it leaves."""
    f[P_O, k], f[P_O + 1, k], f[P_O + 2, k] = ox, oy, oz
    f[P_D, k], f[P_D + 1, k], f[P_D + 2, k] = dx, dy, dz
    f[P_R, k], f[P_R + 1, k], f[P_R + 2, k] = reciprocal(dx), reciprocal(dy), reciprocal(dz)
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
    """First hits of n <= PACKET rays walked through the tree together: each visit tests
    the four children's boxes for every ray, a vector loop a box (`_packet_slabs`), and the
    packet goes where any ray enters, nearest child first (by its nearest ray's entry); a leaf's
    objects are tested for each ray that enters its box before its own bound. Each ray gets the
    hit `bvh_walk` finds for it (same box and object arithmetic, ties to the lower gid whatever
    the order of tests); neighbouring eye rays take much the same path, so a packet makes one
    walk's decisions for all of them (Wald et al., "Interactive Rendering with Coherent Ray
    Tracing", 2001).

    f: float64 scratch (P_ROWS, PACKET): rows P_O.. origin, P_D.. direction, P_R..
    `reciprocal`s, P_LO t_lo, P_BOUND t_hi in; P_BEST best t out (t_hi if none); origin,
    best_u: int64 (PACKET,) gids of the surfaces left (-1 none) in, local ids hit (-1) out.
    pstack (STACK, PACKET) float64 and refs (STACK,) int64: the pending children. Returns
    how many of the rays tested at inner nodes had entered them (of n per visit): how
    coherent the packet was (`keep_packets`). With any_hit a ray leaves the packet at its
    first hit before its bound (its bound set below every box's entry): a shadow ray needs
    only to know it is blocked, and walked on to its nearest hit it kept the packet visiting
    nodes for nothing."""
    flat, flat_refs = bvh
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
            for k in range(n):
                entered += 1 if f[P_CUR, k] < f[P_BOUND, k] else 0
            at = ref * NODE_COLS
            a0 = _entry(flat, at, f, 0, n)
            a1 = _entry(flat, at + 1, f, 1, n)
            a2 = _entry(flat, at + 2, f, 2, n)
            a3 = _entry(flat, at + 3, f, 3, n)
            if a0 < math.inf or a1 < math.inf or a2 < math.inf or a3 < math.inf:
                a0, i0, a1, i1, a2, i2, a3, i3 = sort4(a0, a1, a2, a3)
                for a, i in ((a3, i3), (a2, i2), (a1, i1)):
                    if a < math.inf:
                        for k in range(n):
                            pstack[top, k] = f[P_E + i, k]
                        refs[top] = flat_refs[at + REF_COL + i]
                        top += 1
                for k in range(n):
                    f[P_CUR, k] = f[P_E + i0, k]
                ref = flat_refs[at + REF_COL + i0]
                continue
        else:
            packed = ~ref
            first = packed >> LEAF_BITS
            for u in range(first, first + (packed & LEAF_CAP)):
                if tri is not None and off[1] <= u < off[2]:
                    tests += _packet_triangle(tri, u - off[1], gid[u], f, origin, n)
                    for k in range(n):
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
            live = 0
            for k in range(n):
                live += 1 if pstack[top, k] < f[P_BOUND, k] else 0
            if live > 0:
                ref = refs[top]
                for k in range(n):
                    f[P_CUR, k] = pstack[top, k]
                break
        if ref == 0:
            break
    counters[TESTS] += tests
    counters[STEPS] += visits
    return entered, visits


@inline
def keep_packets(packets, entered, tested):
    """Whether a batch goes on walking in packets after `packets` of them, in which
    `entered` of the `tested` ray-node tests were of rays that had entered the node."""
    return packets < PROBE or entered >= COHERENT * tested
