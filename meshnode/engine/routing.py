"""Who takes a ray on: the cell (box) where its work goes on, and batches regrouped by it
(`routed`), as a node routes its eye rays and the segments leaving its box.

A ray's owner is looked for first among the cells holding the point where it goes on, found
on the arrangement of the cells' faces (`Locator`): per axis the distinct face coordinates,
per box between them the cells covering it. Each axis's coordinate is searched within a
margin far above the round-off of the point and of the slab test (`_MARGIN`), so every cell
that can hold the point is looked at; the answer is the one a look at every cell gives
(`_owner`), which a point in no listed cell gets. Routing balls' passed rays, the same rays
and cells both ways (/tmp script over a simulated mesh): 3x3 75 -> 66 ns a ray, 4x4 104 -> 69
(a uniform grid over the scene listed 11.5 of 16 cells a voxel: cells cut by the objects are
narrow where objects crowd, and gained nothing).
"""

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from meshnode.engine.counters import N_COUNTERS
from meshnode.engine.jit import inline, kernel
from meshnode.engine.occupancy import past_box, work_start
from meshnode.engine.sightlines import eye_cell
from meshnode.engine.traverse import box_span

_MARGIN = 1e-13  # of |o| + |t d| + |the scene's coordinates|: round-off is below 1e-15 of it
ARRANGEMENT_MAX = 1 << 22  # cells x boxes of the arrangement kept at most (else every cell)


class Locator(NamedTuple):
    """The cells' arrangement: per axis its sorted face coordinates, coords[at[a]:at[a] + n[a]];
    per box between them (x fastest) the cells covering it, members[first[v]:first[v + 1]];
    `scale` per axis: the cells' largest coordinate, for the margin."""

    coords: np.ndarray
    at: np.ndarray
    n: np.ndarray
    first: np.ndarray
    members: np.ndarray
    scale: np.ndarray


def cell_locator(los, his) -> Locator:
    """The `Locator` of cells los..his (n, 3); one for every engine routing to the same cells
    (the cost pre-pass builds hundreds of engines on one partition)."""
    los, his = (np.ascontiguousarray(a, float).reshape(-1, 3) for a in (los, his))
    return _locator(los.tobytes(), his.tobytes())


@lru_cache(maxsize=8)
def _locator(los: bytes, his: bytes) -> Locator:
    """`cell_locator` of the cells' bytes: each cell marks the boxes of the arrangement it
    covers (a mesh has at most a few hundred cells). An arrangement too large for that, or
    flat along an axis, lists nothing, and every ray looks at every cell."""
    los, his = (np.frombuffer(b, float).reshape(-1, 3) for b in (los, his))
    axes = [np.unique(np.concatenate([los[:, a], his[:, a]])) for a in range(3)]
    n = np.array([len(c) for c in axes], np.int64)
    dims = np.maximum(n - 1, 0)
    if not dims.all() or len(los) * int(np.prod(dims)) > ARRANGEMENT_MAX:
        return Locator(
            np.zeros(0),
            np.zeros(3, np.int64),
            np.zeros(3, np.int64),
            np.zeros(1, np.int64),
            np.zeros(0, np.int64),
            np.zeros(3),
        )
    # a cell flat along an axis marks the interval above its plane (below, at the top): a
    # point on the plane is looked up in both
    lo_i = [np.minimum(np.searchsorted(axes[a], los[:, a]), dims[a] - 1) for a in range(3)]
    hi_i = [np.maximum(np.searchsorted(axes[a], his[:, a]), lo_i[a] + 1) for a in range(3)]
    cover = np.zeros((len(los), dims[2], dims[1], dims[0]), bool)
    for b in range(len(los)):  # once per cell
        cover[b, lo_i[2][b] : hi_i[2][b], lo_i[1][b] : hi_i[1][b], lo_i[0][b] : hi_i[0][b]] = 1
    flat = cover.reshape(len(los), -1)
    box, cell = np.nonzero(flat.T)  # by arrangement box, then cell
    first = np.zeros(flat.shape[1] + 1, np.int64)
    np.cumsum(np.bincount(box, minlength=flat.shape[1]), out=first[1:])
    at = np.array([0, n[0], n[0] + n[1]], np.int64)
    scale = np.maximum(np.abs(los).max(axis=0), np.abs(his).max(axis=0))
    return Locator(np.concatenate(axes), at, n, first, cell.astype(np.int64), scale)


