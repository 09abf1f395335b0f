"""What the eye and each light see of the occupancy map: per direction block, how near a ray
from there can meet an occupied voxel.

A node routes each eye ray it makes from where its work starts: the first occupied voxel of
the scene's occupancy map it meets (`occupancy.work_start`), a walk of the map that cost more
than tracing the ray did (tetra 3x3: 79 ns a ray against the kernel's 72 ns a segment). Every
pinhole eye ray leaves the same eye through its sample's point of the image plane, so the
map can be seen from the eye once a render: each occupied voxel, padded, projects onto the
image plane inside the rectangle of its corners' projections (the hull of a convex box in
front of the eye), and every block of the sample grid that rectangle touches takes the
distance from the eye to the box as a bound. No ray of a block meets an occupied voxel
nearer than its bound (inf: none at all), so its walk starts there, or is not made. Each
block also learns the cell of the nearest part of those voxels it sees and how near any
other cell's parts come: a ray entering that cell before then starts its work there (any
voxel it meets first lies in it), so it is made by the node tracing that cell
(`meshnode.mesh.claims`) and sent there with no walk at all (`routing.routed`).

Shadow rays all end at their light: seen from each light through the six faces of a cube
around it (`light_maps`), a shadow ray leaving a node's box nearer its light than the bound
of its direction's block has only empty voxels left to cross, and ends lit without the walk
of the map from its exit that would find so (`light_clear`).

Exact: the walk from the bound crosses the same empty voxels' far walls into the same first
occupied voxel, whose entry it computes from the same wall, so the same t; the padding (far
above the round-off of the points, the projection and the walk's voxel indices) keeps the
bound's point out of every occupied voxel, and a clear segment out of all of them.
"""

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from meshnode.engine.camera import view_basis
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.occupancy import Occupancy
from protocols.render import ImageSpec
from protocols.scene import View

BLOCKS = 256  # blocks along the sample grid's longer side, at most
FACE_BLOCKS = 64  # blocks along a side of each face of a light's cube map
PAD = 1e-6  # of a voxel, each way, around every occupied voxel
MARGIN = 0.01  # sample-grid columns (rows) around each projected rectangle
WORK_MAX = 1 << 24  # voxel-by-block writes at most; past it the map is not used
INF = math.inf


class EyeMap(NamedTuple):
    """Per block of `side` x `side` sample-grid cells (x fastest, `blocks_x` a row) the least
    t at which an eye ray through it can meet an occupied voxel; `columns`: the sample
    grid's; `per_cell`: RAY.pixel ids per sample-grid cell (spp; 1 at pixel corners).
    `near` is empty where no map is used (every walk starts at the scene's box)."""

    near: np.ndarray
    side: int
    columns: int
    per_cell: int
    blocks_x: int
    first: np.ndarray  # per block, the cell of the nearest part it sees (SEEN_NONE: none)
    others: np.ndarray  # ... the least distance to a part of any other cell it sees


SEEN_NONE = -1  # `EyeMap.first` of a block that sees no cell's voxels (or is not known)
NO_EYE_MAP = EyeMap(np.zeros(0), 1, 1, 1, 1, np.zeros(0, np.int64), np.zeros(0))


