"""Who takes a ray on: the cell (box) where its work goes on, and batches regrouped by it
(`routed`), as a node routes its eye rays and the segments leaving its box; the cell is
found on the arrangement of the cells' faces (`meshnode.engine.locator`)."""

import math

import numpy as np

from meshnode.engine.counters import N_COUNTERS
from meshnode.engine.jit import inline, kernel
from meshnode.engine.locator import located_owner
from meshnode.engine.mapwalk import past_box, work_start
from meshnode.engine.sightlines import eye_cell
from meshnode.engine.traverse import box_span


@inline
def _first_cell_start(
    ox, oy, oz, rx, ry, rz, t_min, t_max, c, others, los, his, scene_lo, scene_hi
):
    """(cell, t, past) as `routed` has them for an eye ray whose block sees cell c's parts of
    occupied voxels nearest and no other cell's nearer than `others` (`EyeMap.first`); cell
    -1 where the walk must tell: entering c before `others`, it meets no voxel before c's
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
    occ_lo, occ_cell, occ_res, occ_clear, occ_fine = occ
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
            occ_fine,
            counters,
            -math.inf,
        )
        if past == -math.inf:
            out[i], _ = located_owner(
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
    t_min on to where its work starts (`mapwalk.work_start` on the `Occupancy` occ; a ray
    with only empty voxels ahead resumes past the scene's box), as (a new array, the runs'
    starts): box b's run is out[starts[b]:starts[b + 1]], in the order the rays came. A ray
    no box takes, with only empty voxels ahead or missing the scene's box (with `skip`),
    joins box `fallback`'s run; with fallback
    -1 the first is counted (the third value) for the caller to refuse and the second goes
    to the box it enters. `rays` is left as it was. `eye`: an `sightlines.EyeMap` of these
    rays (pinhole eye rays by RAY.pixel) or `NO_EYE_MAP`; a ray through a block of it that
    sees no occupied voxel gets t_min inf (the kernel ends it at once, as it would past the
    scene's box).

    One pass where a node made five over every batch (a copy, skip_empty, owners, an argsort
    and a split): simulated tetra 3x3, those took 2x the tracing kernel's CPU."""
    occ_lo, occ_cell, occ_res, occ_clear, occ_fine = occ
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
        if skip and eye.near.shape[0] and not ids_from <= pixel[i] < ids_to:
            ids_from, ids_to, t_from, nearest, others = eye_cell(eye, pixel[i])
        if t_from == math.inf and fallback >= 0:
            # Its block sees no occupied voxel: it meets nothing, and the fallback's kernel
            # ends it at once (t_min inf) with no span or walk made here (tetra 3x3: 43% of
            # its eye rays, 29 ns a ray here and 35 in the kernel, where it was sent past
            # the scene's box to be ended there).
            dest[i] = fallback
            t_min[i] = math.inf
            starts[fallback + 1] += 1
            continue
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        irx = 1.0 / dx if dx != 0.0 else math.inf
        iry = 1.0 / dy if dy != 0.0 else math.inf
        irz = 1.0 / dz if dz != 0.0 else math.inf
        t, past = ray_t_min[i], -math.inf
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
                occ_fine,
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
            b, t = located_owner(
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
