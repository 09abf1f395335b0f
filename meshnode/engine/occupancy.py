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
"""

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from meshnode.engine.counters import OCC_STEPS
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.traverse import _region_exit, box_span
from protocols.render import EVERYWHERE

INF = math.inf


class Occupancy(NamedTuple):
    """The map as the kernels take it: box corner, voxel size, voxels per axis, and per voxel
    (x fastest) the Chebyshev distance in voxels to the nearest occupied one (0: occupied,
    capped at 255): a walk through empty space jumps out of the empty cube around it in one
    step, as the grid's walk does through empty macro cells."""

    lo: np.ndarray
    cell: np.ndarray
    res: np.ndarray
    clear: np.ndarray


def occupancy_arrays(lo, hi, res, bits: bytes) -> Occupancy:
    """The kernels' form of a map over the box lo..hi of res voxels (x, y, z), packed `bits`
    (numpy's packbits order, x fastest); the caller has checked the sizes."""
    res = np.asarray(res, np.int64)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    clear = _clear(tuple(res.tolist()), bytes(bits))
    return Occupancy(lo, np.maximum((hi - lo) / res, 1e-300), res, clear)


@lru_cache(maxsize=4)
def _clear(res: tuple, bits: bytes) -> np.ndarray:
    """`distances` of a packed map, flat; one array shared by every engine built on the same
    map (the kernels only read it): a node builds an engine per box it holds and the cost
    pre-pass hundreds, all on the partition's one map (tetra 3x3's pre-pass: 328 builds,
    6.2 s of its 20 s in this function)."""
    full = np.unpackbits(np.frombuffer(bits, np.uint8), count=int(np.prod(res))).astype(bool)
    return distances(full.reshape(res[::-1])).ravel()


def distances(full: np.ndarray) -> np.ndarray:
    """Chebyshev distance of every voxel to the nearest occupied one, capped at 255: grow
    the occupied set one voxel at a time (a max over each axis in turn) and note when each
    voxel joins. At most max(res) rounds of whole-array steps."""
    clear = np.full(full.shape, 255, np.uint8)
    clear[full] = 0
    reached = full.copy()
    for k in range(1, min(255, max(full.shape) + 1)):
        if reached.all():
            break
        grown = reached.copy()
        for axis in range(3):
            step = grown.copy()
            lead = [slice(None)] * 3
            lag = [slice(None)] * 3
            lead[axis], lag[axis] = slice(1, None), slice(None, -1)
            step[tuple(lead)] |= grown[tuple(lag)]
            step[tuple(lag)] |= grown[tuple(lead)]
            grown = step
        clear[grown & ~reached] = k
        reached = grown
    return clear


def everywhere(lo, hi) -> Occupancy:
    """A map of one occupied voxel: nothing is skipped (one node, image space)."""
    return occupancy_arrays(lo, hi, *EVERYWHERE)


@leaf
def _index(o, d, t, lo, inv, i0, i1):
    """Voxel index along one axis of the point at t, clamped to [i0, i1] (a multiply by the
    voxel's reciprocal size: a step's division was on its critical path)."""
    return min(max(int(math.floor((o + t * d - lo) * inv)), i0), i1)


@leaf
def first_occupied(ox, oy, oz, dx, dy, dz, rx, ry, rz, t0, t1, lo, cell, res, clear, counters):
    """t where the ray enters the first occupied voxel between t0 and t1 (t0 itself when it
    starts in one), inf when every voxel it crosses there is empty. rx, ry, rz are the
    reciprocal direction; each step (out of one voxel, or of the empty cube around it)
    counts as an occupancy step."""
    nx, ny, nz = res[0], res[1], res[2]
    lx, ly, lz = lo[0], lo[1], lo[2]
    cx, cy, cz = cell[0], cell[1], cell[2]
    qx, qy, qz = 1.0 / cx, 1.0 / cy, 1.0 / cz
    ix = _index(ox, dx, t0, lx, qx, 0, nx - 1)
    iy = _index(oy, dy, t0, ly, qy, 0, ny - 1)
    iz = _index(oz, dz, t0, lz, qz, 0, nz - 1)
    t = t0
    found = t0  # non-finite arithmetic: skip nothing
    steps = 0
    # Each step leaves the cube it was in along the ray: at most nx + ny + nz of them (the
    # bound also stops a ray whose arithmetic went non-finite).
    for _ in range(nx + ny + nz + 3):
        steps += 1
        k = clear[ix + nx * (iy + ny * iz)]
        if k == 0:
            found = t
            break
        r = k - 1
        x0, x1 = max(ix - r, 0), min(ix + r, nx - 1)
        y0, y1 = max(iy - r, 0), min(iy + r, ny - 1)
        z0, z1 = max(iz - r, 0), min(iz + r, nz - 1)
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
        # inside the cube's slab (clamped against round-off), so every step leaves the cube.
        if t == tx:
            ix = x1 + 1 if dx > 0.0 else x0 - 1
            iy = _index(oy, dy, t, ly, qy, y0, y1)
            iz = _index(oz, dz, t, lz, qz, z0, z1)
        elif t == ty:
            iy = y1 + 1 if dy > 0.0 else y0 - 1
            ix = _index(ox, dx, t, lx, qx, x0, x1)
            iz = _index(oz, dz, t, lz, qz, z0, z1)
        else:
            iz = z1 + 1 if dz > 0.0 else z0 - 1
            ix = _index(ox, dx, t, lx, qx, x0, x1)
            iy = _index(oy, dy, t, ly, qy, y0, y1)
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
    counters,
):
    """(t_min moved on to the first occupied voxel the ray meets inside the scene's box, or
    t_min itself where it misses the box or meets none; where it crosses the box through
    empty voxels only, a t just past its exit from the box, else -inf). rx, ry, rz: 1 /
    direction (inf for 0). A segment resumed past the box is one a node's kernel ends at
    once (escaped, or its light reached), where it would walk the box to end it."""
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
        return t_min, -INF
    t = first_occupied(ox, oy, oz, dx, dy, dz, rx, ry, rz, s0, s1, lo, cell, res, clear, counters)
    if t == INF:
        return t_min, s1 + abs(s1) * 1e-9 + 1e-300
    return (t if t > t_min else t_min), -INF


@kernel
def skip_empty(rays, scene_lo, scene_hi, lo, cell, res, clear, counters):
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
            counters,
        )[0]
