"""What the eye sees of the occupancy map: per block of the image's sample grid, how near an
eye ray through it can meet a marked sub-voxel, and in which cell.

A node routes each eye ray it makes from where its work starts: the first occupied voxel of
the scene's occupancy map it meets (`mapwalk.work_start`), a walk of the map that cost more
than tracing the ray did (tetra 3x3: 79 ns a ray against the kernel's 72 ns a segment). Every
pinhole eye ray leaves the same eye through its sample's point of the image plane, so the
map can be seen from the eye once a render: each occupied voxel's box of marked sub-voxels
(`mapbounds.marked_box`: the whole voxel in a map without them), padded, projects onto the
image plane inside the rectangle of the projections of its part that eye rays can reach (the
hull of a convex box clipped to the eye rays' frustum), and every block of the sample grid
that rectangle touches takes the distance from the eye to the box as a bound. No ray of a block
meets a marked sub-voxel nearer than its bound (inf: none at all), so its walk starts there,
or is not made. (The voxels' own boxes bounded the blocks before: balls and tetra 3x3 under
a quarter share routed their eye rays in 123-134 and 154-156 ns a ray, 71-97 and 91-104 ns
on the sub-voxels' boxes, as 78% and 77% of their rays, then 90% and 83%, went to a cell
with no walk.) Each block also learns the cell of the nearest part of those voxels
it sees and how near any other cell's parts come: a ray entering that cell before then
starts its work there (any voxel it meets first lies in it), so it is made by the node
tracing that cell (`meshnode.mesh.claims`) and sent there with no walk at all
(`routing.routed`).

The lights' side of the same idea, for shadow rays, is `meshnode.engine.lightmaps`'.

Exact: a ray's work starts at its bound or later only where no marked sub-voxel lies nearer,
and marked sub-voxels hold every surface (their marking is padded), so no hit is passed by;
the walk from the bound then finds the first voxel whose marked sub-voxels the rest of its
path may cross, as from the scene's box, or starts in it. The padding (far above the
round-off of the points, the projection and the walk's voxel indices) keeps the bound's
point out of every marked sub-voxel, and a clear segment out of all of them.
"""

import math
from typing import NamedTuple

import numpy as np

from meshnode.engine.camera import view_basis
from meshnode.engine.jit import inline, kernel, leaf
from meshnode.engine.mapbounds import bound_maps, box_distance, marked_boxes, padded_voxel, per_map
from meshnode.engine.occupancy import Occupancy
from protocols.render import ImageSpec
from protocols.scene import View

BLOCKS = 256  # blocks along the sample grid's longer side, at most
MARGIN = 0.01  # sample-grid columns (rows) around each projected rectangle
WORK_MAX = 1 << 24  # voxel-by-block writes at most; past it the map is not used
INF = math.inf


