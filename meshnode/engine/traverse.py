"""Walking a ray through the uniform grid with the incremental next-voxel step.

Per axis: `delta` is the t between successive voxel walls, `nxt` the t of the next wall. Each
step takes the axis with the smallest `nxt`. Every object is tested at most once per ray
(mailbox stamped with the ray id); equal distances go to the lower gid, so the first hit never
depends on the order of tests (grid, storage or node). A hit beyond the current voxel is kept,
but the walk goes on until the voxel that contains it: a nearer hit may still come (DESIGN.md 4).

Over the 400 lines a module may have, on purpose: the walk, the mailbox, brute force and the
tie rule are the innermost loop of every ray, kept in one module so numba inlines them into
one another (a call between modules costs reference counting per array argument per step).
"""

import math

from meshnode.engine.counters import STEPS, TESTS
from meshnode.engine.intersect import hit_cone, hit_polygon, hit_sphere, hit_triangle
from meshnode.engine.jit import inline, leaf

INF = math.inf
# Hits within a relative TIE of each other are one distance, and the lower gid wins: surfaces
# that coincide (SPD teapot_s1's spout is two sheets of triangles in one plane) would
# otherwise be won by round-off, pixel by pixel, each with its own shading normal: speckles.
# Objects are tested up to best_t * TIE so that such a twin is seen.
TIE = 1.0 + 1e-9


@inline
def better(t, u, best_t, best_u, gid):
    """Whether a hit at t on object u beats the best so far (ties: the lower gid)."""
    if best_u < 0:
        return t < best_t
    if t * TIE < best_t:
        return True
    return t <= best_t * TIE and gid[u] < gid[best_u]


@inline
def test_object(
    u, ox, oy, oz, dx, dy, dz, t_lo, t_hi, origin, gid, off, sph, tri, poly, pinfo, puv, pband, cone
):
    """Dispatch on the local id's kind; kinds passed as None are compiled out."""
    self_hit = origin >= 0 and gid[u] == origin  # eye rays (origin -1) skip the load
    if sph is not None and u < off[1]:
        return hit_sphere(sph, u, ox, oy, oz, dx, dy, dz, t_lo, t_hi, self_hit)
    if tri is not None and u < off[2]:
        if self_hit:  # a ray cannot meet the plane it leaves
            return INF
        return hit_triangle(tri, u - off[1], ox, oy, oz, dx, dy, dz, t_lo, t_hi)[0]
    if poly is not None and u < off[3]:
        if self_hit:
            return INF
        return hit_polygon(poly, pinfo, puv, pband, u - off[2], ox, oy, oz, dx, dy, dz, t_lo, t_hi)
    if cone is not None:
        return hit_cone(cone, u - off[3], ox, oy, oz, dx, dy, dz, t_lo, t_hi, self_hit)
    return INF


