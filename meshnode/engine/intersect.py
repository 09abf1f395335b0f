"""Ray-object tests, one function per primitive kind.

Each returns the ray parameter of the first *visible* hit in (t_lo, t_hi), or inf. Rays leaving
a surface carry its gid; `self_hit` then asks for the one root that is not the origin itself,
which removes self-intersection without a scene-sized epsilon (planar objects are simply
skipped by the caller).

Table layouts (built by `tables.py`):
- sphere row: cx cy cz r vis (vis +1 outside visible, -1 inside, 0 both sides)
- triangle row: v0(3) e1(3) e2(3)  (the unit geometric normal made at a hit: `triangle_normal`)
- polygon row: p0(3) n(3) vmin band_scale cu cv in2 out2 ; info row: start count axis_u
  axis_v first_band bands ; 2-D vertices relative to p0 ; band table: offsets of each band's
  edge list, then the lists (an edge named by the row of its end vertex)
- cone row: b(3) a(3) L r0 k vis   (a unit axis, radius r0 + k s for s in [0, L])
"""

import math

from meshnode.engine.jit import inline, leaf
from meshnode.engine.tables import (
    POLY_BAND_SCALE,
    POLY_CU,
    POLY_CV,
    POLY_IN2,
    POLY_OUT2,
    POLY_VMIN,
)

INF = math.inf
# Barycentric slack of every triangle test. A ray through an edge that two triangles share has
# a barycentric within a few ulps of 0 in both, and Moller-Trumbore's rounding can put it just
# outside both: the ray leaks through a closed mesh (5% of rays aimed at a box's corners and
# edges did, at every scale: tests/test_surface_properties.py). Widening each triangle by this
# much closes those cracks; barycentrics are relative, so the slack is the same at every scale
# and moves a silhouette edge by a billionth of the triangle's size.
EDGE_SLACK = 1e-9


@leaf
def hit_sphere(s, i, ox, oy, oz, dx, dy, dz, t_lo, t_hi, self_hit):
    """Nearest visible root of |o + t d - c| = r for a unit direction d."""
    wx = ox - s[i, 0]
    wy = oy - s[i, 1]
    wz = oz - s[i, 2]
    b = wx * dx + wy * dy + wz * dz
    vis = s[i, 4]
    if self_hit:
        # The origin lies on the sphere: the other root is -2b, always an exit (inside) hit.
        t = -2.0 * b
        if vis <= 0.0 and t_lo < t < t_hi:
            return t
        return INF
    r = s[i, 3]
    c = wx * wx + wy * wy + wz * wz - r * r
    disc = b * b - c
    if disc < 0.0:
        return INF
    h = math.sqrt(disc)
    # Stable roots: q has no cancellation, c / q gives the other.
    q = -(b + h) if b >= 0.0 else -(b - h)
    if q == 0.0:
        return INF
    t0 = q
    t1 = c / q
    if t1 < t0:
        t0, t1 = t1, t0
    # t0 enters the sphere (outside side), t1 leaves it (inside side).
    if vis >= 0.0 and t_lo < t0 < t_hi:
        return t0
    if vis <= 0.0 and t_lo < t1 < t_hi:
        return t1
    return INF