@inline
def _cell_span(ox, oy, oz, irx, iry, irz, t, t_max, los, his, b):
    """`box_span` of the ray from t on cell b of los..his (indexed, no row views made)."""
    x0, y0, z0, x1, y1, z1 = los[b, 0], los[b, 1], los[b, 2], his[b, 0], his[b, 1], his[b, 2]
    return box_span(ox, oy, oz, irx, iry, irz, t, t_max, x0, y0, z0, x1, y1, z1)


@inline
def _owner(ox, oy, oz, irx, iry, irz, t, t_max, los, his):
    """(box, t) of one ray for `owners`: the box that takes it on from t, and t, moved to
    that box's entry where the ray is in none at t."""
    best, best_exit = -1, t
    next_entry, next_box = math.inf, -1
    for b in range(los.shape[0]):
        b0, b1 = _cell_span(ox, oy, oz, irx, iry, irz, t, t_max, los, his, b)
        if b0 <= t and b1 > best_exit:
            best_exit = b1
            best = b
        elif t < b0 < b1 and b0 < next_entry:
            next_entry = b0
            next_box = b
    if best < 0 and next_box >= 0:
        return next_box, next_entry
    return best, t


@inline
def _below(coords, at, n, v, right):
    """How many of coords[at:at + n] (sorted) lie below v (with `right`, at or below)."""
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) >> 1
        c = coords[at + mid]
        if c < v or (right and c == v):
            lo = mid + 1
        else:
            hi = mid
    return lo


@inline
def _span_of(coords, at, n, p, m):
    """(first, last) arrangement intervals along one axis that [p - m, p + m] meets (last <
    first: none)."""
    first = max(_below(coords, at, n, p - m, False) - 1, 0)
    last = min(_below(coords, at, n, p + m, True), n - 1) - 1
    return first, last


@inline
def _located_owner(
    ox, oy, oz, dx, dy, dz, irx, iry, irz, t, t_max, los, his, coords, at, n, first, members, scale
):
    """`_owner`'s answer, looking first only at the cells the arrangement `loc` lists near
    the ray's point at t (ties, as there, to the lower cell); every cell where none of those
    holds it (the cell it enters next, or none). The `Locator`'s arrays come one by one,
    unpacked once a batch."""
    best, best_exit = -1, t
    if n[0] > 1:
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        x0, x1 = _span_of(coords, at[0], n[0], px, _MARGIN * (abs(ox) + abs(t * dx) + scale[0]))
        y0, y1 = _span_of(coords, at[1], n[1], py, _MARGIN * (abs(oy) + abs(t * dy) + scale[1]))
        z0, z1 = _span_of(coords, at[2], n[2], pz, _MARGIN * (abs(oz) + abs(t * dz) + scale[2]))
        for z in range(z0, z1 + 1):
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    v = x + (n[0] - 1) * (y + (n[1] - 1) * z)
                    for k in range(first[v], first[v + 1]):
                        b = members[k]
                        b0, b1 = _cell_span(ox, oy, oz, irx, iry, irz, t, t_max, los, his, b)
                        if b0 <= t and (b1 > best_exit or (b1 == best_exit and 0 <= b < best)):
                            best_exit = b1
                            best = b
    if best >= 0:
        return best, t
    return _owner(ox, oy, oz, irx, iry, irz, t, t_max, los, his)