@inline
def hinted(
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
):
    """Distance to the any-hit query's hint object (the last blocker from the same surface
    towards the same light), tested before any walk; inf without a hint or when it misses."""
    if hint < 0:
        return INF
    counters[TESTS] += 1
    return test_object(
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


@leaf
def box_span(ox, oy, oz, rx, ry, rz, t_lo, t_hi, lo0, lo1, lo2, hi0, hi1, hi2):
    """Clip [t_lo, t_hi] to the box by slabs; empty when the result has t0 > t1.

    rx, ry, rz are reciprocal direction components (inf where the direction is 0)."""
    t0 = t_lo
    t1 = t_hi
    for a in range(3):
        o = ox if a == 0 else (oy if a == 1 else oz)
        r = rx if a == 0 else (ry if a == 1 else rz)
        lo = lo0 if a == 0 else (lo1 if a == 1 else lo2)
        hi = hi0 if a == 0 else (hi1 if a == 1 else hi2)
        if math.isinf(r):
            if o < lo or o > hi:
                return 1.0, 0.0
            continue
        ta = (lo - o) * r
        tb = (hi - o) * r
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    return t0, t1


@inline
def _slab(o, r, lo, hi, t0, t1):
    """[t0, t1] clipped to one axis's slab [lo, hi] (r: the finite reciprocal direction)."""
    ta = (lo - o) * r
    tb = (hi - o) * r
    if ta > tb:
        ta, tb = tb, ta
    return max(t0, ta), min(t1, tb)


@inline
def two_spans(
    ox,
    oy,
    oz,
    rx,
    ry,
    rz,
    t_lo,
    t_hi,
    a_lo0,
    a_lo1,
    a_lo2,
    a_hi0,
    a_hi1,
    a_hi2,
    b_lo0,
    b_lo1,
    b_lo2,
    b_hi0,
    b_hi1,
    b_hi2,
):
    """`box_span` of one segment in two boxes a and b at once, exactly as two calls give
    them: a mesh node clips every segment to the scene's box and its own, and apart the
    two cost a tenth of tetra's mesh kernel (each axis's origin, reciprocal and branch
    once here, and no call)."""
    a0 = b0 = t_lo
    a1 = b1 = t_hi
    a_out = b_out = False
    for k in range(3):
        o = ox if k == 0 else (oy if k == 1 else oz)
        r = rx if k == 0 else (ry if k == 1 else rz)
        alo = a_lo0 if k == 0 else (a_lo1 if k == 1 else a_lo2)
        ahi = a_hi0 if k == 0 else (a_hi1 if k == 1 else a_hi2)
        blo = b_lo0 if k == 0 else (b_lo1 if k == 1 else b_lo2)
        bhi = b_hi0 if k == 0 else (b_hi1 if k == 1 else b_hi2)
        if math.isinf(r):
            a_out = a_out or o < alo or o > ahi
            b_out = b_out or o < blo or o > bhi
            continue
        a0, a1 = _slab(o, r, alo, ahi, a0, a1)
        b0, b1 = _slab(o, r, blo, bhi, b0, b1)
    if a_out:
        a0, a1 = 1.0, 0.0
    if b_out:
        b0, b1 = 1.0, 0.0
    return a0, a1, b0, b1


@leaf
def _voxel(o, d, t, lo, cell, n):
    """Voxel index along one axis of the point at t, clamped into the grid."""
    return min(max(int(math.floor((o + t * d - lo) / cell)), 0), n - 1)


@leaf
def _region_exit(o, d, inv, i_lo, i_hi, lo, cell):
    """t where the ray leaves voxels [i_lo, i_hi] along one axis (inf when d is 0); with
    i_lo = i_hi, the next voxel wall."""
    if d > 0.0:
        return (lo + (i_hi + 1) * cell - o) * inv
    if d < 0.0:
        return (lo + i_lo * cell - o) * inv
    return INF


@leaf
def walk(
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
    ray_id,
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
):
    """First hit (or, with any_hit, any hit) in (t_lo, t_hi) through the `GridArrays` grid:
    returns (t, local id or -1). mail[u] == ray_id marks object u as tested for this ray.

    gid ... cone are the fields of a `Geometry`, as arguments: only so does numba compile out
    the absent kinds. An any-hit query may pass in `hint` (else -1) the object most likely to
    block it, the one that last blocked a shadow ray from the same object towards the same
    light (`trace.trace_batch`'s shadow cache): it is tested first, and a hit on it is
    returned without walking.

    In an empty voxel whose macro cell lies k macro cells from any object, the ray jumps out of
    the empty cube of radius k - 1 around it in one step and the walk restarts there."""
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
    glo, cell, res, offsets, slots, e_vox, e_start, e_count, bits, refs, macro, mres, mshift = grid
    nx = res[0]
    ny = res[1]
    nz = res[2]
    hx = glo[0] + cell[0] * nx
    hy = glo[1] + cell[1] * ny
    hz = glo[2] + cell[2] * nz
    # Reciprocal directions: every wall crossing below is a multiply, not a divide.
    rx = 1.0 / dx if dx != 0.0 else INF
    ry = 1.0 / dy if dy != 0.0 else INF
    rz = 1.0 / dz if dz != 0.0 else INF
    t0, t1 = box_span(ox, oy, oz, rx, ry, rz, t_lo, t_hi, glo[0], glo[1], glo[2], hx, hy, hz)
    if t0 > t1:
        return INF, -1
    # Voxel of the entry point, clamped: the entry lies on the box within round-off.
    ix = _voxel(ox, dx, t0, glo[0], cell[0], nx)
    iy = _voxel(oy, dy, t0, glo[1], cell[1], ny)
    iz = _voxel(oz, dz, t0, glo[2], cell[2], nz)
    # Per-axis index step, wall-to-wall distance and next wall.
    sx = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
    sy = 1 if dy > 0.0 else (-1 if dy < 0.0 else 0)
    sz = 1 if dz > 0.0 else (-1 if dz < 0.0 else 0)
    dtx = cell[0] * abs(rx)
    dty = cell[1] * abs(ry)
    dtz = cell[2] * abs(rz)
    ntx = _region_exit(ox, dx, rx, ix, ix, glo[0], cell[0])
    nty = _region_exit(oy, dy, ry, iy, iy, glo[1], cell[1])
    ntz = _region_exit(oz, dz, rz, iz, iz, glo[2], cell[2])
    v = ix + nx * (iy + ny * iz)
    csr = offsets.shape[0] > 0
    slot_mask = 0 if csr else slots.shape[0] - 2
    slot = v & slot_mask
    best_t = t_hi
    best_u = -1
    tests = 0
    steps = 0
    # Every step leaves a voxel (or a cube of them) for one further along the ray, so a walk
    # takes at most nx + ny + nz steps; the bound keeps a ray whose arithmetic went non-finite
    # or overflowed (a peer's rays, a scene at 1e300) from walking forever.
    max_steps = 2 * (nx + ny + nz) + 16
    while steps <= max_steps:
        # Empty macro cell: jump out of the empty cube of macro cells around it without
        # touching the voxel table (the small macro table stays in cache).
        mx = ix >> mshift
        my = iy >> mshift
        mz = iz >> mshift
        k = macro[mx + mres[0] * (my + mres[1] * mz)]
        if k >= 1:
            r = k - 1
            x0 = max((mx - r) << mshift, 0)
            x1 = min((mx + r + 1) << mshift, nx) - 1
            y0 = max((my - r) << mshift, 0)
            y1 = min((my + r + 1) << mshift, ny) - 1
            z0 = max((mz - r) << mshift, 0)
            z1 = min((mz + r + 1) << mshift, nz) - 1
            tx = _region_exit(ox, dx, rx, x0, x1, glo[0], cell[0])
            ty = _region_exit(oy, dy, ry, y0, y1, glo[1], cell[1])
            tz = _region_exit(oz, dz, rz, z0, z1, glo[2], cell[2])
            t_jump = min(tx, min(ty, tz))
            if best_u >= 0 and best_t <= t_jump:
                break
            if t_jump > t1:
                break
            steps += 1
            ix = min(max(_voxel(ox, dx, t_jump, glo[0], cell[0], nx), x0), x1)
            iy = min(max(_voxel(oy, dy, t_jump, glo[1], cell[1], ny), y0), y1)
            iz = min(max(_voxel(oz, dz, t_jump, glo[2], cell[2], nz), z0), z1)
            if tx <= ty and tx <= tz:
                ix = x1 + 1 if sx > 0 else x0 - 1
                if ix < 0 or ix >= nx:
                    break
            elif ty <= tz:
                iy = y1 + 1 if sy > 0 else y0 - 1
                if iy < 0 or iy >= ny:
                    break
            else:
                iz = z1 + 1 if sz > 0 else z0 - 1
                if iz < 0 or iz >= nz:
                    break
            ntx = _region_exit(ox, dx, rx, ix, ix, glo[0], cell[0])
            nty = _region_exit(oy, dy, ry, iy, iy, glo[1], cell[1])
            ntz = _region_exit(oz, dz, rz, iz, iz, glo[2], cell[2])
            v = ix + nx * (iy + ny * iz)
            slot = v & slot_mask
            continue
        # Find this voxel's references.
        a = 0
        b = 0
        if csr:
            a = offsets[v]
            b = offsets[v + 1]
        elif (bits[v >> 3] >> (v & 7)) & 1:  # empty voxels never touch the hash table
            for e in range(slots[slot], slots[slot + 1]):
                if e_vox[e] == v:
                    a = e_start[e]
                    b = a + e_count[e]
                    break
        # Test each object once per ray.
        for r in range(a, b):
            u = refs[r]
            if mail[u] == ray_id:
                continue
            mail[u] = ray_id
            tests += 1
            bound = best_t if best_u < 0 else best_t * TIE
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
            if t < INF and better(t, u, best_t, best_u, gid):
                best_t = t
                best_u = u
                if any_hit:
                    break
        if any_hit and best_u >= 0:
            break
        t_exit = min(ntx, min(nty, ntz))
        if best_u >= 0 and best_t * TIE <= t_exit:  # no twin can lie beyond this voxel
            break
        if t_exit > t1:
            break
        # Step to the neighbouring voxel across the nearest wall.
        steps += 1
        if ntx <= nty and ntx <= ntz:
            ix += sx
            if ix < 0 or ix >= nx:
                break
            ntx += dtx
            step = sx
        elif nty <= ntz:
            iy += sy
            if iy < 0 or iy >= ny:
                break
            nty += dty
            step = sy * nx
        else:
            iz += sz
            if iz < 0 or iz >= nz:
                break
            ntz += dtz
            step = sz * nx * ny
        v += step
        slot = (slot + step) & slot_mask
    counters[TESTS] += tests
    counters[STEPS] += steps
    return best_t, best_u


@leaf
def brute_force(
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
):
    """Every object against the ray: the no-grid reference the grid must agree with (gid ...
    cone: a `Geometry`'s fields, as in `walk`)."""
    best_t = t_hi
    best_u = -1
    n = gid.shape[0]
    for u in range(n):
        counters[TESTS] += 1
        bound = best_t if best_u < 0 else best_t * TIE
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
        if t < INF and better(t, u, best_t, best_u, gid):
            best_t = t
            best_u = u
            if any_hit:
                break
    return best_t, best_u
