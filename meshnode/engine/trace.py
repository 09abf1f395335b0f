"""The batch driver: rays in, colour per input ray and ray counts out.

Each input ray's tree is traced depth-first on a small local stack. Colour flows forward: a ray
carries its weight, every hit deposits `weight * ambient`, spawns one shadow ray per light the
surface faces (carrying the light's diffuse + specular share, deposited only if the light is
reached) and reflected / refracted rays carrying `weight * Ks` and `weight * T`.

Over the 400 lines a module may have, on purpose: numba inlines only what one compilation unit
sees, and each kernel here is compiled once per variant (minutes on a cold cache), so the
driver and the segment walk stay together where their shared helpers inline instead of being
called across modules on every ray segment. Routing rays to the node that takes them on is a
kernel of its own (`meshnode.engine.routing`).
"""

import math

import numpy as np

from meshnode.engine.bvh import NEAR_ZERO, bvh_walk
from meshnode.engine.bvh import STACK as BVH_STACK
from meshnode.engine.counters import (
    ESCAPED,
    EYE_HITS,
    FORWARDED,
    HITS,
    INTERNAL,
    REFLECTED_RAYS,
    REFRACTED_RAYS,
    SEGMENTS,
    SHADOW_BLOCKED,
    SHADOW_LIT,
    SHADOW_RAYS,
)
from meshnode.engine.jit import inline, kernel
from meshnode.engine.lightmaps import light_clear
from meshnode.engine.mapwalk import first_occupied
from meshnode.engine.packet import (
    P_BEST,
    P_R,
    PACKET,
    keep_packets,
    load_ray,
    packet_scratch,
    packet_walk,
)
from meshnode.engine.shade import normals, phong, phongs, refract
from meshnode.engine.tables import LIGHT_POS, LIGHT_RGB, MAT_IOR, MAT_KD, MAT_KS, MAT_RGB, MAT_SHINE
from meshnode.engine.traverse import brute_force, two_spans, walk
from protocols.dtypes import EYE, REFLECTED, REFRACTED, SHADOW

HINT_SLOTS = 1 << 14  # the shadow cache's largest size (`hint_slots`)
# A shadow ray's highlight inputs (its stack row `sx`, a highlight log row): diffuse share
# per channel, then Ks (0: no highlight pending, the weights are final), cos, exponent.
_KS, _C, _SHINE, _HILITE = 3, 4, 5, 6
LOG_ROWS = 1024  # deposits logged before they are summed (`_settle`): a log that stays in cache


@kernel
def hint_slots(pairs):
    """Slots of the shadow cache: a power of two covering every (object, light) pair, at
    most HINT_SLOTS (a table that stays in cache)."""
    n = 1
    while n < pairs and n < HINT_SLOTS:
        n *= 2
    return n


@inline
def _push(
    so, sd, sw, st, sk, sp, px, py, pz, dx, dy, dz, w0, w1, w2, t_lo, t_hi, kind, depth, gid, light
):
    """Push a secondary ray onto the ray tree's stack (columns as the stack's arrays say);
    returns the new stack height."""
    so[sp, 0], so[sp, 1], so[sp, 2] = px, py, pz
    sd[sp, 0], sd[sp, 1], sd[sp, 2] = dx, dy, dz
    sw[sp, 0], sw[sp, 1], sw[sp, 2] = w0, w1, w2
    st[sp, 0], st[sp, 1] = t_lo, t_hi
    sk[sp, 0], sk[sp, 1], sk[sp, 2], sk[sp, 3] = kind, depth, gid, light
    return sp + 1


