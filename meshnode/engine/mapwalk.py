"""A ray's walk along the scene's occupancy map (`meshnode.engine.occupancy`): where the
first occupied voxel ahead of it lies whose marked sub-voxels its path may cross, or that none
does. An object-space node walks it for every segment leaving its box (`trace`) and for every
eye ray it routes (`routing`).

Most steps of a walk from a box's exit go a voxel at a time: past occupied voxels whose marked
sub-voxels the path misses, and through empty voxels beside them (a ray leaving a box on
rings, 3x3 cells: 7.5 steps, 2.2 of them past occupied voxels and 2.5 through lone empty
ones). So the walk keeps the current voxel's walls from step to step, and tests an occupied
voxel's sub-voxels on the ray in sub-voxel units, the path's whole span first: the same walks
took 25% less time on rings and balls (`python -m bench.walks`).
"""

import math

from meshnode.engine.counters import OCC_STEPS, OCC_WALKS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.occupancy import SUB, SUB_RANGES
from meshnode.engine.traverse import box_span

INF = math.inf
# A path's sub-voxels are taken this far (in sub-voxels) around its end points: far above the
# round-off of o + t d (about 1e-16 of |o| + |t d|, 3e-11 sub-voxels of a 64^3 map for an
# origin a thousand boxes away).
SUB_MARGIN = 1e-3


@leaf
def _index(o, d, t, lo, inv, i0, i1):
    """Voxel index along one axis of the point at t, clamped to [i0, i1] (a multiply by the
    voxel's reciprocal size: a step's division was on its critical path)."""
    return min(max(int(math.floor((o + t * d - lo) * inv)), i0), i1)


@inline
def _sub_range(fa, fb):
    """The sub-voxel coordinates along one axis a path between the points fa and fb (in
    sub-voxels from the voxel's low wall) may cross: their span widened by SUB_MARGIN and
    clamped into the voxel."""
    a = min(max(min(fa, fb) - SUB_MARGIN, 0.0), SUB - 1.0)
    b = min(max(max(fa, fb) + SUB_MARGIN, 0.0), SUB - 1.0)
    return int(a), int(b)


@inline
def _span_bits(ax, bx, ay, by, az, bz):
    """The bits of the sub-voxels a path between two points (per axis a, b, in sub-voxels
    from the voxel's low walls) may cross (`_sub_range` on each axis)."""
    x0, x1 = _sub_range(ax, bx)
    y0, y1 = _sub_range(ay, by)
    z0, z1 = _sub_range(az, bz)
    return SUB_RANGES[0, x0, x1] & SUB_RANGES[1, y0, y1] & SUB_RANGES[2, z0, z1]


@inline
def _path_meets(mask, ax, ay, az, bx, by, bz):
    """Whether the path between two points (`_span_bits`) may cross a sub-voxel of `mask`:
    its whole span first, which most paths past an occupied voxel miss, then the span of
    each half, nearer the path's own sub-voxels."""
    if (mask & _span_bits(ax, bx, ay, by, az, bz)) == 0:
        return False
    mx, my, mz = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
    if (mask & _span_bits(ax, mx, ay, my, az, mz)) != 0:
        return True
    return (mask & _span_bits(mx, bx, my, by, mz, bz)) != 0


@inline
def _wall(o, lo, cell, r, i, up):
    """t where the ray (origin o, 1 / direction r along the axis) reaches the wall of voxel
    i it leaves by (the high one going up the axis); inf when it does not move along it."""
    if r == INF:
        return INF
    return (lo + (i + up) * cell - o) * r


@leaf
def first_occupied(
    ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, t1, lo, cell, res, clear, fine, counters
):
    """t where the ray enters the first occupied voxel between t0 and t1 (t0 itself when it
    starts in one) whose marked sub-voxels its path may cross (`fine`; empty: every occupied
    voxel), inf when every voxel it crosses there is empty. rx, ry, rz are the reciprocal
    direction (inf for 0); each step (out of one voxel, or of the empty cube the ray's way
    from it, `Occupancy`) counts as an occupancy step. With an inner map (`Occupancy`) the
    ray walks it where it crosses its box and the outer map before and after."""
    counters[OCC_WALKS] += 1
    ray = (ox, oy, oz, dx, dy, dz, rx, ry, rz)
    if res.shape[0] == 3:
        return _walk(*ray, t0, t1, lo, cell, res, 0, clear, fine, 0, counters)
    i0, i1 = box_span(ox, oy, oz, rx, ry, rz, t0, t1, *_inner_box(lo, cell, res))
    if not i0 <= i1:  # the inner box missed
        return _walk(*ray, t0, t1, lo, cell, res, 0, clear, fine, 0, counters)
    if t0 < i0:  # the outer map up to the inner box (a voxel met at its wall: the inner's)
        t = _walk(*ray, t0, i0, lo, cell, res, 0, clear, fine, 0, counters)
        if t < i0:
            return t
    outer = res[0] * res[1] * res[2]
    t = _walk(*ray, i0, i1, lo, cell, res, 3, clear, fine, outer, counters)
    if t < INF or not i1 < t1:
        return t
    return _walk(*ray, i1, t1, lo, cell, res, 0, clear, fine, 0, counters)


