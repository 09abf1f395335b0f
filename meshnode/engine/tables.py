"""Kernel tables built from a `SceneData`: one float table per primitive kind, or None.

A kind that is absent is passed to the kernels as None, and numba compiles a variant with that
kind's code pruned away: a triangle-only node never runs sphere or cone code in its inner loop.
Objects get a local id in the order spheres, triangles, polygons, cones; `gid` and `mat` map a
local id back to the scene.
"""

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from protocols.scene import OBJECT_KINDS, SceneData

SPHERE_COLS, TRIANGLE_COLS, POLYGON_COLS, CONE_COLS = 5, 9, 12, 10
# Polygon row columns after p0 and the normal: where band 0 starts in v, bands per unit of v;
# then a centre (u, v) and the squared radii of a disc inside the polygon (-1: none) and of
# one around it (`polygon_discs`).
POLY_VMIN, POLY_BAND_SCALE, POLY_CU, POLY_CV, POLY_IN2, POLY_OUT2 = 6, 7, 8, 9, 10, 11
# The discs are shrunk (the inner) and grown (the outer) by this share of the outer radius:
# a point they decide lies that far from every edge, where the crossing test's round-off
# (ulps of the polygon's coordinates) cannot reach, so both answer alike.
DISC_MARGIN = 1e-7
# Polygons with at least this many vertices get bands (a quad's four edges cost less than a
# band lookup); about two vertices per band, at most MAX_BANDS. Bands are kept only where a
# band lists at most 1/MIN_SAVING of the edges on average, and all bands together at most
# MAX_LISTINGS entries per vertex (`polygon_bands`).
BAND_MIN_VERTICES, MAX_BANDS, MIN_SAVING, MAX_LISTINGS = 12, 256, 8, 64
# Columns of a materials row and of a lights row (MAT_RGB, LIGHT_POS and LIGHT_RGB: the first
# of three).
MAT_RGB, MAT_KD, MAT_KS, MAT_SHINE, MAT_TRANSMIT, MAT_IOR, MAT_COLS = 0, 3, 4, 5, 6, 7, 8
LIGHT_POS, LIGHT_RGB, LIGHT_COLS = 0, 3, 6


class Geometry(NamedTuple):
    """The objects as the intersection kernels read them; row layouts in `intersect.py`.

    A kind the node does not hold is None. numba compiles out an `x is None` branch only when x
    is an argument of the compiled function that branches (inlined code included), never a
    field of a tuple: so the kernels that branch on kinds, or inline code that does
    (`traverse.walk` and `brute_force`, `shade.normals`, `voxelize._touches`), take these fields
    as arguments; the tracing entry points take the whole tuple and pass its fields on."""

    gid: np.ndarray  # (n,) int32 scene object id per local id
    off: np.ndarray  # (5,) int64 first local id of spheres, triangles, polygons, cones; then n
    sph: np.ndarray | None  # (ns, SPHERE_COLS)
    tri: np.ndarray | None  # (nt, TRIANGLE_COLS)
    poly: np.ndarray | None  # (np, POLYGON_COLS) plane rows
    pinfo: np.ndarray | None  # (np, 6) int64 start count axis_u axis_v first_band bands
    puv: np.ndarray | None  # (nv, 2) polygon vertices in their plane, relative to p0
    pband: np.ndarray | None  # (nb,) int64 band offsets then edge lists (`polygon_bands`)
    cone: np.ndarray | None  # (nc, CONE_COLS)


class Shading(NamedTuple):
    """What the tracing kernel reads at a hit, besides the lights and transmittances (which
    stay arguments of their own: None compiles out shadow rays and refraction)."""

    mat: np.ndarray  # (n,) int32 material per local id
    materials: np.ndarray  # (m, MAT_COLS) columns MAT_RGB ... MAT_IOR
    tri_n: np.ndarray | None  # (nt, 9) vertex normals, None when every triangle is flat
    ambient: float  # intensity of the ambient term
    background: np.ndarray  # (3,) colour of rays that escape
    max_depth: int  # rays at this depth spawn no reflected or refracted rays
    t_eps: float  # secondary rays start here: absorbs round-off, not a scene-sized epsilon