@kernel
def _packet_hits(rays, on, counters, geo, bvh, out):
    """With `on`, the first hit (t, local id) of each of the batch's rays but shadow rays,
    PACKET neighbours at a time (`packet_walk`): what walking each alone finds; local id -2
    for the rays left to walk alone, once packets stop paying (`keep_packets`) and for
    shadow rays. Without, empty arrays. On a mesh node (`out` not None) also each walked
    ray's reciprocal direction (`reciprocal`), for its spans: dividing again put three
    divisions' latency at the head of every segment (tetra 3x3: 8% of a node's time)."""
    gid, off, sph, tri, poly, pinfo, puv, pband, cone = geo
    n = rays.shape[0] if on else 0
    first_t = np.empty(n)
    first_u = np.full(n, -2, np.int64)
    first_r = np.empty((n if out is not None else 0, 3))
    f, origin, best_u, pstack, refs, idx = packet_scratch()
    m = walked = entered = tested = 0
    for i in range(n):
        r = rays[i]
        if r.kind != SHADOW and r.t_min < math.inf:  # routed past everything: no walk
            load_ray(
                f,
                origin,
                m,
                r.o[0],
                r.o[1],
                r.o[2],
                r.d[0],
                r.d[1],
                r.d[2],
                r.t_min,
                r.t_max,
                r.origin,
            )
            idx[m] = i
            m += 1
        if m == PACKET or (i == n - 1 and m > 0):
            e, v = packet_walk(
                f,
                origin,
                best_u,
                m,
                pstack,
                refs,
                counters,
                gid,
                off,
                sph,
                tri,
                poly,
                pinfo,
                puv,
                pband,
                cone,
                bvh,
            )
            for j in range(m):
                first_t[idx[j]] = f[P_BEST, j]
                first_u[idx[j]] = best_u[j]
                if out is not None:
                    k = idx[j]
                    first_r[k, 0], first_r[k, 1] = f[P_R, j], f[P_R + 1, j]
                    first_r[k, 2] = f[P_R + 2, j]
            m = 0
            walked += 1
            entered += e
            tested += v
            if not keep_packets(walked, entered, tested, bvh[0]):
                break
    return first_t, first_u, first_r


@inline
def _span_reciprocal(d, r):
    """1/d for a span (inf for d == 0) from r = `reciprocal`(d): the same number wherever d
    is not near zero, so the division is made once."""
    if abs(d) >= NEAR_ZERO:
        return r
    return 1.0 / d if d != 0.0 else math.inf


@kernel
def _push_out(
    out, n, ox, oy, oz, dx, dy, dz, wr, wg, wb, t_min, t_max, pixel, origin, depth, kind, light
):
    """Write a ray that continues on another node at slot n, growing `out` when full."""
    if n == out.shape[0]:
        grown = np.empty(2 * out.shape[0] + 16, out.dtype)
        grown[:n] = out[:n]
        out = grown
    q = out[n]
    q.o[0], q.o[1], q.o[2] = ox, oy, oz
    q.d[0], q.d[1], q.d[2] = dx, dy, dz
    q.w[0], q.w[1], q.w[2] = wr, wg, wb
    q.t_min, q.t_max = t_min, t_max
    q.pixel, q.origin, q.depth, q.kind, q.light = pixel, origin, depth, kind, light
    return out


@inline
def _lit(wr, wg, wb, x, q):
    """A shadow ray's weights once its highlight is known: w * (diffuse + specular), the
    shading loop's arithmetic, from row q of x (`_HILITE` columns)."""
    spec = x[q, _KS] * phong(x[q, _C], x[q, _SHINE])
    return wr * (x[q, 0] + spec), wg * (x[q, 1] + spec), wb * (x[q, 2] + spec)


@inline
def _log(lg, n, v0, v1, v2, k):
    """Deposit row n of the log: its colour, or a highlight's weights and the highlight's
    index k (-1: none); returns the next row."""
    lg[n, 0], lg[n, 1], lg[n, 2], lg[n, 3] = v0, v1, v2, k
    return n + 1


@inline
def _summed(lg, hk, ph, lo, hi, cr, cg, cb):
    """cr, cg, cb plus the logged deposits lo..hi in their order, each highlight's
    (`ph`: the powers, `hk`: diffuse shares and Ks) as the shading loop would have made it."""
    for j in range(lo, hi):
        k = int(lg[j, 3])
        if k < 0:
            cr += lg[j, 0]
            cg += lg[j, 1]
            cb += lg[j, 2]
        else:
            spec = hk[k, 3] * ph[k]
            cr += lg[j, 0] * (hk[k, 0] + spec)
            cg += lg[j, 1] * (hk[k, 1] + spec)
            cb += lg[j, 2] * (hk[k, 2] + spec)
    return cr, cg, cb


