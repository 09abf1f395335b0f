"""Which voxels each object touches: the kernels that fill the grid's voxel references and
mark the scene's occupancy map.

A box-range test alone puts a large sphere or a slanted triangle in every voxel of its bounds;
these kernels keep only the voxels an object's surface can reach, conservatively: box-sphere
distance, a triangle's separating axes (its plane and its edges across the box's axes), a
polygon's plane straddling the box, a cone's axis within its largest radius of the box. Kept
apart from `grid` (resolution, storage, the build that calls `voxel_refs` to count and then to
fill) and from the host's map (`host.planning.occupancy`, which calls `touched_map`): overlap
tests are geometry, not grid or map policy. The map's occupied share of 64^3 voxels, objects'
bounds against these tests: teapot 9.4 -> 6.0%, mount 9.3 -> 5.3, rings 16.2 -> 11.6, tetra
14.0 -> 7.1, sombrero 12.3 -> 6.5, jacks 29.4 -> 4.4; balls the same (small spheres).
"""

import math

import numpy as np

from meshnode.engine.intersect import triangle_normal
from meshnode.engine.jit import kernel


@kernel
def voxel_refs(glo, cell, res, lo, hi, geo, fill, counts, starts, refs):
    """Count (fill=False) or write (fill=True) the references of every object.

    Bounds give a voxel range; spheres and planar objects then keep only voxels they touch
    (box-sphere distance, plane straddles box), which cuts references for large objects."""
    nx, ny = res[0], res[1]
    ijk_lo = np.empty(3, np.int64)
    ijk_hi = np.empty(3, np.int64)
    for u in range(lo.shape[0]):
        _bounds_voxels(lo, hi, u, 0.0, 1e-7, glo, cell, res, ijk_lo, ijk_hi)
        for iz in range(ijk_lo[2], ijk_hi[2] + 1):
            for iy in range(ijk_lo[1], ijk_hi[1] + 1):
                for ix in range(ijk_lo[0], ijk_hi[0] + 1):
                    if not _touches(
                        u,
                        ix,
                        iy,
                        iz,
                        glo,
                        cell,
                        0.0,
                        False,
                        geo.off,
                        geo.sph,
                        geo.tri,
                        geo.poly,
                        None,
                    ):
                        continue
                    v = ix + nx * (iy + ny * iz)
                    if fill:
                        refs[starts[v]] = u
                        starts[v] += 1
                    else:
                        counts[v] += 1


@kernel
def touched_map(glo, cell, res, lo, hi, grow, geo, full, fine, sub, tests):
    """Mark full[x + nx * (y + ny * z)] for every voxel that some object's surface reaches
    with the voxel grown by `grow` on every side (the occupancy map's padding, so a walk's
    round-off never steps past a surface), testing the voxels of each object's bounds grown
    alike as `_touches` tests them; and in fine[v] (uint64, bit x + sub y + sub^2 z) the
    sub-voxels of a sub^3 split of the voxel that a surface reaching it reaches, grown alike.
    A sub-voxel grown lies inside its voxel grown, so only voxels an object reaches have
    theirs tested: a large sphere's shell, not its bounds, at the finer size. A voxel is
    marked whole (more marked is as exact) when another object reaches it once half its
    sub-voxels are (few paths through it miss them all), or once `tests` sub-voxel tests are
    spent (shells, nested spheres 60 of 64 sub-voxels deep in every voxel: 0.6 s of tests).
    Returns the tests left."""
    nx, ny = res[0], res[1]
    ijk_lo = np.empty(3, np.int64)
    ijk_hi = np.empty(3, np.int64)
    sub_lo = np.empty(3, np.int64)
    sub_hi = np.empty(3, np.int64)
    part = cell / sub
    every = np.uint64(0xFFFFFFFFFFFFFFFF) >> np.uint64(64 - sub**3)
    for u in range(lo.shape[0]):
        _bounds_voxels(lo, hi, u, grow, 0.0, glo, cell, res, ijk_lo, ijk_hi)
        _bounds_voxels(lo, hi, u, grow, 0.0, glo, part, res * sub, sub_lo, sub_hi)
        for iz in range(ijk_lo[2], ijk_hi[2] + 1):
            for iy in range(ijk_lo[1], ijk_hi[1] + 1):
                for ix in range(ijk_lo[0], ijk_hi[0] + 1):
                    v = ix + nx * (iy + ny * iz)
                    if fine[v] == every or not _reached(u, ix, iy, iz, glo, cell, grow, geo):
                        continue
                    full[v] = True
                    if tests <= 0 or _bits(fine[v]) * 2 >= sub**3:
                        fine[v] = every
                    else:
                        bits, made = _sub_touched(
                            u, ix, iy, iz, sub, sub_lo, sub_hi, fine[v], glo, part, grow, geo
                        )
                        fine[v] |= bits
                        tests -= made
    return tests