@inline
def _inner_box(lo, cell, res):
    """The inner map's box as `box_span` takes it (lo, then hi, per axis)."""
    return (
        lo[3],
        lo[4],
        lo[5],
        lo[3] + res[3] * cell[3],
        lo[4] + res[4] * cell[4],
        lo[5] + res[5] * cell[5],
    )


@leaf
def _walk(
    ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, t1, lo, cell, res, at, clear, fine, base, counters
):
    """`first_occupied` on one map: the one whose corner, voxel size and voxels per axis are
    lo, cell and res from index `at` (0 the outer, 3 the inner), its voxels from `base` in
    clear and fine."""
    nx, ny, nz = res[at], res[at + 1], res[at + 2]
    lx, ly, lz = lo[at], lo[at + 1], lo[at + 2]
    cx, cy, cz = cell[at], cell[at + 1], cell[at + 2]
    qx, qy, qz = 1.0 / cx, 1.0 / cy, 1.0 / cz
    ix = _index(ox, dx, t0, lx, qx, 0, nx - 1)
    iy = _index(oy, dy, t0, ly, qy, 0, ny - 1)
    iz = _index(oz, dz, t0, lz, qz, 0, nz - 1)
    row = clear[(1 if dx < 0.0 else 0) + (2 if dy < 0.0 else 0) + (4 if dz < 0.0 else 0)]
    ux, uy, uz = int(dx > 0.0), int(dy > 0.0), int(dz > 0.0)
    sx, sy, sz = 2 * ux - 1, 2 * uy - 1, 2 * uz - 1
    # the ray in sub-voxels from the map's corner (g + t h), for occupied voxels' tests
    gx, gy, gz = (ox - lx) * qx * SUB, (oy - ly) * qy * SUB, (oz - lz) * qz * SUB
    hx, hy, hz = dx * qx * SUB, dy * qy * SUB, dz * qz * SUB
    t = t0
    found = t0  # non-finite arithmetic: skip nothing
    steps = 0
    # the current voxel's walls ahead: a step of one voxel moves only its axis's
    tx, ty, tz = (
        _wall(ox, lx, cx, rx, ix, ux),
        _wall(oy, ly, cy, ry, iy, uy),
        _wall(oz, lz, cz, rz, iz, uz),
    )
    # Each step leaves the voxel or cube it was in along the ray: at most nx + ny + nz of
    # them (the bound also stops a ray whose arithmetic went non-finite).
    for _ in range(nx + ny + nz + 3):
        steps += 1
        v = base + ix + nx * (iy + ny * iz)
        k = row[v]
        if k <= 1:  # occupied (0), or empty with an occupied voxel beside it the ray's way
            t_end = min(tx, min(ty, tz))
            if k == 0:
                if fine.shape[0] == 0:
                    found = t
                    break
                te = min(t_end, t1)
                if not (te >= t and te - t < INF):
                    found = t
                    break
                bx, by, bz = ix * SUB, iy * SUB, iz * SUB
                if _path_meets(
                    fine[v],
                    gx + t * hx - bx,
                    gy + t * hy - by,
                    gz + t * hz - bz,
                    gx + te * hx - bx,
                    gy + te * hy - by,
                    gz + te * hz - bz,
                ):
                    found = t
                    break
            t = t_end  # its marked sub-voxels lie off the ray's way: step out of it
            if t > t1:
                found = INF
                break
            if not t >= t0:
                break
            if t == tx:
                ix += sx
                tx = _wall(ox, lx, cx, rx, ix, ux)
            elif t == ty:
                iy += sy
                ty = _wall(oy, ly, cy, ry, iy, uy)
            else:
                iz += sz
                tz = _wall(oz, lz, cz, rz, iz, uz)
        else:
            r = k - 1  # the cube reaches r voxels on from this one, the ray's way on each axis
            x0, x1 = (ix, min(ix + r, nx - 1)) if ux else (max(ix - r, 0), ix)
            y0, y1 = (iy, min(iy + r, ny - 1)) if uy else (max(iy - r, 0), iy)
            z0, z1 = (iz, min(iz + r, nz - 1)) if uz else (max(iz - r, 0), iz)
            ex = _wall(ox, lx, cx, rx, x1 if ux else x0, ux)
            ey = _wall(oy, ly, cy, ry, y1 if uy else y0, uy)
            ez = _wall(oz, lz, cz, rz, z1 if uz else z0, uz)
            t = min(ex, min(ey, ez))
            if t > t1:
                found = INF
                break
            if not t >= t0:
                break
            # Out through the wall reached first; along the other axes the point is still
            # inside the cube's slab (clamped against round-off), so every step leaves it.
            if t == ex:
                ix = x1 + 1 if ux else x0 - 1
                if y0 < y1:
                    iy = _index(oy, dy, t, ly, qy, y0, y1)
                if z0 < z1:
                    iz = _index(oz, dz, t, lz, qz, z0, z1)
            elif t == ey:
                iy = y1 + 1 if uy else y0 - 1
                if x0 < x1:
                    ix = _index(ox, dx, t, lx, qx, x0, x1)
                if z0 < z1:
                    iz = _index(oz, dz, t, lz, qz, z0, z1)
            else:
                iz = z1 + 1 if uz else z0 - 1
                if x0 < x1:
                    ix = _index(ox, dx, t, lx, qx, x0, x1)
                if y0 < y1:
                    iy = _index(oy, dy, t, ly, qy, y0, y1)
            tx, ty, tz = (
                _wall(ox, lx, cx, rx, ix, ux),
                _wall(oy, ly, cy, ry, iy, uy),
                _wall(oz, lz, cz, rz, iz, uz),
            )
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            found = INF
            break
    counters[OCC_STEPS] += steps
    return found