@kernel
def owners(rays, los, his):
    """Index of the box that takes each ray on from its t_min: it must hold the point at t_min
    and let the ray advance (exit beyond t_min); among those the one the ray crosses farthest,
    so overlapping boxes mean fewer hops. Where round-off leaves the point just outside every
    box, the ray goes to the box it enters next and its t_min moves to that entry (the sliver
    between holds no object). -1 where no box lies ahead at all."""
    n = rays.shape[0]
    out = np.full(n, -1, np.int64)
    for i in range(n):
        r = rays[i]
        irx = 1.0 / r.d[0] if r.d[0] != 0.0 else math.inf
        iry = 1.0 / r.d[1] if r.d[1] != 0.0 else math.inf
        irz = 1.0 / r.d[2] if r.d[2] != 0.0 else math.inf
        out[i], r.t_min = _owner(r.o[0], r.o[1], r.o[2], irx, iry, irz, r.t_min, r.t_max, los, his)
    return out


@inline
def _first_cell_start(
    ox, oy, oz, rx, ry, rz, t_min, t_max, c, others, los, his, scene_lo, scene_hi
):
    """(cell, t, past) as `routed` has them for an eye ray whose block sees cell c's parts of
    occupied voxels nearest and no other cell's nearer than `others` (`EyeMap.first`), or
    None where the walk must tell: entering c before `others`, it meets no voxel before c's
    (c's parts lie in c), so its work starts where it enters c with no walk of the map (c's
    kernel finds the same first hit from there as from the first voxel); missing c with no
    other cell seen, it meets none and goes past the scene's box as `work_start` sends it."""
    c0, c1 = box_span(
        ox,
        oy,
        oz,
        rx,
        ry,
        rz,
        t_min,
        t_max,
        los[c, 0],
        los[c, 1],
        los[c, 2],
        his[c, 0],
        his[c, 1],
        his[c, 2],
    )
    if c0 <= c1 and c0 < others:
        return c, c0, -math.inf
    if others < math.inf:
        return -1, t_min, math.nan
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
    return c, t_min, (math.inf if s0 > s1 else past_box(s1))


@kernel
def start_cells(rays, scene_lo, scene_hi, occ, los, his, loc):
    """Per ray the cell its work starts in as `routed` finds it with no eye map (the walk of
    the map `occ` from the scene's box), -1 where it meets no occupied voxel: sampled once a
    block, where each block's eye rays are best made (`meshnode.mesh.claims`)."""
    occ_lo, occ_cell, occ_res, occ_clear = occ
    coords, at, nc, first, members, scale = loc
    counters = np.zeros(N_COUNTERS, np.int64)
    out = np.full(rays.shape[0], -1, np.int64)
    for i in range(rays.shape[0]):
        r = rays[i]
        ox, oy, oz, dx, dy, dz = r.o[0], r.o[1], r.o[2], r.d[0], r.d[1], r.d[2]
        irx = 1.0 / dx if dx != 0.0 else math.inf
        iry = 1.0 / dy if dy != 0.0 else math.inf
        irz = 1.0 / dz if dz != 0.0 else math.inf
        t, past = work_start(
            ox,
            oy,
            oz,
            dx,
            dy,
            dz,
            irx,
            iry,
            irz,
            r.t_min,
            r.t_max,
            scene_lo,
            scene_hi,
            occ_lo,
            occ_cell,
            occ_res,
            occ_clear,
            counters,
            -math.inf,
        )
        if past == -math.inf:
            out[i], _ = _located_owner(
                ox,
                oy,
                oz,
                dx,
                dy,
                dz,
                irx,
                iry,
                irz,
                t,
                r.t_max,
                los,
                his,
                coords,
                at,
                nc,
                first,
                members,
                scale,
            )
    return out