@kernel
def _settle(out_rgb, trees, n_trees, lg, hk, hc, hs, ph, n_hl, lo, n_log, cr, cg, cb):
    """Every logged deposit summed: the log's highlights in one vector loop (`phongs`), then
    each finished tree's deposits onto its prefix (trees: prefix, ray, log rows) into
    out_rgb, and the unfinished tree's (rows lo..n_log; lo -1: none) onto cr, cg, cb,
    returned: the same sums the loop makes with each highlight at hand."""
    phongs(hc, hs, ph, n_hl)
    for t in range(n_trees):
        r, g, b = _summed(
            lg, hk, ph, int(trees[t, 4]), int(trees[t, 5]), trees[t, 0], trees[t, 1], trees[t, 2]
        )
        i = int(trees[t, 3])
        out_rgb[i, 0] += r
        out_rgb[i, 1] += g
        out_rgb[i, 2] += b
    if lo >= 0:
        cr, cg, cb = _summed(lg, hk, ph, lo, n_log, cr, cg, cb)
    return cr, cg, cb


@kernel
def trace_batch(
    rays,
    out_rgb,
    counters,
    brute,
    geo,
    grid,
    shading,
    transmit,
    lights,
    scene_lo,
    scene_hi,
    out,
    bvh,
    in_packets,
    occ,
    box,
    light_near,
):
    """Trace every ray of `rays` (RAY records) and its whole tree; add colour to out_rgb[i].

    The objects are the `Geometry` geo in the `BvhArrays` bvh, or with bvh None the
    `GridArrays` grid (or all tested, with brute), shaded by the `Shading` shading. The
    structure is a type, like the kinds: the one passed None is compiled out, its walk and
    all (`variants.Variant.structure`). `lights` (rows by LIGHT_* columns) None compiles out
    shadow rays, `transmit` (each material's transmittance) None compiles out refraction.
    `box` (corner, voxel size, voxels per axis: the grid's, or a one-voxel box's beside a
    hierarchy, `grid.box_only`) is the node's box.

    On a mesh node `out` is a RAY array: a segment that is not in this node's box
    where it starts, or leaves it before ending, is written there with t_min where to resume
    (origin and direction unchanged, so every node computes the same t), and the grown array
    and the count written are returned. A hit beyond the box is not trusted (an object held
    elsewhere may come first); a shadow ray blocked by any object it meets is blocked.
    With `out` None (one node, box = scene) this code is compiled out. `in_packets`: a
    batch's own rays may find their first hits in packets (with a hierarchy). `occ`: the
    scene's `Occupancy` map; a segment with nothing but empty voxels ahead of it ends here
    instead of going on, one that goes on resumes at the first occupied voxel
    (`meshnode.engine.occupancy`)."""
    # Fields into locals once: numba counts references at each read of a tuple's field, and
    # reads in the ray loop made balls and rings trace 10% slower.
    gid, off, sph, tri, poly, pinfo, puv, pband, cone = geo
    mat, materials, tri_n, amb, background, max_depth, t_eps = shading
    glo, cell, res = box
    occ_lo, occ_cell, occ_res, occ_clear, occ_fine = occ
    n_lights = 0 if lights is None else lights.shape[0]
    cap = int(max_depth) * (n_lights + 2) + 4
    so = np.empty((cap, 3))
    sd = np.empty((cap, 3))
    sw = np.empty((cap, 3))
    st = np.empty((cap, 2))
    sk = np.empty((cap, 5), np.int64)  # kind, depth, origin gid, light, hint slot
    # the grid's mailbox (one stamp an object); a hierarchy has none: n int64 to fill per
    # batch, and 8 MB of cache lines pushed out, on the million-triangle tetrahedron
    mail = np.full(gid.shape[0] if bvh is None else 0, -1, np.int64)
    stack = np.empty(2 * BVH_STACK)
    # With a hierarchy the batch's own rays (all but shadow rays) find their first hits in
    # packets of neighbours (`_packet_hits`) before their trees are traced one by one. Each
    # is the walk the loop below would make (same span, same origin); on an object-space
    # node a hit beyond the box is then dropped as a walk's would be, and the hit of a ray
    # that starts outside the box is never read (it goes on first).
    if bvh is not None:
        packets = in_packets
        first_t, first_u, first_r = _packet_hits(rays, packets, counters, geo, bvh, out)
    else:
        packets = False
        first_t, first_u, first_r = np.empty(0), np.empty(0, np.int64), np.empty((0, 3))
    # Shadow cache: the object that last blocked a shadow ray from the same object towards
    # the same light is tried first (walk's hint), one slot per (object, light) pair, or per
    # pair modulo HINT_SLOTS: one slot per light was overwritten between the shadow rays of
    # one surface by those of the surfaces its reflected and refracted rays met (gears: 37%
    # of blocked rays found by the hint).
    hint_mask = hint_slots(gid.shape[0] * max(n_lights, 1)) - 1
    blocker = np.full(hint_mask + 1, -1, np.int64)
    # Highlights wait until their shadow ray is found lit, and are then computed
    # LOG_ROWS at a time in vector code (`_settle`): a ray tree's deposits from its first
    # such shadow ray on are logged (lg: colour, or weights and highlight index; hk, hc,
    # hs: the highlights' inputs) to be summed in their order once the powers are known;
    # trees: the finished ones' prefix, ray and log rows. Each row count is at most n_log.
    sx = np.empty((cap, _HILITE))
    lg = np.empty((LOG_ROWS, 4))
    hk = np.empty((LOG_ROWS, 4))
    hc = np.empty(LOG_ROWS)
    hs = np.empty(LOG_ROWS)
    ph = np.empty(LOG_ROWS)
    trees = np.empty((LOG_ROWS, 6))
    n_log = n_hl = n_trees = 0
    ray_id = 0
    buf = out  # `out` itself must stay unassigned for numba to prune on `out is None`
    n_out = 0
    ghi0 = glo[0] + cell[0] * res[0]
    ghi1 = glo[1] + cell[1] * res[1]
    ghi2 = glo[2] + cell[2] * res[2]
    glo0, glo1, glo2 = glo[0], glo[1], glo[2]  # the boxes in locals, read once
    slo0, slo1, slo2 = scene_lo[0], scene_lo[1], scene_lo[2]
    shi0, shi1, shi2 = scene_hi[0], scene_hi[1], scene_hi[2]
    for i in range(rays.shape[0]):
        r = rays[i]
        if out is None and packets and first_u[i] == -1:
            # Its packet found nothing: it escapes, with the deposit and counts the loop
            # below makes, without the trip through the stack (jacks: 94% of its eye rays).
            ray_id += 1
            counters[SEGMENTS] += 1
            counters[ESCAPED] += 1
            cr = 0.0
            cg = 0.0
            cb = 0.0
            cr += r.w[0] * background[0]
            cg += r.w[1] * background[1]
            cb += r.w[2] * background[2]
            out_rgb[i, 0] += cr
            out_rgb[i, 1] += cg
            out_rgb[i, 2] += cb
            continue
        so[0, 0], so[0, 1], so[0, 2] = r.o[0], r.o[1], r.o[2]
        sd[0, 0], sd[0, 1], sd[0, 2] = r.d[0], r.d[1], r.d[2]
        sw[0, 0], sw[0, 1], sw[0, 2] = r.w[0], r.w[1], r.w[2]
        st[0, 0], st[0, 1] = r.t_min, r.t_max
        sk[0, 0], sk[0, 1], sk[0, 2], sk[0, 3] = r.kind, r.depth, r.origin, r.light
        sk[0, 4] = r.light & hint_mask  # its object's local id unknown: the light's own slot
        sx[0, _KS] = 0.0  # a shadow ray from another node carries its final weights
        sp = 1
        cr = 0.0
        cg = 0.0
        cb = 0.0
        logged = -1  # the log row of this tree's first highlight, -1 while none
        root = True  # the first segment popped is the batch's ray itself
        while sp > 0:
            sp -= 1
            ox, oy, oz = so[sp, 0], so[sp, 1], so[sp, 2]
            dx, dy, dz = sd[sp, 0], sd[sp, 1], sd[sp, 2]
            wr, wg, wb = sw[sp, 0], sw[sp, 1], sw[sp, 2]
            t_lo, t_hi = st[sp, 0], st[sp, 1]
            kind, depth, origin, light = sk[sp, 0], sk[sp, 1], sk[sp, 2], sk[sp, 3]
            slot = sk[sp, 4]
            if n_log == LOG_ROWS:  # room for this segment's one deposit
                cr, cg, cb = _settle(
                    out_rgb, trees, n_trees, lg, hk, hc, hs, ph, n_hl, logged, n_log, cr, cg, cb
                )
                n_log = n_hl = n_trees = 0
                logged = -1
            shadow = kind == SHADOW
            # the batch's ray itself, walked in a packet: its hit and reciprocals are known
            in_packet = packets and root and not shadow and first_u[i] > -2
            ray_id += 1
            counters[SEGMENTS] += 1
            clear = False
            if out is not None:
                if in_packet:
                    irx = _span_reciprocal(dx, first_r[i, 0])  # divided in the packet
                    iry = _span_reciprocal(dy, first_r[i, 1])
                    irz = _span_reciprocal(dz, first_r[i, 2])
                else:
                    irx = 1.0 / dx if dx != 0.0 else math.inf
                    iry = 1.0 / dy if dy != 0.0 else math.inf
                    irz = 1.0 / dz if dz != 0.0 else math.inf
                s0, s1, n0, n1 = two_spans(
                    ox,
                    oy,
                    oz,
                    irx,
                    iry,
                    irz,
                    t_lo,
                    t_hi,
                    slo0,
                    slo1,
                    slo2,
                    shi0,
                    shi1,
                    shi2,
                    glo0,
                    glo1,
                    glo2,
                    ghi0,
                    ghi1,
                    ghi2,
                )
                resume = -1.0
                if s0 > s1:
                    n1 = math.inf  # the segment misses the scene: it ends here, below,
                    clear = True  # with nothing to walk (every object is in the scene's box)
                elif n0 > s0 or n1 <= s0:
                    resume = s0  # not in this box where its part inside the scene starts
                    if (
                        first_occupied(
                            ox,
                            oy,
                            oz,
                            dx,
                            dy,
                            dz,
                            irx,
                            iry,
                            irz,
                            s0,
                            s1,
                            occ_lo,
                            occ_cell,
                            occ_res,
                            occ_clear,
                            occ_fine,
                            counters,
                        )
                        == math.inf
                    ):
                        resume = -1.0  # nothing lies ahead: it ends here, below
                        n1 = math.inf
                        clear = True
                if resume >= 0.0:
                    if shadow and sx[sp, _KS] > 0.0:
                        wr, wg, wb = _lit(wr, wg, wb, sx, sp)
                    buf = _push_out(
                        buf,
                        n_out,
                        ox,
                        oy,
                        oz,
                        dx,
                        dy,
                        dz,
                        wr,
                        wg,
                        wb,
                        resume,
                        t_hi,
                        r.pixel,
                        origin,
                        depth,
                        kind,
                        light,
                    )
                    n_out += 1
                    counters[FORWARDED] += 1
                    continue
            if clear:
                t, u = math.inf, -1  # only empty voxels lie ahead
            elif in_packet:
                t, u = first_t[i], first_u[i]
            # Each walk under `is not None` of its own structure: numba prunes a branch on
            # an argument passed None, and types every other (the grid's walk of None fails)
            elif bvh is not None:
                hint = blocker[slot] if shadow else -1
                t, u = bvh_walk(
                    ox,
                    oy,
                    oz,
                    dx,
                    dy,
                    dz,
                    t_lo,
                    t_hi,
                    origin,
                    shadow,
                    hint,
                    stack,
                    counters,
                    gid,
                    off,
                    sph,
                    tri,
                    poly,
                    pinfo,
                    puv,
                    pband,
                    cone,
                    bvh,
                )
            elif grid is not None:
                if brute:
                    t, u = brute_force(
                        ox,
                        oy,
                        oz,
                        dx,
                        dy,
                        dz,
                        t_lo,
                        t_hi,
                        origin,
                        shadow,
                        counters,
                        gid,
                        off,
                        sph,
                        tri,
                        poly,
                        pinfo,
                        puv,
                        pband,
                        cone,
                    )
                else:
                    hint = blocker[slot] if shadow else -1
                    t, u = walk(
                        ox,
                        oy,
                        oz,
                        dx,
                        dy,
                        dz,
                        t_lo,
                        t_hi,
                        origin,
                        shadow,
                        hint,
                        ray_id,
                        mail,
                        counters,
                        gid,
                        off,
                        sph,
                        tri,
                        poly,
                        pinfo,
                        puv,
                        pband,
                        cone,
                        grid,
                    )
            else:  # no structure: never, but numba types each branch
                t, u = math.inf, -1
            root = False
            if out is not None:
                if u >= 0 and not shadow and t > n1:
                    u = -1  # a hit beyond this box: another node may hold a nearer object
                if u < 0 and n1 < s1:
                    # Leaves this box inside the scene: continue on the node owning the first
                    # occupied voxel ahead; with none ahead it ends here, below. A shadow
                    # ray whose way to its light is clear by the map seen from the light
                    # (`light_near`, `lightmaps.light_maps`) needs no walk to know it.
                    t_on = -1.0
                    if lights is not None:
                        if (
                            shadow
                            and light < light_near.shape[0]
                            and light_clear(
                                light_near,
                                light,
                                lights[light, LIGHT_POS],
                                lights[light, LIGHT_POS + 1],
                                lights[light, LIGHT_POS + 2],
                                ox + n1 * dx,
                                oy + n1 * dy,
                                oz + n1 * dz,
                            )
                        ):
                            t_on = math.inf
                    if t_on < 0.0:
                        t_on = first_occupied(
                            ox,
                            oy,
                            oz,
                            dx,
                            dy,
                            dz,
                            irx,
                            iry,
                            irz,
                            n1,
                            s1,
                            occ_lo,
                            occ_cell,
                            occ_res,
                            occ_clear,
                            occ_fine,
                            counters,
                        )
                    if t_on < math.inf:
                        if shadow and sx[sp, _KS] > 0.0:
                            wr, wg, wb = _lit(wr, wg, wb, sx, sp)
                        buf = _push_out(
                            buf,
                            n_out,
                            ox,
                            oy,
                            oz,
                            dx,
                            dy,
                            dz,
                            wr,
                            wg,
                            wb,
                            max(n1, t_on),
                            t_hi,
                            r.pixel,
                            origin,
                            depth,
                            kind,
                            light,
                        )
                        n_out += 1
                        counters[FORWARDED] += 1
                        continue
            if shadow:
                # The light is reached unless something lies in between.
                if u >= 0:
                    counters[SHADOW_BLOCKED] += 1
                    blocker[slot] = u
                else:
                    counters[SHADOW_LIT] += 1
                    if sx[sp, _KS] > 0.0:  # its highlight waits (`_settle`)
                        hk[n_hl, 0], hk[n_hl, 1], hk[n_hl, 2] = sx[sp, 0], sx[sp, 1], sx[sp, 2]
                        hk[n_hl, 3], hc[n_hl], hs[n_hl] = sx[sp, _KS], sx[sp, _C], sx[sp, _SHINE]
                        if logged < 0:
                            logged = n_log
                        n_log = _log(lg, n_log, wr, wg, wb, n_hl)
                        n_hl += 1
                    elif logged >= 0:
                        n_log = _log(lg, n_log, wr, wg, wb, -1)
                    else:
                        cr += wr
                        cg += wg
                        cb += wb
                continue
            if u < 0:
                counters[ESCAPED] += 1
                if logged >= 0:
                    n_log = _log(
                        lg, n_log, wr * background[0], wg * background[1], wb * background[2], -1
                    )
                else:
                    cr += wr * background[0]
                    cg += wg * background[1]
                    cb += wb * background[2]
                continue
            counters[HITS] += 1
            if kind == EYE:
                counters[EYE_HITS] += 1
            px = ox + t * dx
            py = oy + t * dy
            pz = oz + t * dz
            gx, gy, gz, nx, ny, nz = normals(
                u, px, py, pz, ox, oy, oz, dx, dy, dz, off, sph, tri, tri_n, poly, cone
            )
            # Turn both normals toward the incoming ray; remember which side was hit.
            entering = gx * dx + gy * dy + gz * dz < 0.0
            if not entering:
                gx, gy, gz, nx, ny, nz = -gx, -gy, -gz, -nx, -ny, -nz
            m = mat[u]
            kd = materials[m, MAT_KD]
            ks = materials[m, MAT_KS]
            ar = wr * amb * kd * materials[m, MAT_RGB]
            ag = wg * amb * kd * materials[m, MAT_RGB + 1]
            ab = wb * amb * kd * materials[m, MAT_RGB + 2]
            if logged >= 0:
                n_log = _log(lg, n_log, ar, ag, ab, -1)
            else:
                cr += ar
                cg += ag
                cb += ab
            dn = dx * nx + dy * ny + dz * nz
            rx = dx - 2.0 * dn * nx
            ry = dy - 2.0 * dn * ny
            rz = dz - 2.0 * dn * nz
            # Keep directions unit length: the intersection tests assume it, and drift would
            # grow along a reflection chain.
            rn = 1.0 / math.sqrt(rx * rx + ry * ry + rz * rz)
            rx *= rn
            ry *= rn
            rz *= rn
            # A smooth-shaded triangle's normal can tilt so far from its face that the mirror
            # direction points into the surface (teapot_s1's spout: shading normals lie in
            # the face, reflections went inside and came back dark as isolated speckles).
            # Mirror such a direction back above the face; elsewhere this never fires.
            rg = rx * gx + ry * gy + rz * gz
            if rg < 0.0:
                rx -= 2.0 * rg * gx
                ry -= 2.0 * rg * gy
                rz -= 2.0 * rg * gz
            hit_gid = gid[u]
            if lights is not None:
                shine = materials[m, MAT_SHINE]
                for li in range(n_lights):
                    lx = lights[li, LIGHT_POS] - px
                    ly = lights[li, LIGHT_POS + 1] - py
                    lz = lights[li, LIGHT_POS + 2] - pz
                    ln = math.sqrt(lx * lx + ly * ly + lz * lz)
                    lx /= ln
                    ly /= ln
                    lz /= ln
                    cos = lx * nx + ly * ny + lz * nz
                    if cos <= 0.0:
                        continue  # the surface faces away from this light
                    rl = rx * lx + ry * ly + rz * lz
                    hilite = ks > 0.0 and rl > 0.0  # computed once the light is reached
                    counters[SHADOW_RAYS] += 1
                    kr = kd * cos * materials[m, MAT_RGB]
                    kg = kd * cos * materials[m, MAT_RGB + 1]
                    kb = kd * cos * materials[m, MAT_RGB + 2]
                    # with a highlight, the light's share: (diffuse + specular) comes later
                    dr = 1.0 if hilite else kr + 0.0
                    dg = 1.0 if hilite else kg + 0.0
                    db = 1.0 if hilite else kb + 0.0
                    sp = _push(
                        so,
                        sd,
                        sw,
                        st,
                        sk,
                        sp,
                        px,
                        py,
                        pz,
                        lx,
                        ly,
                        lz,
                        wr * lights[li, LIGHT_RGB] * dr,
                        wg * lights[li, LIGHT_RGB + 1] * dg,
                        wb * lights[li, LIGHT_RGB + 2] * db,
                        t_eps,
                        ln,
                        SHADOW,
                        depth + 1,
                        hit_gid,
                        li,
                    )
                    sk[sp - 1, 4] = (u * n_lights + li) & hint_mask
                    sx[sp - 1, 0], sx[sp - 1, 1], sx[sp - 1, 2] = kr, kg, kb
                    sx[sp - 1, _KS] = ks if hilite else 0.0
                    sx[sp - 1, _C], sx[sp - 1, _SHINE] = rl, shine
            if depth >= max_depth:
                continue
            kt = 0.0
            if transmit is not None:
                kt = transmit[m]
            refl = ks
            if kt > 0.0:
                eta = 1.0 / materials[m, MAT_IOR] if entering else materials[m, MAT_IOR]
                ok, tx, ty, tz = refract(dx, dy, dz, nx, ny, nz, eta)
                if ok:
                    counters[REFRACTED_RAYS] += 1
                    sp = _push(
                        so,
                        sd,
                        sw,
                        st,
                        sk,
                        sp,
                        px,
                        py,
                        pz,
                        tx,
                        ty,
                        tz,
                        wr * kt,
                        wg * kt,
                        wb * kt,
                        t_eps,
                        math.inf,
                        REFRACTED,
                        depth + 1,
                        hit_gid,
                        0,
                    )
                else:
                    refl += kt  # total internal reflection: the transmitted share reflects
                    counters[INTERNAL] += 1
            if ks > 0.0 or kt > 0.0:  # SPD: reflective or transmitting surfaces reflect
                counters[REFLECTED_RAYS] += 1
                sp = _push(
                    so,
                    sd,
                    sw,
                    st,
                    sk,
                    sp,
                    px,
                    py,
                    pz,
                    rx,
                    ry,
                    rz,
                    wr * refl,
                    wg * refl,
                    wb * refl,
                    t_eps,
                    math.inf,
                    REFLECTED,
                    depth + 1,
                    hit_gid,
                    0,
                )
        if logged >= 0:
            trees[n_trees, 0], trees[n_trees, 1], trees[n_trees, 2] = cr, cg, cb
            trees[n_trees, 3], trees[n_trees, 4], trees[n_trees, 5] = i, logged, n_log
            n_trees += 1
        else:
            out_rgb[i, 0] += cr
            out_rgb[i, 1] += cg
            out_rgb[i, 2] += cb
    if n_trees > 0:
        _settle(out_rgb, trees, n_trees, lg, hk, hc, hs, ph, n_hl, -1, n_log, 0.0, 0.0, 0.0)
    return buf, n_out