@inline
def work_start(
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    rx,
    ry,
    rz,
    t_min,
    t_max,
    scene_lo,
    scene_hi,
    lo,
    cell,
    res,
    clear,
    fine,
    counters,
    t_from,
):
    """(t_min moved on to the first occupied voxel the ray meets inside the scene's box, or
    t_min itself where it misses the box or meets none; where it crosses the box through
    empty voxels only, a t just past its exit from the box, inf where it misses the box,
    else -inf). rx, ry, rz: 1 / direction (inf for 0). A segment resumed past the box, or
    missing it, is one a node's kernel ends at once (escaped, or its light reached), where
    it would walk the box to end it. `t_from`: a t before which the ray meets no occupied
    voxel (`sightlines`; -inf if none is known), where the walk may start."""
    s0, s1 = box_span(
        ox,
        oy,
        oz,
        rx,
        ry,
        rz,
        t_min,
        t_max,
        scene_lo[0],
        scene_lo[1],
        scene_lo[2],
        scene_hi[0],
        scene_hi[1],
        scene_hi[2],
    )
    if s0 > s1:
        return t_min, INF
    if t_from >= s1:
        t = INF
    else:
        t0 = max(s0, t_from)
        t = first_occupied(
            ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, s1, lo, cell, res, clear, fine, counters
        )
    if t == INF:
        return t_min, past_box(s1)
    return (t if t > t_min else t_min), -INF


@inline
def past_box(s1):
    """A t just past s1, a ray's exit from the scene's box (`work_start`)."""
    return s1 + abs(s1) * 1e-9 + 1e-300


@kernel
def skip_empty(rays, scene_lo, scene_hi, lo, cell, res, clear, fine, counters):
    """Move each ray's t_min on to the first occupied voxel it meets inside the scene's box
    (`work_start`): an eye ray then goes first to the node whose cell holds the space where
    its work starts, not to the one whose cell it only crosses on the way in (the same
    segments a node makes when it passes a segment on)."""
    for i in range(rays.shape[0]):
        r = rays[i]
        ox, oy, oz = r.o[0], r.o[1], r.o[2]
        dx, dy, dz = r.d[0], r.d[1], r.d[2]
        rx = 1.0 / dx if dx != 0.0 else INF
        ry = 1.0 / dy if dy != 0.0 else INF
        rz = 1.0 / dz if dz != 0.0 else INF
        r.t_min = work_start(
            ox,
            oy,
            oz,
            dx,
            dy,
            dz,
            rx,
            ry,
            rz,
            r.t_min,
            r.t_max,
            scene_lo,
            scene_hi,
            lo,
            cell,
            res,
            clear,
            fine,
            counters,
            -INF,
        )[0]
