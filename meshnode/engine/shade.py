"""Surface normals at a hit and the Whitted spawn rules (DESIGN.md 4), as scalar kernels."""

import math

from meshnode.engine.intersect import hit_triangle
from meshnode.engine.jit import leaf


@leaf
def normals(u, px, py, pz, ox, oy, oz, dx, dy, dz, off, sph, tri, tri_n, poly, cone):
    """Front (outward) geometric normal and shading normal at a hit on local object u."""
    if sph is not None and u < off[1]:
        r = sph[u, 3]
        nx = (px - sph[u, 0]) / r
        ny = (py - sph[u, 1]) / r
        nz = (pz - sph[u, 2]) / r
        return nx, ny, nz, nx, ny, nz
    if tri is not None and u < off[2]:
        i = u - off[1]
        gx, gy, gz = tri[i, 9], tri[i, 10], tri[i, 11]
        if tri_n is not None:
            # Interpolate vertex normals with the barycentrics of this very hit.
            _, bu, bv = hit_triangle(tri, i, ox, oy, oz, dx, dy, dz, -math.inf, math.inf)
            bw = 1.0 - bu - bv
            sx = bw * tri_n[i, 0] + bu * tri_n[i, 3] + bv * tri_n[i, 6]
            sy = bw * tri_n[i, 1] + bu * tri_n[i, 4] + bv * tri_n[i, 7]
            sz = bw * tri_n[i, 2] + bu * tri_n[i, 5] + bv * tri_n[i, 8]
            ln = math.sqrt(sx * sx + sy * sy + sz * sz)
            if ln > 0.0:
                return gx, gy, gz, sx / ln, sy / ln, sz / ln
        return gx, gy, gz, gx, gy, gz
    if poly is not None and u < off[3]:
        i = u - off[2]
        return poly[i, 3], poly[i, 4], poly[i, 5], poly[i, 3], poly[i, 4], poly[i, 5]
    if cone is None:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 1.0
    i = u - off[3]
    ax, ay, az = cone[i, 3], cone[i, 4], cone[i, 5]
    vx, vy, vz = px - cone[i, 0], py - cone[i, 1], pz - cone[i, 2]
    s = vx * ax + vy * ay + vz * az
    kr = cone[i, 8] * (cone[i, 7] + cone[i, 8] * s)
    nx = vx - s * ax - kr * ax
    ny = vy - s * ay - kr * ay
    nz = vz - s * az - kr * az
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx / ln, ny / ln, nz / ln, nx / ln, ny / ln, nz / ln


@leaf
def refract(dx, dy, dz, nx, ny, nz, eta):
    """Snell's law with n facing the incoming ray; returns ok=False on total internal reflection."""
    c1 = -(dx * nx + dy * ny + dz * nz)
    k = 1.0 - eta * eta * (1.0 - c1 * c1)
    if k < 0.0:
        return False, 0.0, 0.0, 0.0
    f = eta * c1 - math.sqrt(k)
    tx = eta * dx + f * nx
    ty = eta * dy + f * ny
    tz = eta * dz + f * nz
    ln = math.sqrt(tx * tx + ty * ty + tz * tz)
    return True, tx / ln, ty / ln, tz / ln
