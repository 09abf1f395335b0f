"""The scene's occupancy map on an object-space node: which coarse voxels of the whole scene
any object touches (the host rasterises every object's padded bounds, `host.planning.occupancy.
occupancy_map`; each node gets the same map with its partition).

A segment leaving a node's box goes on to the node whose cell holds it; when the rest of its
path crosses only empty voxels there is nothing left to hit, and passing it on would only
send it through every cell ahead to escape or reach its light. With the map the node that
has it ends it at once (the same colour, the same count: an escaped ray or a lit shadow ray),
and a segment that does meet an occupied voxel resumes at that voxel, so the nodes whose
cells it crosses empty never see it.

Exact because the map is conservative: an object's bounds are padded before they are
rasterised, so any point of any object lies inside occupied voxels by at least the padding,
and a segment resumed at the first occupied voxel it enters misses nothing before it.

An occupied voxel also carries which of its 4x4x4 sub-voxels a surface reaches
(`Occupancy.fine`, marked as the voxels are): a walk reaching it looks at the sub-voxels its
path through the voxel may cross, and goes on past it where none is marked. A 64^3 voxel
holding a few small spheres, or a slanted triangle's edge, is mostly empty, and every ray
crossing it was passed on to meet nothing there.
"""

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from meshnode.engine.counters import OCC_STEPS, OCC_WALKS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.traverse import _region_exit, box_span
from protocols.render import EVERYWHERE

INF = math.inf
OCTANTS = 8  # rows of `Occupancy.clear`: one a ray octant
SUB = 4  # sub-voxels along each axis of a voxel (`Occupancy.fine`: 64 bits a voxel)
FINE_BYTES = 8  # a voxel's sub-voxel mask
# A path's sub-voxels are taken this far (in sub-voxels) around its end points: far above the
# round-off of o + t d (about 1e-16 of |o| + |t d|, 3e-11 sub-voxels of a 64^3 map for an
# origin a thousand boxes away).
SUB_MARGIN = 1e-3


def _sub_ranges() -> np.ndarray:
    """(3, SUB, SUB) uint64: per axis and range a..b of sub-voxel coordinates, the bits of
    every sub-voxel whose coordinate on that axis lies in a..b (bit x + SUB y + SUB^2 z)."""
    out = np.zeros((3, SUB, SUB), np.uint64)
    idx = np.arange(SUB**3)
    coord = (idx % SUB, idx // SUB % SUB, idx // SUB**2)
    for axis in range(3):
        for a in range(SUB):
            for b in range(a, SUB):
                bits = idx[(coord[axis] >= a) & (coord[axis] <= b)]
                out[axis, a, b] = np.bitwise_or.reduce(np.uint64(1) << bits.astype(np.uint64))
    return out


SUB_RANGES = _sub_ranges()


class Occupancy(NamedTuple):
    """The map as the kernels take it: box corner, voxel size, voxels per axis, and per ray
    octant (row: 1 for x, 2 for y, 4 for z where the direction is negative) and voxel (x
    fastest) the side in voxels of the largest empty cube with that voxel at its corner and
    reaching the way a ray of that octant goes (0: occupied, capped at 255): a walk through
    empty space jumps out of it in one step, as the grid's walk does through empty macro
    cells. A cube centred on the voxel (one Chebyshev distance for all rays) stops at the
    nearest object whatever side it lies on: a ray leaving a floor or a cluster upwards took
    3.4-8.2 steps to find nothing ahead (simulated 3x3, rings and teapot)."""

    lo: np.ndarray
    cell: np.ndarray
    res: np.ndarray
    clear: np.ndarray  # (8, voxels) uint8
    fine: np.ndarray  # (voxels,) uint64: an occupied voxel's marked sub-voxels; empty: none


def occupancy_arrays(lo, hi, res, bits: bytes, fine: bytes = b"") -> Occupancy:
    """The kernels' form of a map over the box lo..hi of res voxels (x, y, z), packed `bits`
    (numpy's packbits order, x fastest) and `fine`, the occupied voxels' sub-voxel masks in
    voxel order (FINE_BYTES each, little-endian; empty: none); the caller has checked the
    sizes."""
    res = np.asarray(res, np.int64)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    clear = _clear(tuple(res.tolist()), bytes(bits))
    masks = _fine(tuple(res.tolist()), bytes(bits), bytes(fine))
    return Occupancy(lo, np.maximum((hi - lo) / res, 1e-300), res, clear, masks)


@lru_cache(maxsize=4)
def _fine(res: tuple, bits: bytes, fine: bytes) -> np.ndarray:
    """`Occupancy.fine` of a packed map: every voxel's mask, the occupied ones' from `fine`
    (shared, read only, by every engine built on the map, as `_clear` is)."""
    if not fine:
        return np.zeros(0, np.uint64)
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res))).astype(bool)
    out = np.zeros(full.size, np.uint64)
    out[full] = np.frombuffer(fine, "<u8")
    return out