@kernel
def routed(rays, skip, fallback, scene_lo, scene_hi, occ, los, his, loc, eye):
    """`rays` regrouped by the box that takes each on (`owners`), with `skip` after moving
    t_min on to where its work starts (`occupancy.work_start` on the `Occupancy` occ; a ray
    with only empty voxels ahead resumes past the scene's box), as (a new array, the runs'
    starts): box b's run is out[starts[b]:starts[b + 1]], in the order the rays came. A ray
    no box takes, with only empty voxels ahead or missing the scene's box (with `skip`),
    joins box `fallback`'s run; with fallback
    -1 the first is counted (the third value) for the caller to refuse and the second goes
    to the box it enters. `rays` is left as it was. `eye`: an `sightlines.EyeMap` of these
    rays (pinhole eye rays by RAY.pixel) or `NO_EYE_MAP`.

    One pass where a node made five over every batch (a copy, skip_empty, owners, an argsort
    and a split): simulated tetra 3x3, those took 2x the tracing kernel's CPU."""
    occ_lo, occ_cell, occ_res, occ_clear = occ
    coords, at, nc, first, members, scale = loc
    # the last sample-grid cell's ids, bound, the cell seen nearest and the others' bound
    ids_from, ids_to, t_from, nearest, others = 0, 0, -math.inf, -1, -math.inf
    n, boxes = rays.shape[0], los.shape[0]
    dest = np.empty(n, np.int64)
    t_min = np.empty(n)
    starts = np.zeros(boxes + 1, np.int64)
    counters = np.zeros(N_COUNTERS, np.int64)  # occupancy steps here are not a trace's
    lost = 0
    o, d, pixel = rays["o"], rays["d"], rays["pixel"]
    ray_t_min, ray_t_max = rays["t_min"], rays["t_max"]
    for i in range(n):
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        irx = 1.0 / dx if dx != 0.0 else math.inf
        iry = 1.0 / dy if dy != 0.0 else math.inf
        irz = 1.0 / dz if dz != 0.0 else math.inf
        t, past = ray_t_min[i], -math.inf
        if skip and eye.near.shape[0] and not ids_from <= pixel[i] < ids_to:
            ids_from, ids_to, t_from, nearest, others = eye_cell(eye, pixel[i])
        b, seen = -1, False
        if skip and nearest >= 0:
            b, t, past = _first_cell_start(
                ox,
                oy,
                oz,
                irx,
                iry,
                irz,
                t,
                ray_t_max[i],
                nearest,
                others,
                los,
                his,
                scene_lo,
                scene_hi,
            )
            seen = b >= 0
        if skip and not seen:
            t, past = work_start(
                ox,
                oy,
                oz,
                dx,
                dy,
                dz,
                irx,
                iry,
                irz,
                t,
                ray_t_max[i],
                scene_lo,
                scene_hi,
                occ_lo,
                occ_cell,
                occ_res,
                occ_clear,
                counters,
                t_from,
            )
        if seen and past == -math.inf:
            pass  # b and t from the cell seen first
        elif past > -math.inf and fallback >= 0:
            # Only empty voxels ahead, or it misses the scene's box: any node's kernel ends
            # it at once (tetra: 30% and 40% of its eye rays), so the fallback's (the node
            # routing it) does, with no box looked up (9 spans on 3x3: 40% of the routing):
            # handed to the cell it enters, every such ray was a pass to end a ray.
            b = fallback
            if past < math.inf:
                t = past  # resumes past the scene's box
        else:
            b, t = _located_owner(
                ox,
                oy,
                oz,
                dx,
                dy,
                dz,
                irx,
                iry,
                irz,
                t,
                ray_t_max[i],
                los,
                his,
                coords,
                at,
                nc,
                first,
                members,
                scale,
            )
            if -math.inf < past < math.inf:
                t = past
        if b < 0:
            lost += 1
            b = max(fallback, 0)
        dest[i] = b
        t_min[i] = t
        starts[b + 1] += 1
    for b in range(boxes):
        starts[b + 1] += starts[b]
    at = starts[:-1].copy()
    out = np.empty(n, rays.dtype)
    out_t_min = out["t_min"]
    for i in range(n):
        k = at[dest[i]]
        at[dest[i]] += 1
        out[k] = rays[i]
        out_t_min[k] = t_min[i]
    return out, starts, lost
