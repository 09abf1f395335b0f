"""Walking a ray through the uniform grid with the incremental next-voxel step.

Per axis: `delta` is the t between successive voxel walls, `nxt` the t of the next wall. Each
step takes the axis with the smallest `nxt`. Every object is tested at most once per ray
(mailbox stamped with the ray id); a hit beyond the current voxel is kept, but the walk goes on
until the voxel that contains it, because a nearer hit may still come (DESIGN.md 4).
"""

import math

from meshnode.engine.intersect import hit_cone, hit_polygon, hit_sphere, hit_triangle
from meshnode.engine.jit import kernel

INF = math.inf


@kernel
def test_object(u, ox, oy, oz, dx, dy, dz, t_lo, t_hi, origin, gid, off,
                sph, tri, poly, pinfo, puv, cone):  # fmt: skip
    """Dispatch on the local id's kind; kinds passed as None are compiled out."""
    self_hit = gid[u] == origin
    if sph is not None and u < off[1]:
        return hit_sphere(sph, u, ox, oy, oz, dx, dy, dz, t_lo, t_hi, self_hit)
    if tri is not None and u < off[2]:
        if self_hit:  # a ray cannot meet the plane it leaves
            return INF
        return hit_triangle(tri, u - off[1], ox, oy, oz, dx, dy, dz, t_lo, t_hi)[0]
    if poly is not None and u < off[3]:
        if self_hit:
            return INF
        return hit_polygon(poly, pinfo, puv, u - off[2], ox, oy, oz, dx, dy, dz, t_lo, t_hi)
    if cone is not None:
        return hit_cone(cone, u - off[3], ox, oy, oz, dx, dy, dz, t_lo, t_hi, self_hit)
    return INF


@kernel
def box_span(ox, oy, oz, dx, dy, dz, t_lo, t_hi, lo0, lo1, lo2, hi0, hi1, hi2):
    """Clip [t_lo, t_hi] to the box by slabs; empty when the result has t0 > t1."""
    t0 = t_lo
    t1 = t_hi
    for a in range(3):
        o = ox if a == 0 else (oy if a == 1 else oz)
        d = dx if a == 0 else (dy if a == 1 else dz)
        lo = lo0 if a == 0 else (lo1 if a == 1 else lo2)
        hi = hi0 if a == 0 else (hi1 if a == 1 else hi2)
        if d == 0.0:
            if o < lo or o > hi:
                return 1.0, 0.0
            continue
        ta = (lo - o) / d
        tb = (hi - o) / d
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    return t0, t1


@kernel
def walk(ox, oy, oz, dx, dy, dz, t_lo, t_hi, origin, any_hit, ray_id, mail, counters,
         gid, off, sph, tri, poly, pinfo, puv, cone,
         glo, cell, res, offsets, slots, e_vox, e_start, e_count, bits, refs):  # fmt: skip
    """First hit (or, with any_hit, any hit) in (t_lo, t_hi): returns (t, local id or -1)."""
    ghi0 = glo[0] + cell[0] * res[0]
    ghi1 = glo[1] + cell[1] * res[1]
    ghi2 = glo[2] + cell[2] * res[2]
    t0, t1 = box_span(ox, oy, oz, dx, dy, dz, t_lo, t_hi, glo[0], glo[1], glo[2], ghi0, ghi1, ghi2)
    if t0 > t1:
        return INF, -1
    nx = res[0]
    ny = res[1]
    nz = res[2]
    # Voxel of the entry point, clamped: the entry lies on the box within round-off.
    ix = min(max(int(math.floor((ox + t0 * dx - glo[0]) / cell[0])), 0), nx - 1)
    iy = min(max(int(math.floor((oy + t0 * dy - glo[1]) / cell[1])), 0), ny - 1)
    iz = min(max(int(math.floor((oz + t0 * dz - glo[2]) / cell[2])), 0), nz - 1)
    # Per-axis wall distance, next wall and index steps.
    if dx > 0.0:
        sx, dtx, ntx = 1, cell[0] / dx, (glo[0] + (ix + 1) * cell[0] - ox) / dx
    elif dx < 0.0:
        sx, dtx, ntx = -1, -cell[0] / dx, (glo[0] + ix * cell[0] - ox) / dx
    else:
        sx, dtx, ntx = 0, INF, INF
    if dy > 0.0:
        sy, dty, nty = 1, cell[1] / dy, (glo[1] + (iy + 1) * cell[1] - oy) / dy
    elif dy < 0.0:
        sy, dty, nty = -1, -cell[1] / dy, (glo[1] + iy * cell[1] - oy) / dy
    else:
        sy, dty, nty = 0, INF, INF
    if dz > 0.0:
        sz, dtz, ntz = 1, cell[2] / dz, (glo[2] + (iz + 1) * cell[2] - oz) / dz
    elif dz < 0.0:
        sz, dtz, ntz = -1, -cell[2] / dz, (glo[2] + iz * cell[2] - oz) / dz
    else:
        sz, dtz, ntz = 0, INF, INF
    v = ix + nx * (iy + ny * iz)
    slot_mask = 0
    slot = 0
    if slots is not None:
        slot_mask = slots.shape[0] - 2
        slot = v & slot_mask
    best_t = t_hi
    best_u = -1
    tests = 0
    steps = 0
    while True:
        # Find this voxel's references.
        a = 0
        b = 0
        if offsets is not None:
            a = offsets[v]
            b = offsets[v + 1]
        if bits is not None:
            if (bits[v >> 3] >> (v & 7)) & 1:  # empty voxels never touch the table
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
            t = test_object(u, ox, oy, oz, dx, dy, dz, t_lo, best_t, origin, gid, off,
                            sph, tri, poly, pinfo, puv, cone)  # fmt: skip
            if t < best_t:
                best_t = t
                best_u = u
                if any_hit:
                    break
        if any_hit and best_u >= 0:
            break
        t_exit = min(ntx, min(nty, ntz))
        if best_u >= 0 and best_t <= t_exit:
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
    counters[6] += tests
    counters[7] += steps
    return best_t, best_u


@kernel
def brute_force(ox, oy, oz, dx, dy, dz, t_lo, t_hi, origin, any_hit, counters,
                gid, off, sph, tri, poly, pinfo, puv, cone):  # fmt: skip
    """Every object against the ray: the no-grid reference the grid must agree with."""
    best_t = t_hi
    best_u = -1
    n = gid.shape[0]
    for u in range(n):
        counters[6] += 1
        t = test_object(u, ox, oy, oz, dx, dy, dz, t_lo, best_t, origin, gid, off,
                        sph, tri, poly, pinfo, puv, cone)  # fmt: skip
        if t < best_t:
            best_t = t
            best_u = u
            if any_hit:
                break
    return best_t, best_u