@kernel
def _bits(x):
    """How many bits of the uint64 x are set."""
    n = 0
    while x:
        x &= x - np.uint64(1)
        n += 1
    return n


@kernel
def _sub_touched(u, ix, iy, iz, sub, sub_lo, sub_hi, marked, glo, part, grow, geo):
    """(the bits of voxel (ix, iy, iz)'s sub-voxels (size `part`) that object u's surface
    reaches, grown by `grow`, among those not yet `marked` and inside its bounds' sub-voxels
    sub_lo..sub_hi (a plane's test alone would mark its plane past its edges), the tests
    made)."""
    out = np.uint64(0)
    made = 0
    x0, y0, z0 = ix * sub, iy * sub, iz * sub
    for sz in range(max(sub_lo[2] - z0, 0), min(sub_hi[2] - z0, sub - 1) + 1):
        for sy in range(max(sub_lo[1] - y0, 0), min(sub_hi[1] - y0, sub - 1) + 1):
            for sx in range(max(sub_lo[0] - x0, 0), min(sub_hi[0] - x0, sub - 1) + 1):
                bit = np.uint64(1) << np.uint64(sx + sub * (sy + sub * sz))
                if marked & bit:
                    continue
                made += 1
                if _reached(u, x0 + sx, y0 + sy, z0 + sz, glo, part, grow, geo):
                    out |= bit
    return out, made


@kernel
def _reached(u, ix, iy, iz, glo, size, grow, geo):
    """`_touches` as the map tests a voxel (or sub-voxel) of size `size`: edges and cones
    included, the kinds from the scene's `geo`."""
    return _touches(
        u, ix, iy, iz, glo, size, grow, True, geo.off, geo.sph, geo.tri, geo.poly, geo.cone
    )


@kernel
def _bounds_voxels(lo, hi, u, grow, share, glo, cell, res, ijk_lo, ijk_hi):
    """The first and last voxel along each axis (into ijk_lo, ijk_hi) that object u's bounds
    reach, grown by `grow` plus `share` of a voxel, clamped to the grid."""
    for a in range(3):
        margin = grow + share * cell[a]
        i0 = int(math.floor((lo[u, a] - margin - glo[a]) / cell[a]))
        i1 = int(math.floor((hi[u, a] + margin - glo[a]) / cell[a]))
        ijk_lo[a] = min(max(i0, 0), res[a] - 1)
        ijk_hi[a] = min(max(i1, 0), res[a] - 1)


@kernel
def _touches(u, ix, iy, iz, glo, cell, grow, edges, off, sph, tri, poly, cone):
    """Conservative voxel-object overlap, the voxel grown by `grow` on every side (kinds
    passed as None are compiled out, cones then kept by their bounds); `edges`: a triangle
    is tested on its edges' axes too, not its plane alone. The grid passes neither edges nor
    cones: its resolution and the forecast that prices it (`structure_cost.grid_forecast`)
    were fitted to the plane and the bounds (balls_s2's floor quads then halved their
    references and its build chose 23x23 voxels against the forecast's 16x16)."""
    c0 = glo[0] + (ix + 0.5) * cell[0]
    c1 = glo[1] + (iy + 0.5) * cell[1]
    c2 = glo[2] + (iz + 0.5) * cell[2]
    h0 = 0.5 * cell[0] * (1.0 + 1e-6) + grow
    h1 = 0.5 * cell[1] * (1.0 + 1e-6) + grow
    h2 = 0.5 * cell[2] * (1.0 + 1e-6) + grow
    if sph is not None and u < off[1]:
        dd = 0.0
        for a in range(3):
            c = c0 if a == 0 else (c1 if a == 1 else c2)
            h = h0 if a == 0 else (h1 if a == 1 else h2)
            e = abs(sph[u, a] - c) - h
            if e > 0.0:
                dd += e * e
        r = sph[u, 3] * (1.0 + 1e-9)
        if dd > r * r:
            return False
        # A voxel wholly inside the sphere holds none of its surface.
        far = 0.0
        for a in range(3):
            c = c0 if a == 0 else (c1 if a == 1 else c2)
            h = h0 if a == 0 else (h1 if a == 1 else h2)
            e = abs(sph[u, a] - c) + h
            far += e * e
        r_in = sph[u, 3] * (1.0 - 1e-9)
        return far >= r_in * r_in
    if tri is not None and u < off[2]:
        i = u - off[1]
        nx, ny, nz = triangle_normal(tri, i)
        return _plane_straddles(
            tri[i, 0],
            tri[i, 1],
            tri[i, 2],
            nx,
            ny,
            nz,
            c0,
            c1,
            c2,
            h0,
            h1,
            h2,
        ) and not (edges and _edges_separate(tri, i, c0, c1, c2, h0, h1, h2))
    if poly is not None and u < off[3]:
        i = u - off[2]
        return _plane_straddles(
            poly[i, 0],
            poly[i, 1],
            poly[i, 2],
            poly[i, 3],
            poly[i, 4],
            poly[i, 5],
            c0,
            c1,
            c2,
            h0,
            h1,
            h2,
        )
    if cone is not None and u < off[4]:
        i = u - off[3]
        return _axis_within(cone, i, c0, c1, c2, math.sqrt(h0 * h0 + h1 * h1 + h2 * h2))
    return True