@lru_cache(maxsize=4)
def _clear(res: tuple, bits: bytes) -> np.ndarray:
    """`reaches` of a packed map; one array shared by every engine built on the same map
    (the kernels only read it): a node builds an engine per box it holds and the cost
    pre-pass hundreds, all on the partition's one map (tetra 3x3's pre-pass: 328 builds,
    6.2 s of its 20 s in this function when it was a Chebyshev distance in NumPy)."""
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res))).astype(bool)
    if full.all():  # one node's map (`everywhere`): nothing to skip, no kernel to load
        return np.zeros((OCTANTS, full.size), np.uint8)
    return reaches(full.reshape(res[::-1]))


@kernel
def reaches(full):
    """(8, voxels) uint8: for each ray octant (see `Occupancy`) and voxel of the (z, y, x)
    map `full`, the side of the largest empty cube with the voxel at its corner reaching
    that octant's way, capped at 255; space past the map counts as empty. Each octant is
    one sweep against its rays' way: a side is one more than the least of the seven
    neighbours' the cube's other voxels lie in (the largest-square recurrence in 3-D)."""
    nz, ny, nx = full.shape
    out = np.empty((OCTANTS, nz * ny * nx), np.uint8)
    for octant in range(OCTANTS):
        sx = -1 if octant & 1 else 1
        sy = -1 if octant & 2 else 1
        sz = -1 if octant & 4 else 1
        side = out[octant]
        for kz in range(nz):
            z = nz - 1 - kz if sz > 0 else kz
            for ky in range(ny):
                y = ny - 1 - ky if sy > 0 else ky
                for kx in range(nx):
                    x = nx - 1 - kx if sx > 0 else kx
                    at = x + nx * (y + ny * z)
                    if full[z, y, x]:
                        side[at] = 0
                        continue
                    least = 255
                    for e in range(1, 8):
                        x2 = x + sx * (e & 1)
                        y2 = y + sy * ((e >> 1) & 1)
                        z2 = z + sz * ((e >> 2) & 1)
                        if 0 <= x2 < nx and 0 <= y2 < ny and 0 <= z2 < nz:
                            least = min(least, np.int64(side[x2 + nx * (y2 + ny * z2)]))
                    side[at] = min(least + 1, 255)
    return out


def everywhere(lo, hi) -> Occupancy:
    """A map of one occupied voxel: nothing is skipped (one node, image space)."""
    return occupancy_arrays(lo, hi, *EVERYWHERE)


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
def _sub_point(ox, oy, oz, dx, dy, dz, t, lo, q, ix, iy, iz):
    """The ray's point at t in sub-voxels from the low walls of voxel (ix, iy, iz) (corner
    lo, inverse size q)."""
    return (
        ((ox + t * dx - lo[0]) * q[0] - ix) * SUB,
        ((oy + t * dy - lo[1]) * q[1] - iy) * SUB,
        ((oz + t * dz - lo[2]) * q[2] - iz) * SUB,
    )


@inline
def _half_bits(ax, bx, ay, by, az, bz):
    """The bits of the sub-voxels a path between two points (per axis a, b: `_sub_point`)
    may cross (`_sub_range` on each axis)."""
    x0, x1 = _sub_range(ax, bx)
    y0, y1 = _sub_range(ay, by)
    z0, z1 = _sub_range(az, bz)
    return SUB_RANGES[0, x0, x1] & SUB_RANGES[1, y0, y1] & SUB_RANGES[2, z0, z1]


@inline
def _path_meets(mask, ox, oy, oz, dx, dy, dz, t, t_end, lo, q, ix, iy, iz):
    """Whether the ray's path from t to t_end through voxel (ix, iy, iz) may cross a sub-voxel
    of `mask`: the path in two halves, each the sub-voxels its end points span on every
    axis (the middle point made once for both); True where its arithmetic is not finite
    (nothing skipped)."""
    if not (t_end >= t and t_end - t < INF):
        return True
    t_mid = 0.5 * (t + t_end)
    ax, ay, az = _sub_point(ox, oy, oz, dx, dy, dz, t, lo, q, ix, iy, iz)
    mx, my, mz = _sub_point(ox, oy, oz, dx, dy, dz, t_mid, lo, q, ix, iy, iz)
    bx, by, bz = _sub_point(ox, oy, oz, dx, dy, dz, t_end, lo, q, ix, iy, iz)
    met = _half_bits(ax, mx, ay, my, az, mz) | _half_bits(mx, bx, my, by, mz, bz)
    return (mask & met) != 0


