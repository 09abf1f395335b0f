"""Ray queries outside a render's ray trees: the nearest hit of each ray, and whether anything
lies on each ray before its end (an any-hit query: shadow rays). `Engine.first_hits` and
`Engine.occluded` check their arrays here and call the kernels.

Both are one kernel (`ray_hits`), any_hit a value: a nearest-hit query is an any-hit query's
walk that does not stop at the first hit. A query's directions are made unit length by its
kernel, so distances are in scene units.
"""

import math

import numpy as np

from meshnode.engine.bvh import STACK as BVH_STACK
from meshnode.engine.bvh import bvh_walk
from meshnode.engine.counters import N_COUNTERS, SEGMENTS
from meshnode.engine.jit import kernel
from meshnode.engine.packet import (
    P_BEST,
    P_D,
    PACKET,
    keep_packets,
    load_ray,
    packet_scratch,
    packet_walk,
)
from meshnode.engine.rows import unit_directions
from meshnode.engine.traverse import brute_force, walk


def _rays(origins, directions):
    """(origins, directions) as contiguous float64 (n, 3) arrays of one shape."""
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError(f"origins {o.shape} and directions {d.shape} differ in shape")
    return o, d


def _refuse(bad: int, o, d) -> None:
    """Raise for ray `bad` (>= 0), refused by a kernel."""
    if bad >= 0:
        raise ValueError(
            f"ray {bad}: directions must be finite and non-zero; origins "
            f"finite (origin {o[bad].tolist()}, direction {d[bad].tolist()})"
        )


def first_hits(engine, origins, directions, t_min: float = 0.0):
    """`Engine.first_hits`: (distance, scene object id) of each ray's nearest hit."""
    o, d = _rays(origins, directions)
    n = len(o)
    t, gid = _query(engine, o, d, t_min, np.full(n, math.inf), np.full(n, -1, np.int64), False)
    return t, gid


def occluded(engine, origins, directions, t_max, leaving=None, t_min: float = 0.0):
    """`Engine.occluded`: whether some object lies on each ray in (t_min, t_max)."""
    o, d = _rays(origins, directions)
    n = len(o)
    t_hi = np.ascontiguousarray(np.broadcast_to(np.asarray(t_max, np.float64), (n,)))
    if leaving is None:
        leaving = np.full(n, -1, np.int64)
    leaving = np.ascontiguousarray(np.broadcast_to(np.asarray(leaving, np.int64), (n,)))
    if np.isnan(t_hi).any():
        raise ValueError(f"ray {int(np.argmax(np.isnan(t_hi)))}: t_max is NaN")
    _, gid = _query(engine, o, d, t_min, t_hi, leaving, True)
    return gid >= 0


def _query(engine, o, d, t_min: float, t_hi, leaving, any_hit: bool):
    """(t, gid) of `ray_hits` over the engine's objects; a ray it refuses raises."""
    counters = np.zeros(N_COUNTERS, np.int64)
    t, gid, bad = ray_hits(
        o,
        d,
        float(t_min),
        t_hi,
        leaving,
        any_hit,
        engine.brute,
        counters,
        engine.geometry,
        engine.grid_arrays,
        engine.bvh_arrays,
    )
    _refuse(bad, o, d)
    return t, gid


@kernel
def ray_hits(orig, dirs, t_lo, t_hi, leaving, any_hit, brute, counters, geo, grid, bvh):
    """For each ray the hit in (t_lo, t_hi[i]) among the objects of the `Geometry` geo: the
    nearest, or with any_hit the first found (the walk stops there: shadow rays), as
    (distance, scene id or -1). Walks the `BvhArrays` bvh (PACKET neighbouring rays at a
    time, `packet_walk`, while they stay coherent enough, `keep_packets`; then each alone),
    or with bvh None the `GridArrays` grid (or all, with brute): the structure is a type,
    the one passed None compiled out (`variants.Variant.structure`). Ray i skips the
    object whose scene id is leaving[i] (-1: none), as the renderer's rays skip the surface
    they leave (`traverse.test_object`); an any-hit ray first tests the last object that
    blocked one (the walks' hint), as the renderer's shadow rays towards one light do.
    Directions are made unit length here: distances are in scene units.
    Returns (t, gid, index of the first ray with a zero or non-finite direction or a
    non-finite origin, or -1); the caller refuses those."""
    gid, off, sph, tri, poly, pinfo, puv, pband, cone = geo
    n = orig.shape[0]
    t_out = np.full(n, math.inf)
    g_out = np.full(n, -1, np.int64)
    mail = np.full(gid.shape[0] if bvh is None else 0, -1, np.int64)  # the grid's alone
    stack = np.empty(2 * BVH_STACK)
    hint = -1
    packets = True  # with a hierarchy, until they stop paying (`keep_packets`)
    f, origin, best_u, pstack, refs, idx = packet_scratch()
    m = walked = entered = tested = 0
    for i in range(n):
        ox, oy, oz = orig[i, 0], orig[i, 1], orig[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        big = max(abs(dx), max(abs(dy), abs(dz)))  # scaled first: no overflow in the norm
        if not (0.0 < big < math.inf) or not (
            abs(ox) < math.inf and abs(oy) < math.inf and abs(oz) < math.inf
        ):
            return t_out, g_out, i
        counters[SEGMENTS] += 1
        if bvh is not None and packets:
            load_ray(f, origin, m, ox, oy, oz, dx, dy, dz, t_lo, t_hi[i], leaving[i])
            idx[m] = i
            m += 1
            if m == PACKET or i == n - 1:
                unit_directions(f, P_D)  # as below, for the whole packet at once
                e, v = packet_walk(
                    f,
                    origin,
                    best_u,
                    m,
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
                    any_hit,
                )
                for j in range(m):
                    t_out[idx[j]] = f[P_BEST, j]
                    if best_u[j] >= 0:
                        g_out[idx[j]] = gid[best_u[j]]
                m = 0
                walked += 1
                entered += e
                tested += v
                packets = keep_packets(walked, entered, tested, bvh[0])
            continue
        s = 1.0 / big
        k = s / math.sqrt((dx * s) ** 2 + (dy * s) ** 2 + (dz * s) ** 2)
        dx *= k
        dy *= k
        dz *= k
        # Each walk under `is not None` of its own structure: numba prunes a branch on an
        # argument passed None, and types every other (the grid's walk of None fails)
        if bvh is not None:
            t, u = bvh_walk(
                ox,
                oy,
                oz,
                dx,
                dy,
                dz,
                t_lo,
                t_hi[i],
                leaving[i],
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
            )
        elif grid is not None:
            if brute:
                t, u = brute_force(
                    ox,
                    oy,
                    oz,
                    dx,
                    dy,
                    dz,
                    t_lo,
                    t_hi[i],
                    leaving[i],
                    any_hit,
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
            else:
                t, u = walk(
                    ox,
                    oy,
                    oz,
                    dx,
                    dy,
                    dz,
                    t_lo,
                    t_hi[i],
                    leaving[i],
                    any_hit,
                    hint,
                    i,
                    mail,
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
                    grid,
                )
        else:  # no structure: never, but numba types each branch
            t, u = math.inf, -1
        t_out[i] = t
        if u >= 0:
            g_out[i] = gid[u]
            if any_hit:
                hint = u
    return t_out, g_out, -1
