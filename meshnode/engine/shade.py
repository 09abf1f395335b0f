"""Surface normals at a hit and the Whitted spawn rules (DESIGN.md 4), as scalar kernels."""

import math

from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from meshnode.engine.intersect import hit_triangle, triangle_normal
from meshnode.engine.jit import inline, leaf


@leaf
def normals(u, px, py, pz, ox, oy, oz, dx, dy, dz, off, sph, tri, tri_n, poly, cone):
    """Front (outward) geometric normal and shading normal at a hit on local object u."""
    if sph is not None and u < off[1]:
        # Normalise by the actual distance, not the radius: a hit point off the surface by
        # round-off must still give a unit normal.
        nx = px - sph[u, 0]
        ny = py - sph[u, 1]
        nz = pz - sph[u, 2]
        ln = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
        nx *= ln
        ny *= ln
        nz *= ln
        return nx, ny, nz, nx, ny, nz
    if tri is not None and u < off[2]:
        i = u - off[1]
        gx, gy, gz = triangle_normal(tri, i)
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


LN2 = 0.6931471805599453
SQRT2 = 1.4142135623730951


@intrinsic
def _bits(typingctx, x):
    """The float64 x's bits as an int64, in a register (no store and load)."""
    if x != types.float64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, b):
    """The float64 whose bits are the int64 b, in a register."""
    if b != types.int64:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@inline
def power(c, shine):
    """c ** shine for c in (0, 1] and shine > 0: the Phong highlight, without loops or calls.
    A libm pow in the shading loop made numba's code for the whole ray loop slower (balls
    traced in 0.75 s instead of 0.55 s: register spills across the call), so the power is
    exp(shine * ln c) from series, with the float's exponent read from its bits. Relative
    error below 1e-13. Its branches are selects once inlined in a loop (`phongs`)."""
    if c >= 1.0:
        return 1.0
    if c < 1e-300:
        return 0.0
    # c = m * 2^e with m in [1, 2), then m in [sqrt(1/2), sqrt(2)).
    b = _bits(c)
    e = ((b >> 52) & 0x7FF) - 1023
    m = _from_bits((b & 0xFFFFFFFFFFFFF) | (1023 << 52))
    if m > SQRT2:
        m *= 0.5
        e += 1
    # ln m = 2 atanh z, z = (m - 1) / (m + 1), |z| < 0.172: series to z^23.
    z = (m - 1.0) / (m + 1.0)
    w = z * z
    s = 1 / 23
    s = s * w + 1 / 21
    s = s * w + 1 / 19
    s = s * w + 1 / 17
    s = s * w + 1 / 15
    s = s * w + 1 / 13
    s = s * w + 1 / 11
    s = s * w + 1 / 9
    s = s * w + 1 / 7
    s = s * w + 1 / 5
    s = s * w + 1 / 3
    s = s * w + 1.0
    y = shine * (2.0 * z * s + e * LN2)
    if y < -708.0:
        return 0.0
    # exp y = 2^n e^r with |r| <= ln2 / 2: Taylor to r^17.
    n = int(math.floor(y * (1.0 / LN2) + 0.5))
    r = y - n * LN2
    p = 1 / 355687428096000
    p = p * r + 1 / 20922789888000
    p = p * r + 1 / 1307674368000
    p = p * r + 1 / 87178291200
    p = p * r + 1 / 6227020800
    p = p * r + 1 / 479001600
    p = p * r + 1 / 39916800
    p = p * r + 1 / 3628800
    p = p * r + 1 / 362880
    p = p * r + 1 / 40320
    p = p * r + 1 / 5040
    p = p * r + 1 / 720
    p = p * r + 1 / 120
    p = p * r + 1 / 24
    p = p * r + 1 / 6
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    return p * _from_bits((n + 1023) << 52)


@leaf
def phong(c, shine):
    """`power` as a call of its own: one highlight at a time (a ray leaving the node)."""
    return power(c, shine)


@leaf
def phongs(c, shine, out, n):
    """out[k] = `power`(c[k], shine[k]) for k < n: a batch's highlights in one loop that
    LLVM runs in vector code, each lane the scalar arithmetic. One at a time they were a
    chain of some 30 dependent multiply-adds a shadow ray (teapot: a tenth of its time)."""
    for k in range(n):
        out[k] = power(c[k], shine[k])
