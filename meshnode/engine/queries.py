"""Ray queries outside a render's ray trees: the nearest hit of each ray, and whether anything
lies on each ray before its end (an any-hit query: shadow rays). `Engine.first_hits` and
`Engine.occluded` check their arrays here and call the kernels.

A query's directions are made unit length by its kernel, so distances are in scene units.
"""

import math

import numpy as np

from meshnode.engine.bvh import STACK as BVH_STACK
from meshnode.engine.bvh import bvh_walk
from meshnode.engine.counters import N_COUNTERS, SEGMENTS
from meshnode.engine.jit import kernel
from meshnode.engine.packet import PACKET, keep_packets, packet_walk
from meshnode.engine.trace import _load, _packets
from meshnode.engine.trace import first_hits as first_hits_kernel
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
    counters = np.zeros(N_COUNTERS, np.int64)
    t, gid, bad = first_hits_kernel(
        o,
        d,
        float(t_min),
        engine.brute,
        counters,
        engine.geometry,
        engine.grid_arrays,
        engine.bvh_arrays,
    )
    _refuse(bad, o, d)
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
    counters = np.zeros(N_COUNTERS, np.int64)
    blocked, bad = any_hits(
        o,
        d,
        float(t_min),
        t_hi,
        leaving,
        engine.brute,
        counters,
        engine.geometry,
        engine.grid_arrays,
        engine.bvh_arrays,
    )
    _refuse(bad, o, d)
    return blocked


@kernel
def any_hits(orig, dirs, t_lo, t_hi, leaving, brute, counters, geo, grid, bvh):
    """Whether any object of the `Geometry` geo lies on each ray in (t_lo, t_hi[i]), walking
    the `BvhArrays` bvh (PACKET neighbouring rays at a time for their first hits before
    t_hi, `packet_walk`, while they stay coherent enough, `keep_packets`; then each alone),
    or with bvh None the `GridArrays` grid (or all, with brute), a lone ray's walk stopping
    at the first hit found (any_hit). Ray i skips the object whose scene id is
    leaving[i] (-1: none) as the renderer's shadow rays skip the surface they leave
    (`traverse.test_object`). As the renderer's shadow rays towards one light, each ray
    first tests the last object that blocked one (the walks' hint): neighbouring rays are
    often blocked by the same object. Directions are made unit length here.
    Returns (blocked per ray, index of the first ray with a zero or non-finite direction or
    a non-finite origin, or -1); the caller refuses those."""
    gid, off, sph, tri, poly, pinfo, puv, pband, cone = geo
    n = orig.shape[0]
    blocked = np.zeros(n, np.bool_)
    mail = np.full(gid.shape[0], -1, np.int64)
    stack = np.empty(2 * BVH_STACK)
    hint = -1
    packets = True  # with a hierarchy, until they stop paying (`keep_packets`)
    f, origin, best_u, pstack, refs, idx = _packets()
    m = walked = entered = tested = 0
    for i in range(n):
        ox, oy, oz = orig[i, 0], orig[i, 1], orig[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        big = max(abs(dx), max(abs(dy), abs(dz)))  # scaled first: no overflow in the norm
        if not (0.0 < big < math.inf) or not (
            abs(ox) < math.inf and abs(oy) < math.inf and abs(oz) < math.inf
        ):
            return blocked, i
        s = 1.0 / big
        k = s / math.sqrt((dx * s) ** 2 + (dy * s) ** 2 + (dz * s) ** 2)
        dx *= k
        dy *= k
        dz *= k
        counters[SEGMENTS] += 1
        # With a hierarchy, PACKET neighbours walk it together (neighbours' rays to one light
        # take much the same path), each leaving the packet at its first hit before t_hi.
        if bvh is not None and packets:
            _load(f, origin, m, ox, oy, oz, dx, dy, dz, t_lo, t_hi[i], leaving[i])
            idx[m] = i
            m += 1
            if m == PACKET or i == n - 1:
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
                    True,
                )
                for j in range(m):
                    blocked[idx[j]] = best_u[j] >= 0
                m = 0
                walked += 1
                entered += e
                tested += v
                packets = keep_packets(walked, entered, tested)
            continue
        # Walk the structure present (the one passed None is compiled out, as in first_hits).
        if bvh is not None:
            _, u = bvh_walk(
                ox,
                oy,
                oz,
                dx,
                dy,
                dz,
                t_lo,
                t_hi[i],
                leaving[i],
                True,
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
                _, u = brute_force(
                    ox,
                    oy,
                    oz,
                    dx,
                    dy,
                    dz,
                    t_lo,
                    t_hi[i],
                    leaving[i],
                    True,
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
                _, u = walk(
                    ox,
                    oy,
                    oz,
                    dx,
                    dy,
                    dz,
                    t_lo,
                    t_hi[i],
                    leaving[i],
                    True,
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
            _, u = math.inf, -1
        if u >= 0:
            blocked[i] = True
            hint = u
    return blocked, -1