class EyeMap(NamedTuple):
    """Per block of `side` x `side` sample-grid cells (x fastest, `blocks_x` a row) the least
    t at which an eye ray through it can meet a marked sub-voxel; `columns`: the sample
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
    width, height = image.size
    columns, rows = image.sample_grid()
    side = -(-max(columns, rows) // BLOCKS)
    bx, by = -(-columns // side), -(-rows // side)
    seen_from = (*view_basis(view, width, height), float(width), float(height), columns, rows, side)

    def bounds():
        made = [_near(voxels, seen_from, bx, by) for voxels in bound_maps(occ)]
        return np.minimum.reduce([n for n, _ in made]), sum(w for _, w in made)

    # the bounds depend on the map, view and image alone: made once for every simulated
    # mesh of a plan (balls 3x3: 5 ms of the map's 10); the cells seen, for each partition
    near, work = per_map(occ, ("eye", repr(view), repr(image)), bounds)
    occ = occ.outer  # the cells seen first, on the outer map alone
    args = ((occ.clear[0], marked_boxes(occ), occ.lo, occ.cell, occ.res), seen_from, bx, by)
    if work > WORK_MAX:
        return NO_EYE_MAP, f"not used: {work} voxel-block writes past {WORK_MAX}"
    first, others = np.full(bx * by, SEEN_NONE, np.int64), np.full(bx * by, INF)
    if cells is not None:
        first, others = _cells_seen(*args, *(np.ascontiguousarray(c, float) for c in cells))
    per_cell = 1 if image.corners() else image.spp
    open_blocks = float(np.mean(near == INF))
    return EyeMap(near, side, columns, per_cell, bx, first, others), (
        f"{bx}x{by} blocks of {side} samples a side; {open_blocks:.0%} see no marked sub-voxel"
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


@inline
def _view(seen_from):
    """The eye's view as `_rectangle` reads it: `seen_from` (eye, fwd, right, up, step, width,
    height, columns, rows, block side) and the least cosine between an eye ray and the eye's
    axis (a sample's px, py are at most (width / 2 + 1) steps across): a point at distance r
    nearer the eye's plane than r * front lies outside every eye ray's frustum."""
    eye, fwd, right, up, step, width, height, cols, rows, side = seen_from
    reach = (0.5 * max(width, height) + 2.0) * step
    front = 1.0 / math.sqrt(1.0 + 2.0 * reach * reach)
    return (eye, fwd, right, up, step, width, height, cols, rows, side, front)


@kernel
def _near(voxels, seen_from, bx, by):
    """(per block the least distance from the eye to a padded occupied voxel's box of marked
    sub-voxels projecting onto it, the voxel-block writes made; past WORK_MAX it stops).
    `voxels`: (a row of `Occupancy.clear`, 0 where a voxel is occupied; the boxes, as
    `marked_box`; the map's corner, voxel size and voxels per axis); `seen_from`: as `_view`
    takes it. A voxel reaching behind the eye's plane bounds every block."""
    occupied, marked, lo, cell, res = voxels
    view = _view(seen_from)
    eye = view[0]
    near = np.full(bx * by, INF)
    everywhere, work = INF, 0
    b_lo, b_hi = np.empty(3), np.empty(3)
    for v in range(occupied.shape[0]):
        if occupied[v] != 0:
            continue
        bound = padded_voxel(v, lo, cell, res, eye, b_lo, b_hi, marked) * (1.0 - 1e-12)
        state, i0, i1, j0, j1 = _rectangle(b_lo, b_hi, view, bound)
        if state == BEHIND:
            everywhere = min(everywhere, bound)
        elif state == ON_IMAGE:
            work += (i1 - i0 + 1) * (j1 - j0 + 1)
            if work > WORK_MAX:
                return near, work
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    near[j * bx + i] = min(near[j * bx + i], bound)
    if everywhere < INF:
        for b in range(near.shape[0]):
            near[b] = min(near[b], everywhere)
    return near, work


@kernel
def _cells_seen(voxels, seen_from, bx, by, cell_los, cell_his):
    """(per block the cell of cell_los..cell_his of the nearest part of the padded boxes of
    marked sub-voxels (`_near`'s) projecting onto it, per block the least distance to a part
    of any other cell: `EyeMap.first`, `EyeMap.others`). A voxel across cells is seen part
    by part, each part (widened by round-off) under its own cell; a part reaching behind
    the eye's plane is seen by every block."""
    first = np.full(bx * by, SEEN_NONE, np.int64)
    first_d, others = np.full(bx * by, INF), np.full(bx * by, INF)
    behind = np.full(cell_los.shape[0], INF)  # per cell, its nearest part behind the eye
    occupied, marked, lo, cell, res = voxels
    view = _view(seen_from)
    eye = view[0]
    b_lo, b_hi, p_lo, p_hi = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for v in range(occupied.shape[0]):
        if occupied[v] != 0:
            continue
        padded_voxel(v, lo, cell, res, eye, b_lo, b_hi, marked)
        for c in range(cell_los.shape[0]):
            if not _part_in_cell(b_lo, b_hi, eye, cell_los[c], cell_his[c], p_lo, p_hi):
                continue
            d = box_distance(p_lo, p_hi) * (1.0 - 1e-12)
            state, i0, i1, j0, j1 = _rectangle(p_lo, p_hi, view, d)
            if state == BEHIND:
                behind[c] = min(behind[c], d)
            elif state == ON_IMAGE:
                for j in range(j0, j1 + 1):
                    for i in range(i0, i1 + 1):
                        _seen_part(first, first_d, others, j * bx + i, c, d)
    for c in range(behind.shape[0]):
        if behind[c] < INF:
            for b in range(first.shape[0]):
                _seen_part(first, first_d, others, b, c, behind[c])
    return first, others


OFF_IMAGE, ON_IMAGE, BEHIND = 0, 1, 2  # `_rectangle`'s states


@leaf
def _rectangle(b_lo, b_hi, view, d):
    """(state, i0, i1, j0, j1): the blocks (columns i0..i1, rows j0..j1) the box b_lo..b_hi
    (relative to the eye, at distance `d` from it) projects onto, inside the hull of the
    projections of its part in front of the plane s = d * front * (1 - 1e-3) (its corners
    there and its edges' crossings of it) and a MARGIN; OFF_IMAGE where it misses. Nearer the
    eye's plane than that, no point of the box lies in any eye ray's frustum, so a floor
    reaching behind the eye bounds only the blocks that see it (it had bounded every block:
    balls 3x3, most blocks of six cells' nodes then walked the map, 120-370 ns an eye ray
    against 40); BEHIND only where the eye is in the box (d = 0: every block)."""
    eye, fwd, right, up, step, width, height, cols, rows, side, front = view
    s_min = d * front * (1.0 - 1e-3)
    if not s_min > 0.0:
        return BEHIND, 0, 0, 0, 0
    x0, x1, y0, y1 = INF, -INF, INF, -INF
    for c in range(8):  # each corner in front of the plane, and each edge's crossing of it
        cs = _depth(b_lo, b_hi, c, fwd)
        if cs >= s_min:
            fx, fy = _projected(b_lo, b_hi, c, c, 0.0, view, s_min)
            x0, x1, y0, y1 = min(x0, fx), max(x1, fx), min(y0, fy), max(y1, fy)
        for a in range(3):  # the edge to the corner on axis a's high side
            e = c | (1 << a)
            if e == c:
                continue
            es = _depth(b_lo, b_hi, e, fwd)
            if (cs < s_min) != (es < s_min):
                w = (s_min - cs) / (es - cs)
                fx, fy = _projected(b_lo, b_hi, c, e, w, view, s_min)
                x0, x1, y0, y1 = min(x0, fx), max(x1, fx), min(y0, fy), max(y1, fy)
    # sample-grid cell i holds samples at i <= fx < i + 1
    if x0 > x1 or x1 + MARGIN < 0.0 or y1 + MARGIN < 0.0 or x0 - MARGIN >= cols:
        return OFF_IMAGE, 0, 0, 0, 0
    if y0 - MARGIN >= rows:
        return OFF_IMAGE, 0, 0, 0, 0
    i0 = max(int(math.floor(x0 - MARGIN)), 0) // side
    i1 = min(int(math.floor(x1 + MARGIN)), cols - 1) // side
    j0 = max(int(math.floor(y0 - MARGIN)), 0) // side
    j1 = min(int(math.floor(y1 + MARGIN)), rows - 1) // side
    return ON_IMAGE, i0, i1, j0, j1


@inline
def _projected(b_lo, b_hi, c, e, w, view, s_min):
    """(fx, fy) on the sample grid of the point `w` of the way from corner c of the box to
    corner e (bit a: the high side on axis a), at least s_min in front of the eye."""
    eye, fwd, right, up, step, width, height, cols, rows, side, front = view
    px, py, s = 0.0, 0.0, 0.0
    for a in range(3):
        lo_a = b_hi[a] if c >> a & 1 else b_lo[a]
        hi_a = b_hi[a] if e >> a & 1 else b_lo[a]
        q = lo_a + w * (hi_a - lo_a)
        px += q * right[a]
        py += q * up[a]
        s += q * fwd[a]
    s = max(s, s_min)
    return px / s / step + 0.5 * width, 0.5 * height - py / s / step  # as `fill_eye_rays`


@inline
def _depth(b_lo, b_hi, c, fwd):
    """How far corner c (bit a: the high side on axis a) of the box lies along `fwd`."""
    s = 0.0
    for a in range(3):
        s += (b_hi[a] if c >> a & 1 else b_lo[a]) * fwd[a]
    return s


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