@inline
def hit_triangle(tr, i, ox, oy, oz, dx, dy, dz, t_lo, t_hi):
    """Moller-Trumbore, two-sided, edges widened by EDGE_SLACK; returns t, barycentrics u, v."""
    e1x, e1y, e1z = tr[i, 3], tr[i, 4], tr[i, 5]
    e2x, e2y, e2z = tr[i, 6], tr[i, 7], tr[i, 8]
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return INF, 0.0, 0.0
    inv = 1.0 / det
    sx = ox - tr[i, 0]
    sy = oy - tr[i, 1]
    sz = oz - tr[i, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -EDGE_SLACK or u > 1.0 + EDGE_SLACK:
        return INF, 0.0, 0.0
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < -EDGE_SLACK or u + v > 1.0 + EDGE_SLACK:
        return INF, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if t_lo < t < t_hi:
        return t, u, v
    return INF, 0.0, 0.0


@inline
def triangle_normal(tr, i):
    """Unit geometric normal e1 x e2 of triangle row i; zero for a zero-area triangle (a
    patch pole), never hit. Made where needed (a hit, a voxel overlap) rather than stored:
    the hit test then reads a 72-byte row, not 96 (the million-triangle tetrahedron's
    eye rays walked alone 203 -> 196 ns a ray in a copy of the walk)."""
    e1x, e1y, e1z = tr[i, 3], tr[i, 4], tr[i, 5]
    e2x, e2y, e2z = tr[i, 6], tr[i, 7], tr[i, 8]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    length = math.sqrt(nx * nx + ny * ny + nz * nz)
    if length > 0.0:
        return nx / length, ny / length, nz / length
    return 0.0, 0.0, 0.0


@leaf
def hit_polygon(pl, info, v2, band, i, ox, oy, oz, dx, dy, dz, t_lo, t_hi):
    """Plane hit then an even-odd crossing test in 2-D: any vertex count, concave allowed.

    A polygon with bands (info column 5 > 0) tests only the edges listed for the band of v the
    hit lies in, not all of them (a gear face has 144): the same per-edge arithmetic on the
    edges that can cross, so the same answer (Haines, "Point in Polygon Strategies"). Before
    any edge, a point in the polygon's inner disc is a hit and one beyond its outer disc a
    miss (`tables.polygon_discs`): the answer the edges would give, most gear-face hits
    without them."""
    nx, ny, nz = pl[i, 3], pl[i, 4], pl[i, 5]
    dn = nx * dx + ny * dy + nz * dz
    if dn == 0.0:
        return INF
    # Work relative to p0 so far-from-origin scenes keep their precision.
    wx = pl[i, 0] - ox
    wy = pl[i, 1] - oy
    wz = pl[i, 2] - oz
    t = (nx * wx + ny * wy + nz * wz) / dn
    if not (t_lo < t < t_hi):
        return INF
    rel = (t * dx - wx, t * dy - wy, t * dz - wz)
    au = info[i, 2]
    av = info[i, 3]
    pu = rel[0] if au == 0 else (rel[1] if au == 1 else rel[2])
    pv = rel[0] if av == 0 else (rel[1] if av == 1 else rel[2])
    cu = pu - pl[i, POLY_CU]
    cv = pv - pl[i, POLY_CV]
    d2 = cu * cu + cv * cv
    if d2 < pl[i, POLY_IN2]:
        return t
    if d2 > pl[i, POLY_OUT2]:
        return INF
    start = info[i, 0]
    count = info[i, 1]
    bands = info[i, 5]
    inside = False
    if bands == 0:
        ju = v2[start + count - 1, 0]
        jv = v2[start + count - 1, 1]
        for k in range(start, start + count):
            iu = v2[k, 0]
            iv = v2[k, 1]
            if crosses(iu, iv, ju, jv, pu, pv):
                inside = not inside
            ju = iu
            jv = iv
        return t if inside else INF
    f = (pv - pl[i, POLY_VMIN]) * pl[i, POLY_BAND_SCALE]
    if f < 0.0:  # below the lowest vertex: no edge crosses
        return INF
    b = info[i, 4] + (int(f) if f < bands else bands - 1)
    for e in range(band[b], band[b + 1]):
        k = band[e]
        j = k - 1 if k > start else start + count - 1
        if crosses(v2[k, 0], v2[k, 1], v2[j, 0], v2[j, 1], pu, pv):
            inside = not inside
    return t if inside else INF


@leaf
def crosses(iu, iv, ju, jv, pu, pv):
    """Whether the edge (i, j) crosses the line v = pv to the right of pu (half-open in v, so
    a vertex on the line counts once)."""
    if (iv > pv) == (jv > pv):
        return False
    return pu < (ju - iu) * (pv - iv) / (jv - iv) + iu


@leaf
def hit_cone(cn, i, ox, oy, oz, dx, dy, dz, t_lo, t_hi, self_hit):
    """Open cone or cylinder: both roots of the quadric, clipped to 0 <= s <= L, visible side."""
    ax, ay, az = cn[i, 3], cn[i, 4], cn[i, 5]
    length = cn[i, 6]
    r0 = cn[i, 7]
    k = cn[i, 8]
    vis = cn[i, 9]
    wx = ox - cn[i, 0]
    wy = oy - cn[i, 1]
    wz = oz - cn[i, 2]
    ds = dx * ax + dy * ay + dz * az
    ws = wx * ax + wy * ay + wz * az
    rr = r0 + k * ws
    a = 1.0 - ds * ds * (1.0 + k * k)
    b = wx * dx + wy * dy + wz * dz - ws * ds - k * ds * rr
    c = wx * wx + wy * wy + wz * wz - ws * ws - rr * rr
    if abs(a) < 1e-14:
        if b == 0.0:
            return INF
        t0 = -c / (2.0 * b)
        t1 = INF
    else:
        disc = b * b - a * c
        if disc < 0.0:
            return INF
        h = math.sqrt(disc)
        q = -(b + h) if b >= 0.0 else -(b - h)
        t0 = q / a
        t1 = c / q if q != 0.0 else t0
        if t1 < t0:
            t0, t1 = t1, t0
    if self_hit:
        # Drop the root at the origin: keep the one farther from zero.
        if abs(t0) > abs(t1):
            t1 = INF
        else:
            t0 = t1
            t1 = INF
    for j in range(2):
        t = t0 if j == 0 else t1
        if not (t_lo < t < t_hi):
            continue
        s = ws + t * ds
        if s < 0.0 or s > length:
            continue
        if vis != 0.0:
            # Outward normal n = v_perp - k r(s) a; the ray enters from outside when d.n < 0.
            rs = r0 + k * s
            nx = wx + t * dx - s * ax - k * rs * ax
            ny = wy + t * dy - s * ay - k * rs * ay
            nz = wz + t * dz - s * az - k * rs * az
            outside = nx * dx + ny * dy + nz * dz < 0.0
            if outside != (vis > 0.0):
                continue
        return t
    return INF
