"""Which voxels each object touches: the kernels that fill the grid's voxel references.

A box-range test alone puts a large sphere or a slanted triangle in every voxel of its bounds;
these kernels keep only the voxels an object's surface can reach (box-sphere distance, plane
straddles box), conservatively. Kept apart from `grid` (resolution, storage, the build that
calls `voxel_refs` to count and then to fill): overlap tests are geometry, not grid policy.
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
    for u in range(lo.shape[0]):
        ijk_lo = np.empty(3, np.int64)
        ijk_hi = np.empty(3, np.int64)
        for a in range(3):
            tol = 1e-7 * cell[a]
            i0 = int(math.floor((lo[u, a] - tol - glo[a]) / cell[a]))
            i1 = int(math.floor((hi[u, a] + tol - glo[a]) / cell[a]))
            ijk_lo[a] = min(max(i0, 0), res[a] - 1)
            ijk_hi[a] = min(max(i1, 0), res[a] - 1)
        for iz in range(ijk_lo[2], ijk_hi[2] + 1):
            for iy in range(ijk_lo[1], ijk_hi[1] + 1):
                for ix in range(ijk_lo[0], ijk_hi[0] + 1):
                    if not _touches(u, ix, iy, iz, glo, cell, geo.off, geo.sph, geo.tri, geo.poly):
                        continue
                    v = ix + nx * (iy + ny * iz)
                    if fill:
                        refs[starts[v]] = u
                        starts[v] += 1
                    else:
                        counts[v] += 1


@kernel
def _touches(u, ix, iy, iz, glo, cell, off, sph, tri, poly):
    """Conservative voxel-object overlap for the kinds that have a cheap exact-enough test
    (kinds passed as None are compiled out)."""
    c0 = glo[0] + (ix + 0.5) * cell[0]
    c1 = glo[1] + (iy + 0.5) * cell[1]
    c2 = glo[2] + (iz + 0.5) * cell[2]
    h0 = 0.5 * cell[0] * (1.0 + 1e-6)
    h1 = 0.5 * cell[1] * (1.0 + 1e-6)
    h2 = 0.5 * cell[2] * (1.0 + 1e-6)
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
        )
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
    return True


@kernel
def _plane_straddles(px, py, pz, nx, ny, nz, c0, c1, c2, h0, h1, h2):
    dist = nx * (c0 - px) + ny * (c1 - py) + nz * (c2 - pz)
    reach = abs(nx) * h0 + abs(ny) * h1 + abs(nz) * h2
    return abs(dist) <= reach * (1.0 + 1e-9) + 1e-12 * (abs(px) + abs(py) + abs(pz))