def eye_map(occ: Occupancy, view: View, image: ImageSpec, cells=None) -> tuple[EyeMap, str]:
    """The `EyeMap` of pinhole eye rays of `image` from `view` over the map `occ`, and why
    it is or is not used (for the stats); with `cells` (los, his), which of them each block
    sees nearest and how near it sees any other (`EyeMap.first`, `EyeMap.others`): an eye
    ray entering the first before any other's voxels starts its work there, so the node
    tracing that cell can make it (`meshnode.mesh.claims`) and route it with no walk."""
    cell_los, cell_his = (np.zeros((0, 3)), np.zeros((0, 3))) if cells is None else cells
    width, height = image.size
    eye, fwd, right, up, step = view_basis(view, width, height)
    columns, rows = image.sample_grid()
    side = -(-max(columns, rows) // BLOCKS)
    bx, by = -(-columns // side), -(-rows // side)
    near, first, others, work = _seen(
        occ.clear[0],
        occ.lo,
        occ.cell,
        occ.res,
        eye,
        fwd,
        right,
        up,
        step,
        float(width),
        float(height),
        columns,
        rows,
        side,
        bx,
        by,
        np.ascontiguousarray(cell_los, float),
        np.ascontiguousarray(cell_his, float),
    )
    if work > WORK_MAX:
        return NO_EYE_MAP, f"not used: {work} voxel-block writes past {WORK_MAX}"
    per_cell = 1 if image.corners() else image.spp
    open_blocks = float(np.mean(near == INF))
    return EyeMap(near, side, columns, per_cell, bx, first, others), (
        f"{bx}x{by} blocks of {side} samples a side; {open_blocks:.0%} see no occupied voxel"
    )


@inline
def eye_cell(eye, pixel):
    """(first id, end id, bound, cell, others) of the sample-grid cell holding RAY.pixel id
    `pixel` under the `EyeMap` eye: the ids of that cell's samples, all in one block, the
    block's bound (-inf where the id lies outside the map: nothing known), the cell it sees
    nearest and the least distance to any other's voxels (`EyeMap.first`, `EyeMap.others`;
    SEEN_NONE where not known)."""
    side, columns, per_cell = eye.side, eye.columns, eye.per_cell
    g = pixel // per_cell
    b = (g // columns) // side * eye.blocks_x + (g % columns) // side
    known = 0 <= g and b < eye.near.shape[0]
    bound = eye.near[b] if known else -INF
    if known and b < eye.first.shape[0]:
        return g * per_cell, (g + 1) * per_cell, bound, eye.first[b], eye.others[b]
    return g * per_cell, (g + 1) * per_cell, bound, SEEN_NONE, -INF


def light_maps(occ: Occupancy, lights: np.ndarray | None) -> np.ndarray:
    """Per light (rows of `lights`, position first) and face of a cube around it (`_face`),
    per block of FACE_BLOCKS x FACE_BLOCKS, the least distance from the light to an occupied
    voxel seen through that block: (lights, 6 * FACE_BLOCKS**2); (0, 0) without lights. A
    shadow ray leaving a node's box nearer its light than its block's bound crosses only
    empty voxels to it (`light_clear`), so the walk of the map from its exit is not made."""
    if lights is None or not len(lights):
        return np.zeros((0, 0))
    return _light_maps(
        occ.clear[0].tobytes(),
        occ.lo.tobytes(),
        occ.cell.tobytes(),
        tuple(occ.res.tolist()),
        np.ascontiguousarray(lights[:, :3]).tobytes(),
    )


@lru_cache(maxsize=8)
def _light_maps(
    occupied: bytes, lo: bytes, cell: bytes, res: tuple, positions: bytes
) -> np.ndarray:
    """`light_maps` of a map and the lights' positions, as bytes: one array for every engine
    built on the same map (the cost pre-pass builds hundreds)."""
    occupied_ = np.frombuffer(occupied, np.uint8)
    lo_, cell_ = np.frombuffer(lo, float), np.frombuffer(cell, float)
    res_ = np.asarray(res, np.int64)
    points = np.frombuffer(positions, float).reshape(-1, 3)
    return np.stack([_faces(occupied_, lo_, cell_, res_, p, FACE_BLOCKS) for p in points])


@leaf
def _padded_voxel(v, lo, cell, res, point, b_lo, b_hi):
    """Voxel v of the map (x fastest), padded by PAD of a voxel and far above round-off, as
    b_lo..b_hi relative to `point`; returns the distance from the point to it."""
    nx, ny = res[0], res[1]
    index = (v % nx, (v // nx) % ny, v // (nx * ny))
    for a in range(3):
        pad = PAD * cell[a] + 1e-12 * (abs(lo[a]) + abs(point[a]) + res[a] * cell[a])
        b_lo[a] = lo[a] + index[a] * cell[a] - pad - point[a]
        b_hi[a] = lo[a] + (index[a] + 1) * cell[a] + pad - point[a]
    return _distance(b_lo, b_hi)


@kernel
def _faces(occupied, lo, cell, res, point, s):
    """The six faces' blocks (`light_maps`) of one point. A voxel at distance r from the
    point is seen through a face (axis a, facing +a or -a) only where it lies at least
    r / sqrt(3) out along that axis (inside the face's pyramid a point's distance is at
    most sqrt(3) times its depth), so each face projects the voxel clipped there: a voxel
    across the face's plane bounds only the blocks it reaches, not the whole face."""
    near = np.full(6 * s * s, INF)
    b_lo, b_hi = np.empty(3), np.empty(3)
    for v in range(occupied.shape[0]):
        if occupied[v] != 0:
            continue
        r = _padded_voxel(v, lo, cell, res, point, b_lo, b_hi)
        bound = r * (1.0 - 1e-12)
        for face in range(6):
            a = face // 2
            b, c = (a + 1) % 3, (a + 2) % 3
            d0, d1 = (b_lo[a], b_hi[a]) if face % 2 == 0 else (-b_hi[a], -b_lo[a])
            d0 = max(d0, r * (1.0 - 1e-9) / math.sqrt(3.0))
            if not d0 > 0.0 or d1 < d0:
                if not d0 > 0.0 and d1 > 0.0:  # the point inside the padded voxel
                    for k in range(face * s * s, (face + 1) * s * s):
                        near[k] = min(near[k], bound)
                continue
            x0 = min(b_lo[b] / d0, b_lo[b] / d1)
            x1 = max(b_hi[b] / d0, b_hi[b] / d1)
            y0 = min(b_lo[c] / d0, b_lo[c] / d1)
            y1 = max(b_hi[c] / d0, b_hi[c] / d1)
            # as `light_clear` maps a direction: fx = u * s / 2 + s / 2, fy = s / 2 - w * s / 2
            fx0, fx1 = x0 * (0.5 * s) + 0.5 * s, x1 * (0.5 * s) + 0.5 * s
            fy0, fy1 = 0.5 * s - y1 * (0.5 * s), 0.5 * s - y0 * (0.5 * s)
            if fx1 + MARGIN < 0.0 or fy1 + MARGIN < 0.0 or fx0 - MARGIN >= s or fy0 - MARGIN >= s:
                continue
            i0 = max(int(math.floor(fx0 - MARGIN)), 0)
            i1 = min(int(math.floor(fx1 + MARGIN)), s - 1)
            j0 = max(int(math.floor(fy0 - MARGIN)), 0)
            j1 = min(int(math.floor(fy1 + MARGIN)), s - 1)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    k = face * s * s + j * s + i
                    near[k] = min(near[k], bound)
    return near


@leaf
def light_clear(maps, light, lx, ly, lz, x, y, z):
    """Whether the segment from the light `light` at (lx, ly, lz) to (x, y, z) crosses only
    empty voxels by `light_maps` (False: it may not; walk the map)."""
    vx, vy, vz = x - lx, y - ly, z - lz
    ax, ay, az = abs(vx), abs(vy), abs(vz)
    if ax >= ay and ax >= az:
        face, depth, a, b = (0 if vx >= 0.0 else 1), ax, vy, vz
    elif ay >= az:
        face, depth, a, b = (2 if vy >= 0.0 else 3), ay, vz, vx
    else:
        face, depth, a, b = (4 if vz >= 0.0 else 5), az, vx, vy
    if not depth > 0.0:
        return False
    s = FACE_BLOCKS
    fx = a / depth * (0.5 * s) + 0.5 * s  # as `_seen` projects with step 2 / s
    fy = 0.5 * s - b / depth * (0.5 * s)
    i = min(max(int(math.floor(fx)), 0), s - 1)
    j = min(max(int(math.floor(fy)), 0), s - 1)
    return maps[light, face * s * s + j * s + i] > math.sqrt(vx * vx + vy * vy + vz * vz)


@kernel
def _seen(
    occupied,
    lo,
    cell,
    res,
    eye,
    fwd,
    right,
    up,
    step,
    width,
    height,
    cols,
    rows,
    side,
    bx,
    by,
    cell_los,
    cell_his,
):
    """(per block the least distance from the eye to a padded occupied voxel projecting onto
    it, per block the cell of cell_los..cell_his of the nearest part of those voxels and the
    least distance to a part of any other cell (`EyeMap.first`, `EyeMap.others`; SEEN_NONE
    and inf without cells), the voxel-block writes made). `occupied`: a row of
    `Occupancy.clear`, 0 where a voxel is occupied. A voxel reaching behind the eye's plane
    bounds every block and is seen by every block. A voxel across cells is seen part by
    part, each part (widened by round-off) under its own cell."""
    near = np.full(bx * by, INF)
    first = np.full(bx * by, SEEN_NONE, np.int64)
    first_d, others = np.full(bx * by, INF), np.full(bx * by, INF)
    behind = np.full(cell_los.shape[0], INF)  # per cell, its nearest part behind the eye
    everywhere, work = INF, 0
    view = (eye, fwd, right, up, step, width, height, cols, rows, side)
    b_lo, b_hi, p_lo, p_hi = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for v in range(occupied.shape[0]):
        if occupied[v] != 0:
            continue
        bound = _padded_voxel(v, lo, cell, res, eye, b_lo, b_hi) * (1.0 - 1e-12)
        state, i0, i1, j0, j1 = _rectangle(b_lo, b_hi, view)
        if state == BEHIND:
            everywhere = min(everywhere, bound)
        elif state == ON_IMAGE:
            work += (i1 - i0 + 1) * (j1 - j0 + 1)
            if work > WORK_MAX:
                return near, first, others, work
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    near[j * bx + i] = min(near[j * bx + i], bound)
        for c in range(cell_los.shape[0]):
            if not _part_in_cell(b_lo, b_hi, eye, cell_los[c], cell_his[c], p_lo, p_hi):
                continue
            d = _distance(p_lo, p_hi) * (1.0 - 1e-12)
            state, i0, i1, j0, j1 = _rectangle(p_lo, p_hi, view)
            if state == BEHIND:
                behind[c] = min(behind[c], d)
            elif state == ON_IMAGE:
                for j in range(j0, j1 + 1):
                    for i in range(i0, i1 + 1):
                        _seen_part(first, first_d, others, j * bx + i, c, d)
    if everywhere < INF:
        for b in range(near.shape[0]):
            near[b] = min(near[b], everywhere)
    for c in range(behind.shape[0]):
        if behind[c] < INF:
            for b in range(near.shape[0]):
                _seen_part(first, first_d, others, b, c, behind[c])
    return near, first, others, work


OFF_IMAGE, ON_IMAGE, BEHIND = 0, 1, 2  # `_rectangle`'s states


@leaf
def _rectangle(b_lo, b_hi, view):
    """(state, i0, i1, j0, j1): the blocks (columns i0..i1, rows j0..j1) the box b_lo..b_hi
    (relative to the eye) projects onto, inside the hull of its corners' projections and a
    MARGIN; BEHIND where it reaches behind the eye's plane, OFF_IMAGE where it misses."""
    eye, fwd, right, up, step, width, height, cols, rows, side = view
    x0, x1, y0, y1 = INF, -INF, INF, -INF
    for c in range(8):
        cx = b_hi[0] if c & 1 else b_lo[0]
        cy = b_hi[1] if c & 2 else b_lo[1]
        cz = b_hi[2] if c & 4 else b_lo[2]
        s = cx * fwd[0] + cy * fwd[1] + cz * fwd[2]
        if not s > 1e-9 * math.sqrt(cx * cx + cy * cy + cz * cz):
            return BEHIND, 0, 0, 0, 0
        px = (cx * right[0] + cy * right[1] + cz * right[2]) / s
        py = (cx * up[0] + cy * up[1] + cz * up[2]) / s
        fx = px / step + 0.5 * width  # as `fill_eye_rays` makes px from fx
        fy = 0.5 * height - py / step
        x0, x1 = min(x0, fx), max(x1, fx)
        y0, y1 = min(y0, fy), max(y1, fy)
    # sample-grid cell i holds samples at i <= fx < i + 1
    if x1 + MARGIN < 0.0 or y1 + MARGIN < 0.0 or x0 - MARGIN >= cols or y0 - MARGIN >= rows:
        return OFF_IMAGE, 0, 0, 0, 0
    i0 = max(int(math.floor(x0 - MARGIN)), 0) // side
    i1 = min(int(math.floor(x1 + MARGIN)), cols - 1) // side
    j0 = max(int(math.floor(y0 - MARGIN)), 0) // side
    j1 = min(int(math.floor(y1 + MARGIN)), rows - 1) // side
    return ON_IMAGE, i0, i1, j0, j1


@leaf
def _part_in_cell(b_lo, b_hi, eye, c_lo, c_hi, p_lo, p_hi):
    """Whether the padded voxel b_lo..b_hi (relative to `eye`) has a part in the cell
    c_lo..c_hi widened by round-off, written to p_lo..p_hi: a ray's work starts on a
    voxel's wall and goes to the cell holding that point (`routing`), so the part a ray
    meets first names the cell it goes to."""
    for a in range(3):
        slack = 1e-9 * (abs(c_lo[a]) + abs(c_hi[a]) + abs(eye[a]))
        p_lo[a] = max(b_lo[a], c_lo[a] - slack - eye[a])
        p_hi[a] = min(b_hi[a], c_hi[a] + slack - eye[a])
        if p_lo[a] > p_hi[a]:
            return False
    return True


@inline
def _seen_part(first, first_d, others, b, c, d):
    """Block b sees a part of cell c at distance d: the nearest part's cell stays first,
    every other cell's parts bound `others` (a cell once first and then passed keeps its
    earlier parts in `others`, so the bound stays one: it may only be nearer)."""
    if first[b] == SEEN_NONE:
        first[b], first_d[b] = c, d
    elif first[b] == c:
        first_d[b] = min(first_d[b], d)
    elif d < first_d[b]:
        others[b] = min(others[b], first_d[b])
        first[b], first_d[b] = c, d
    else:
        others[b] = min(others[b], d)


@inline
def _distance(b_lo, b_hi):
    """The distance from the origin to the box b_lo..b_hi."""
    gap = 0.0
    for a in range(3):
        g = max(b_lo[a], 0.0, -b_hi[a])
        gap += g * g
    return math.sqrt(gap)