@dataclass
class Tables:
    """Everything the kernels read about the objects of one node."""

    spheres: np.ndarray | None  # (ns, 5)
    triangles: np.ndarray | None  # (nt, 12)
    tri_normals: np.ndarray | None  # (nt, 9) vertex normals, only if some triangle is smooth
    polygons: np.ndarray | None  # (np, POLYGON_COLS)
    poly_info: np.ndarray | None  # (np, 6) int64 start count axis_u axis_v first_band bands
    poly_uv: np.ndarray | None  # (nv, 2) vertices in the polygon plane, relative to p0
    poly_bands: np.ndarray | None  # (nb,) int64 band offsets then edge lists
    cones: np.ndarray | None  # (nc, 10)
    gid: np.ndarray  # (n,) int32 scene object id per local id
    mat: np.ndarray  # (n,) int32 material per local id
    lo: np.ndarray  # (n, 3) object bounds
    hi: np.ndarray  # (n, 3)
    offsets: np.ndarray  # (5,) int64 first local id of each kind, plus n
    materials: np.ndarray  # (m, MAT_COLS) columns MAT_RGB ... MAT_IOR
    lights: np.ndarray | None  # (L, LIGHT_COLS) position, intensity-scaled colour
    kinds: tuple[str, ...]
    transmitters: bool

    @property
    def n(self) -> int:
        return len(self.gid)

    @property
    def objects(self) -> int:
        """How many distinct scene ids (an object straddling kinds' tables counts once):
        len(np.unique(gid)) without its hash table (0.8 s on a million ids), and without a
        sort where the ids increase."""
        gid = self.gid
        if len(gid) < 2 or bool(np.all(gid[1:] > gid[:-1])):
            return len(gid)
        ordered = np.sort(gid)
        return 1 + int(np.count_nonzero(ordered[1:] != ordered[:-1]))

    def permuted(self, order: np.ndarray) -> "Tables":
        """These tables with local id j holding the object of old id order[j]; `order` must
        keep every kind in its own range. A hierarchy orders its leaves so: each leaf is then
        a run of consecutive ids, its rows side by side in memory."""
        order = np.asarray(order, np.int64)
        off = self.offsets
        for k in range(4):
            run = order[off[k] : off[k + 1]]
            if len(run) and (run.min() < off[k] or run.max() >= off[k + 1]):
                raise ValueError("a permutation of local ids must keep each kind in its range")

        # (np.take gathers rows 2x faster than indexing with an array)
        def rows(table, k):
            return None if table is None else np.take(table, order[off[k] : off[k + 1]] - off[k], 0)

        return replace(
            self,
            spheres=rows(self.spheres, 0),
            triangles=rows(self.triangles, 1),
            tri_normals=rows(self.tri_normals, 1),
            polygons=rows(self.polygons, 2),
            poly_info=rows(self.poly_info, 2),
            cones=rows(self.cones, 3),
            gid=np.take(self.gid, order),
            mat=np.take(self.mat, order),
            lo=np.take(self.lo, order, 0),
            hi=np.take(self.hi, order, 0),
        )

    def geometry(self) -> Geometry:
        """The object tables as the intersection kernels take them."""
        return Geometry(
            self.gid,
            self.offsets,
            self.spheres,
            self.triangles,
            self.polygons,
            self.poly_info,
            self.poly_uv,
            self.poly_bands,
            self.cones,
        )


def _or_none(a: np.ndarray) -> np.ndarray | None:
    return np.ascontiguousarray(a) if len(a) else None


def _visibility(radius: np.ndarray, transmits: np.ndarray) -> np.ndarray:
    """+1 outside visible, -1 inside visible, 0 both (transmitters are two-sided)."""
    vis = np.where(radius < 0.0, -1.0, 1.0)
    return np.where(transmits, 0.0, vis)