@kernel
def _edges_separate(tri, i, c0, c1, c2, h0, h1, h2):
    """Whether an axis across one of triangle i's edges and one of the box's axes separates
    the triangle from the box (centre c, half sides h): the nine axes its bounds and plane
    leave to the separating-axis test (Akenine-Moller's triangle-box overlap). A slanted
    triangle's plane crosses every voxel along the diagonal of its bounds; these cut it to
    the voxels along the triangle. The margin, far above round-off, keeps the test
    conservative."""
    ax, ay, az = tri[i, 0] - c0, tri[i, 1] - c1, tri[i, 2] - c2  # the corners from the centre
    bx, by, bz = ax + tri[i, 3], ay + tri[i, 4], az + tri[i, 5]
    cx, cy, cz = ax + tri[i, 6], ay + tri[i, 7], az + tri[i, 8]
    size = abs(ax) + abs(ay) + abs(az) + abs(c0) + abs(c1) + abs(c2)
    for edge in range(3):
        if edge == 0:
            ex, ey, ez = tri[i, 3], tri[i, 4], tri[i, 5]
        elif edge == 1:
            ex, ey, ez = tri[i, 6] - tri[i, 3], tri[i, 7] - tri[i, 4], tri[i, 8] - tri[i, 5]
        else:
            ex, ey, ez = tri[i, 6], tri[i, 7], tri[i, 8]
        for axis in range(3):  # the box's axis `axis` crossed with the edge
            if axis == 0:
                px, py, pz = 0.0, -ez, ey
            elif axis == 1:
                px, py, pz = ez, 0.0, -ex
            else:
                px, py, pz = -ey, ex, 0.0
            pa = px * ax + py * ay + pz * az
            pb = px * bx + py * by + pz * bz
            pc = px * cx + py * cy + pz * cz
            reach = abs(px) * h0 + abs(py) * h1 + abs(pz) * h2
            margin = 1e-9 * reach + 1e-12 * (abs(px) + abs(py) + abs(pz)) * size
            if min(pa, pb, pc) > reach + margin or max(pa, pb, pc) < -reach - margin:
                return True
    return False


@kernel
def _axis_within(cone, i, c0, c1, c2, half_diagonal):
    """Whether cone i's axis segment comes within its largest radius of the box (centre c,
    half diagonal given): its surface lies within that radius of the axis, so a box farther
    holds none of it."""
    bx, by, bz = cone[i, 0], cone[i, 1], cone[i, 2]
    dx, dy, dz, length = cone[i, 3], cone[i, 4], cone[i, 5], cone[i, 6]
    s = min(max((c0 - bx) * dx + (c1 - by) * dy + (c2 - bz) * dz, 0.0), length)
    qx, qy, qz = bx + s * dx - c0, by + s * dy - c1, bz + s * dz - c2
    widest = max(cone[i, 7], cone[i, 7] + cone[i, 8] * length)
    reach = (widest + half_diagonal) * (1.0 + 1e-9) + 1e-12 * (abs(bx) + abs(by) + abs(bz) + length)
    return qx * qx + qy * qy + qz * qz <= reach * reach


@kernel
def _plane_straddles(px, py, pz, nx, ny, nz, c0, c1, c2, h0, h1, h2):
    dist = nx * (c0 - px) + ny * (c1 - py) + nz * (c2 - pz)
    reach = abs(nx) * h0 + abs(ny) * h1 + abs(nz) * h2
    return abs(dist) <= reach * (1.0 + 1e-9) + 1e-12 * (abs(px) + abs(py) + abs(pz))