@leaf
def first_occupied(
    ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, t1, lo, cell, res, clear, fine, counters
):
    """t where the ray enters the first occupied voxel between t0 and t1 (t0 itself when it
    starts in one) whose marked sub-voxels its path may cross (`fine`; empty: every occupied
    voxel), inf when every voxel it crosses there is empty. rx, ry, rz are the reciprocal
    direction; each step (out of one voxel, or of the empty cube the ray's way from it,
    `Occupancy`) counts as an occupancy step."""
    nx, ny, nz = res[0], res[1], res[2]
    lx, ly, lz = lo[0], lo[1], lo[2]
    cx, cy, cz = cell[0], cell[1], cell[2]
    qx, qy, qz = 1.0 / cx, 1.0 / cy, 1.0 / cz
    q3 = (qx, qy, qz)
    ix = _index(ox, dx, t0, lx, qx, 0, nx - 1)
    iy = _index(oy, dy, t0, ly, qy, 0, ny - 1)
    iz = _index(oz, dz, t0, lz, qz, 0, nz - 1)
    octant = (1 if dx < 0.0 else 0) + (2 if dy < 0.0 else 0) + (4 if dz < 0.0 else 0)
    t = t0
    found = t0  # non-finite arithmetic: skip nothing
    steps = 0
    # Each step leaves the cube it was in along the ray: at most nx + ny + nz of them (the
    # bound also stops a ray whose arithmetic went non-finite).
    for _ in range(nx + ny + nz + 3):
        steps += 1
        v = ix + nx * (iy + ny * iz)
        k = clear[octant, v]
        if k == 0:
            if fine.shape[0] == 0:
                found = t
                break
            # the voxel's own walls: where its path ends, and the step out of it
            tx = _region_exit(ox, dx, rx, ix, ix, lx, cx)
            ty = _region_exit(oy, dy, ry, iy, iy, ly, cy)
            tz = _region_exit(oz, dz, rz, iz, iz, lz, cz)
            t_end = min(tx, min(ty, tz))
            if _path_meets(fine[v], ox, oy, oz, dx, dy, dz, t, min(t_end, t1), lo, q3, ix, iy, iz):
                found = t
                break
            x0 = x1 = ix  # its marked sub-voxels lie off the ray's way: step out of it
            y0 = y1 = iy
            z0 = z1 = iz
        else:
            r = k - 1  # the cube reaches r voxels on from this one, the ray's way on each axis
            x0, x1 = (ix, min(ix + r, nx - 1)) if dx >= 0.0 else (max(ix - r, 0), ix)
            y0, y1 = (iy, min(iy + r, ny - 1)) if dy >= 0.0 else (max(iy - r, 0), iy)
            z0, z1 = (iz, min(iz + r, nz - 1)) if dz >= 0.0 else (max(iz - r, 0), iz)
            tx = _region_exit(ox, dx, rx, x0, x1, lx, cx)
            ty = _region_exit(oy, dy, ry, y0, y1, ly, cy)
            tz = _region_exit(oz, dz, rz, z0, z1, lz, cz)
        t = min(tx, min(ty, tz))
        if t > t1:
            found = INF
            break
        if not t >= t0:
            break
        # Out through the wall reached first; along the other axes the point is still
        # inside the cube's slab (clamped against round-off), so every step leaves the cube;
        # a one-voxel cube's slab is that voxel (no index to find).
        if t == tx:
            ix = x1 + 1 if dx > 0.0 else x0 - 1
            if y0 < y1:
                iy = _index(oy, dy, t, ly, qy, y0, y1)
            if z0 < z1:
                iz = _index(oz, dz, t, lz, qz, z0, z1)
        elif t == ty:
            iy = y1 + 1 if dy > 0.0 else y0 - 1
            if x0 < x1:
                ix = _index(ox, dx, t, lx, qx, x0, x1)
            if z0 < z1:
                iz = _index(oz, dz, t, lz, qz, z0, z1)
        else:
            iz = z1 + 1 if dz > 0.0 else z0 - 1
            if x0 < x1:
                ix = _index(ox, dx, t, lx, qx, x0, x1)
            if y0 < y1:
                iy = _index(oy, dy, t, ly, qy, y0, y1)
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            found = INF
            break
    counters[OCC_STEPS] += steps
    counters[OCC_WALKS] += 1
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