def segments(starts: np.ndarray, counts: np.ndarray):
    """Gather segments (segment i: rows starts[i] .. starts[i] + counts[i] - 1) one after the
    other: (source row of every member, each segment's first position, each member's segment,
    the position of each member's cyclic successor in its segment - a polygon's next vertex)."""
    starts, counts = np.asarray(starts, np.int64), np.asarray(counts, np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    owner = np.repeat(np.arange(len(counts)), counts)
    at = np.arange(len(owner))
    pos = at - first[owner]
    rows = starts[owner] + pos
    nxt = np.where(pos + 1 < counts[owner], at + 1, first[owner])
    return rows, first, owner, nxt


def _polygon_tables(scene: SceneData):
    """Plane rows, info rows, projected vertices and bounds, as segment operations over every
    polygon's vertices at once (no loop per polygon)."""
    polys = scene.polygons
    n_poly = len(polys)
    counts = polys["count"].astype(np.int64)
    total = int(counts.sum()) if n_poly else 0
    if total == 0:
        z3 = np.zeros((0, 3))
        none = np.zeros((0, POLYGON_COLS)), np.zeros((0, 6), np.int64), np.zeros((0, 2))
        return *none, np.zeros(0, np.int64), z3, z3
    rows, at, owner, succ = segments(polys["start"], counts)
    v = scene.vertices[rows]
    nxt = v[succ]
    # Newell's normal from all vertices: robust when the first ones are near-collinear.
    terms = np.stack(
        [
            (v[:, 1] - nxt[:, 1]) * (v[:, 2] + nxt[:, 2]),
            (v[:, 2] - nxt[:, 2]) * (v[:, 0] + nxt[:, 0]),
            (v[:, 0] - nxt[:, 0]) * (v[:, 1] + nxt[:, 1]),
        ],
        axis=1,
    )
    n = np.add.reduceat(terms, at, axis=0)
    n /= np.linalg.norm(n, axis=1)[:, None]
    drop = np.argmax(np.abs(n), axis=1)  # project onto the plane of the other two axes
    au = np.where(drop == 0, 1, 0)
    av = np.where(drop == 2, 1, 2)
    p0 = v[at]
    rel = v - p0[owner]
    uv = np.column_stack([rel[np.arange(total), au[owner]], rel[np.arange(total), av[owner]]])
    vmin, scale, first, bands, table = polygon_bands(uv, at, counts, owner, succ)
    rows = np.column_stack([p0, n, vmin, scale, *polygon_discs(uv, at, counts, owner, succ)])
    info = np.column_stack([at, counts, au, av, first, bands]).astype(np.int64)
    lo = np.minimum.reduceat(v, at, axis=0)
    hi = np.maximum.reduceat(v, at, axis=0)
    return rows, info, uv, table, lo, hi


def polygon_discs(uv, at, counts, owner, succ):
    """Per polygon: centre (u, v), the squared radius of a disc about it inside the polygon
    (-1 when the centre is outside, as in a C) and of one holding every vertex. A point in the
    inner disc is inside and one beyond the outer outside, whatever the crossing test would
    add up (a gear face's test costs its band's edges; most of its hits land in the disc).
    The centre is the vertices' mean; both radii keep DISC_MARGIN clear of every edge."""
    c = np.add.reduceat(uv, at, axis=0) / counts[:, None]
    rel, nxt = uv - c[owner], uv[succ] - c[owner]
    out = np.sqrt(np.maximum.reduceat((rel * rel).sum(axis=1), at))
    # The centre's crossings of each edge to its right (the kernel's half-open rule).
    du, dv = nxt[:, 0] - rel[:, 0], nxt[:, 1] - rel[:, 1]
    spans = (rel[:, 1] > 0.0) != (nxt[:, 1] > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = spans & (0.0 < du * (0.0 - rel[:, 1]) / dv + rel[:, 0])
        # Distance from the centre to each edge: its nearest point, clamped to the edge.
        s = np.clip(-(rel * np.column_stack([du, dv])).sum(axis=1) / (du * du + dv * dv), 0, 1)
    s = np.nan_to_num(s)
    near = np.hypot(rel[:, 0] + s * du, rel[:, 1] + s * dv)
    inside = np.add.reduceat(cross.astype(np.int64), at) % 2 == 1
    r_in = np.minimum.reduceat(near, at) - DISC_MARGIN * out
    in2 = np.where(inside & (r_in > 0.0), r_in * r_in, -1.0)
    out2 = (out * (1.0 + DISC_MARGIN)) ** 2
    return c[:, 0], c[:, 1], in2, out2


def band_of(v, vmin, scale, bands):
    """The band holding v, as the kernel computes it (monotone in v, so an edge whose v range
    holds v is listed in v's band when it is listed in the bands of its two ends and between)."""
    return np.clip(np.floor((v - vmin) * scale), 0, bands - 1)


def polygon_bands(uv, at, counts, owner, succ):
    """Per polygon: v of band 0, bands per unit of v, first offset in the table and band count
    (0: test every edge); the table: each band's offset into it (one past the last band: the
    end) then each band's edges, named by their end vertex's row, in vertex order. A polygon
    whose bands would each list many of its edges (a comb of tall teeth: every band crosses
    every tooth) keeps the every-edge test: bands would not pay, and the table stays linear in
    the vertices."""
    v = uv[:, 1]
    vmin = np.minimum.reduceat(v, at)
    height = np.maximum.reduceat(v, at) - vmin
    bands = np.where(counts >= BAND_MIN_VERTICES, np.minimum(counts // 2, MAX_BANDS), 0)
    with np.errstate(divide="ignore", over="ignore"):
        scale = np.where(height > 0.0, bands / np.where(height > 0.0, height, 1.0), 0.0)
    bands = np.where(np.isfinite(scale) & (scale > 0.0), bands, 0).astype(np.int64)
    # Edge k runs from vertex k's predecessor to vertex k: pred is k's position in `succ`.
    pred = np.empty(len(v), np.int64)
    pred[succ] = np.arange(len(v))
    ends, o, b_lo, span = _edge_bands(v, pred, owner, vmin, scale, bands)
    listed = np.bincount(o, weights=span, minlength=len(counts))
    crowded = (listed * MIN_SAVING > counts * np.maximum(bands, 1)) | (
        listed > MAX_LISTINGS * counts
    )
    if crowded.any():
        bands[crowded] = 0
        ends, o, b_lo, span = _edge_bands(v, pred, owner, vmin, scale, bands)
    scale = np.where(bands > 0, scale, 0.0)
    # Global band ids: the polygon's first band plus the band; one entry per (edge, band).
    band0 = np.concatenate([[0], np.cumsum(bands)[:-1]]).astype(np.int64)
    n_bands = int(bands.sum())
    gband, _, listing_of, _ = segments(band0[o] + b_lo, span)  # edge listing_of[i] in gband[i]
    edge = ends[listing_of]
    order = np.argsort(gband, kind="stable")  # by band, edges in vertex order within it
    per_band = np.bincount(gband, minlength=n_bands)
    offsets = (n_bands + 1) + np.concatenate([[0], np.cumsum(per_band)])
    table = np.concatenate([offsets, edge[order]]).astype(np.int64) if n_bands else offsets[:0]
    first = np.where(bands > 0, band0, 0)
    return vmin, scale, first, bands, table


def _edge_bands(v, pred, owner, vmin, scale, bands):
    """Edges of the banded polygons (by end vertex), their polygon, first band and number of
    bands they are listed in."""
    ends = np.flatnonzero(bands[owner] > 0)
    o = owner[ends]
    lo_v = np.minimum(v[ends], v[pred[ends]])
    hi_v = np.maximum(v[ends], v[pred[ends]])
    b_lo = band_of(lo_v, vmin[o], scale[o], bands[o]).astype(np.int64)
    b_hi = band_of(hi_v, vmin[o], scale[o], bands[o]).astype(np.int64)
    return ends, o, b_lo, b_hi - b_lo + 1


def _cone_tables(scene: SceneData, transmits):
    c = scene.cones
    base, apex = c["base"], c["apex"]
    axis = apex - base
    length = np.linalg.norm(axis, axis=1)
    a = axis / length[:, None]
    r0, r1 = np.abs(c["base_r"]), np.abs(c["apex_r"])
    inside = (c["base_r"] < 0) | (c["apex_r"] < 0)
    vis = _visibility(np.where(inside, -1.0, 1.0), transmits)
    rows = np.column_stack([base, a, length, r0, (r1 - r0) / length, vis])
    # Bounds of the two rim circles: extent along world axis i is r * sqrt(1 - a_i^2).
    ext = np.sqrt(np.clip(1.0 - a * a, 0.0, 1.0))
    lo = np.minimum(base - r0[:, None] * ext, apex - r1[:, None] * ext)
    hi = np.maximum(base + r0[:, None] * ext, apex + r1[:, None] * ext)
    return rows, lo, hi


def triangle_normals(tri: np.ndarray) -> np.ndarray:
    """(nt, 3) unit geometric normals e1 x e2 of triangle rows, zero for zero-area ones (patch
    poles, never hit): the rows keep none (`intersect.triangle_normal`, the same bits)."""
    n = np.cross(tri[:, 3:6], tri[:, 6:9])
    length = np.linalg.norm(n, axis=1)[:, None]
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def build_tables(scene: SceneData) -> Tables:
    """Convert scene records into kernel tables (vectorised: no loop per object)."""
    mats = scene.materials
    materials = np.empty((len(mats), MAT_COLS))
    materials[:, MAT_RGB : MAT_RGB + 3] = mats["rgb"]
    for col, field in (
        (MAT_KD, "kd"),
        (MAT_KS, "ks"),
        (MAT_SHINE, "shine"),
        (MAT_TRANSMIT, "t"),
        (MAT_IOR, "ior"),
    ):
        materials[:, col] = mats[field]
    transmits_mat = materials[:, MAT_TRANSMIT] > 0.0

    s = scene.spheres
    sph = np.column_stack(
        [s["center"], np.abs(s["radius"]), _visibility(s["radius"], transmits_mat[s["mat"]])]
    ).reshape(-1, SPHERE_COLS)
    sph_lo = s["center"] - np.abs(s["radius"])[:, None]
    sph_hi = s["center"] + np.abs(s["radius"])[:, None]

    t = scene.triangles
    v = t["v"]
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    # No normal column: a row is what a hit test reads (72 bytes, not 96 with the normal,
    # read only at the closest hit: `intersect.triangle_normal`).
    tri = np.column_stack([v[:, 0], e1, e2]).reshape(-1, TRIANGLE_COLS)
    smooth = bool(len(t)) and bool(t["smooth"].any())
    tri_n = t["n"].reshape(-1, 9) if smooth else np.zeros((0, 9))
    # vertex by vertex: numpy's v.min(axis=1) across the middle axis is 4x slower
    tri_lo = np.minimum(np.minimum(v[:, 0], v[:, 1]), v[:, 2])
    tri_hi = np.maximum(np.maximum(v[:, 0], v[:, 1]), v[:, 2])

    poly, info, uv, bands, pl_lo, pl_hi = _polygon_tables(scene)
    cone, cn_lo, cn_hi = _cone_tables(scene, transmits_mat[scene.cones["mat"]])

    groups = (s, t, scene.polygons, scene.cones)
    counts = [len(g) for g in groups]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    lights = None
    if len(scene.lights):
        # SPD rule: every light (and the ambient term) has intensity sqrt(L) / (2 L).
        scale = np.sqrt(len(scene.lights)) / (2.0 * len(scene.lights))
        lights = np.empty((len(scene.lights), LIGHT_COLS))
        lights[:, LIGHT_POS : LIGHT_POS + 3] = scene.lights["pos"]
        lights[:, LIGHT_RGB : LIGHT_RGB + 3] = scene.lights["rgb"] * scale
    names = OBJECT_KINDS
    return Tables(
        spheres=_or_none(sph),
        triangles=_or_none(tri),
        tri_normals=_or_none(tri_n) if smooth else None,
        polygons=_or_none(poly),
        poly_info=_or_none(info),
        poly_uv=_or_none(uv) if len(poly) else None,
        # Never None beside polygons: a kernel reads it whenever it reads them.
        poly_bands=np.ascontiguousarray(bands) if len(poly) else None,
        cones=_or_none(cone),
        gid=np.concatenate([g["gid"] for g in groups]).astype(np.int32),
        mat=np.concatenate([g["mat"] for g in groups]).astype(np.int32),
        lo=np.concatenate([sph_lo, tri_lo, pl_lo, cn_lo]).reshape(-1, 3),
        hi=np.concatenate([sph_hi, tri_hi, pl_hi, cn_hi]).reshape(-1, 3),
        offsets=offsets,
        materials=materials if len(materials) else np.zeros((1, MAT_COLS)),
        lights=lights,
        kinds=tuple(nm for nm, c in zip(names, counts, strict=False) if c),
        transmitters=any(bool(transmits_mat[g["mat"]].any()) for g in groups if len(g)),
    )
