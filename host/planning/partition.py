"""Cutting the work over a rows x cols mesh: image rectangles, one box of object space per
node, and which objects each node holds (DESIGN.md 5).

Boxes: the two world axes most perpendicular to the view are cut where test rays through the
rectangle boundaries meet the near face of the scene box (or, when the eye is inside the box's
slab, the plane through the view's target), so a rectangle's primary rays enter its node's
cell; outer cells reach the scene bounds, so the cells tile the scene. A node's box is its cell
grown by the overlap percentage of its size: the node holds the box's objects and traces a ray
until it leaves the box, then hands it to the node whose cell holds the exit (so overlap keeps
rays longer on one node, while the cells, not the overlap, decide who takes them on).
The cost pre-pass may cut the cells in object space instead, where its work map puts the work
(`host.planning.balance`); the rectangles then only say who makes which eye rays. Correctness never
depends on the cut: a ray is always handed to a box that holds it (see
`meshnode.engine.trace.owners`); the cut only decides how often.
"""

from dataclasses import replace

import numpy as np

from meshnode.engine.camera import eye_rays, view_basis
from meshnode.engine.counters import N_COUNTERS
from meshnode.engine.grid import grow_box
from meshnode.engine.occupancy import Occupancy, occupancy_arrays, skip_empty
from meshnode.engine.tables import build_tables, segments
from meshnode.engine.trace import owners
from protocols.render import EVERYWHERE, MAX_OCC_SIDE, ImageSpec, Partition, RenderSpec
from protocols.scene import SceneData, View


def splits(n: int, parts: int) -> list[int]:
    """Boundaries of `parts` near-equal ranges of range(n)."""
    return [round(i * n / parts) for i in range(parts + 1)]


def rectangles(
    width: int, height: int, rows: int, cols: int, xs=None, ys=None
) -> list[tuple[int, int, int, int]]:
    """(x0, x1, y0, y1) of each node's part of a width x height sample grid, node = r*cols+c;
    column boundaries `xs` and row boundaries `ys` (default: even), one list for every
    column or a list per column (`column_rows`)."""
    if rows > height or cols > width:
        raise ValueError(f"a {rows}x{cols} mesh needs at least {cols}x{rows} samples")
    xs = xs or splits(width, cols)
    yss = column_rows(ys, height, rows, cols)
    return [(xs[c], xs[c + 1], yss[c][r], yss[c][r + 1]) for r in range(rows) for c in range(cols)]


def column_rows(ys, height: int, rows: int, cols: int) -> list[list[int]]:
    """Row boundaries of each column of nodes: `ys` is None (even), one list shared by every
    column, or one list per column (each column of nodes cut where its own work lies: a
    scene whose work gathers in one place cannot be shared out by cuts common to all)."""
    if ys is None:
        ys = splits(height, rows)
    if len(ys) and isinstance(ys[0], (list, tuple, np.ndarray)):
        if len(ys) != cols:
            raise ValueError(f"{len(ys)} columns of row cuts for {cols} columns of nodes")
        return [list(y) for y in ys]
    return [list(ys)] * cols


def scene_box(scene: SceneData) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of every object, padded as the grid pads them."""
    tb = build_tables(scene)
    if not tb.n:
        return np.zeros(3), np.ones(3)
    return grow_box(tb.lo.min(axis=0), tb.hi.max(axis=0))


def _cuts(view: View, width, height, bounds, lo, hi, n_parts, along, image_axis):
    """Cut positions on world axis `along` for the sample-grid boundaries on `image_axis`."""
    eye, fwd, right, up, step = view_basis(view, width, height)
    depth = int(np.argmax(np.abs(fwd)))
    face = lo[depth] if fwd[depth] > 0 else hi[depth]  # the near face
    if (face - eye[depth]) * fwd[depth] <= 0:
        # The eye is inside the box's slab on this axis: cut where the view is aimed instead.
        face = float(np.clip(view.at[depth], lo[depth], hi[depth]))
    cuts = []
    for b in bounds[1:-1]:
        # A ray through the boundary on the image's centre line.
        px = (b - 0.5 * width) * step if image_axis == 0 else 0.0
        py = (0.5 * height - b) * step if image_axis == 1 else 0.0
        d = fwd + px * right + py * up
        if abs(d[depth]) < 1e-12:
            cuts.append(None)
            continue
        t = (face - eye[depth]) / d[depth]
        cuts.append(float(eye[along] + t * d[along]))
    if any(c is None for c in cuts) or len(set(np.sign(np.diff(cuts)))) > 1:
        # Degenerate view: fall back to equal slices.
        cuts = list(lo[along] + (hi[along] - lo[along]) * np.arange(1, n_parts) / n_parts)
    cuts = np.clip(cuts, lo[along], hi[along])
    if len(cuts) and cuts[0] > cuts[-1]:  # the image axis runs against the world axis
        return np.concatenate([[hi[along]], cuts, [lo[along]]])
    return np.concatenate([[lo[along]], cuts, [hi[along]]])


def node_cells(
    scene: SceneData, box, width: int, height: int, rows: int, cols: int, xs=None, ys=None
):
    """(los, his), each (rows*cols, 3): node r*cols+c's cell of object space, cut where rays
    through the rectangles' boundaries (`xs`, `ys` as `rectangles` takes them; default even)
    meet the scene. The cells tile the scene's box."""
    lo, hi = (np.asarray(b, float) for b in box)
    col_axis, row_axis = cell_axes(scene.view, width, height)
    xs = xs or splits(width, cols)
    xcuts = _cuts(scene.view, width, height, xs, lo, hi, cols, col_axis, 0)
    ycuts = [
        _cuts(scene.view, width, height, ys_c, lo, hi, rows, row_axis, 1)
        for ys_c in column_rows(ys, height, rows, cols)
    ]
    return cells_from_cuts(box, (col_axis, row_axis), xcuts, ycuts)


def cell_axes(view: View, width: int, height: int) -> tuple[int, int]:
    """(column axis, row axis): the world axes cells are cut along, the two most
    perpendicular to the view; columns follow the one closest to the image's `right`."""
    _, fwd, right, _, _ = view_basis(view, width, height)
    depth = int(np.argmax(np.abs(fwd)))
    others = [a for a in range(3) if a != depth]
    col_axis = max(others, key=lambda a: abs(right[a]))
    return col_axis, [a for a in others if a != col_axis][0]


def cells_from_cuts(box, axes: tuple[int, int], xcuts, ycuts) -> tuple[np.ndarray, np.ndarray]:
    """(los, his) of rows x cols cells of `box`: column c between world positions xcuts[c]
    and xcuts[c + 1] on axes[0], its row r between ycuts[c][r] and ycuts[c][r + 1] on axes[1]
    (each list running either way); the third axis spans the box."""
    lo, hi = (np.asarray(b, float) for b in box)
    cols, rows = len(xcuts) - 1, len(ycuts[0]) - 1
    col_axis, row_axis = axes
    los = np.tile(lo, (rows * cols, 1))
    his = np.tile(hi, (rows * cols, 1))
    for r in range(rows):
        for c in range(cols):
            n = r * cols + c
            xa, xb = sorted((xcuts[c], xcuts[c + 1]))
            ya, yb = sorted((ycuts[c][r], ycuts[c][r + 1]))
            los[n, col_axis], his[n, col_axis] = xa, xb
            los[n, row_axis], his[n, row_axis] = ya, yb
    return los, his


def grown(los: np.ndarray, his: np.ndarray, overlap: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes grown by `overlap` percent of their size on every side: what each node holds
    and traces (its cell only decides which rays it takes on)."""
    if overlap < 0:
        raise ValueError("overlap must not be negative")
    grow = (his - los) * (overlap / 100.0)
    return los - grow, his + grow


def _flat_shapes(scene: SceneData, tb):
    """Triangles then polygons as one vertex list: (vertices, first vertex, count) per shape.
    A polygon's vertices are moved along its dropped axis onto the plane the engine hits it
    on (through the first vertex, Newell normal): for a polygon that is not quite flat, that
    is the shape the engine tests, not the outline of the vertices."""
    tri = scene.triangles["v"].reshape(-1, 3)
    poly = scene.polygons
    n_vert = poly["count"].astype(np.int64)
    counts = np.concatenate([np.full(len(scene.triangles), 3), n_vert]).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    rows, _, owner, _ = segments(poly["start"], n_vert)
    pv = scene.vertices[rows].reshape(-1, 3).copy()
    if len(pv):
        p0, n = tb.polygons[owner, :3], tb.polygons[owner, 3:6]
        info = tb.poly_info[owner]
        drop = 3 - info[:, 2] - info[:, 3]  # the axis that is neither u nor v
        at = np.arange(len(pv))
        off = ((pv - p0) * n).sum(axis=1)  # distance off the plane, times |n| = 1
        pv[at, drop] -= off / n[at, drop]
    return np.concatenate([tri, pv]), starts, counts


def _edges_separate(verts, starts, counts, lo, hi) -> np.ndarray:
    """Per shape: does some axis edge x box-axis separate it from the box [lo, hi]?"""
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    _, _, shape_of, nxt = segments(starts, counts)
    edges = verts[nxt] - verts  # edge j of its shape, one per vertex
    # Every (edge, vertex of the same shape) pair: each edge's axes project its whole shape.
    per_edge = counts[shape_of]
    pair_vert, edge_first, pair_edge, _ = segments(np.repeat(starts, counts), per_edge)
    rel = verts[pair_vert] - centre
    apart = np.zeros(len(verts), np.bool_)
    for k in range(3):
        axis = np.cross(edges, np.eye(3)[k])
        reach = (np.abs(axis) @ half) * (1 + 1e-9) + 1e-12  # a zero axis separates nothing
        proj = (rel * axis[pair_edge]).sum(axis=1)
        apart |= np.minimum.reduceat(proj, edge_first) > reach
        apart |= np.maximum.reduceat(proj, edge_first) < -reach
    return np.logical_or.reduceat(apart, starts)


def _edge_separated(scene: SceneData, tb, los, his, candidates: np.ndarray) -> np.ndarray:
    """(boxes, flat shapes) bool: the separating-axis tests that bounds and plane tests leave
    out (edges crossed with the box axes), run only on each box's remaining candidates. With
    those, exact for triangles and convex polygons; a concave polygon may be kept needlessly."""
    verts, starts, counts = _flat_shapes(scene, tb)
    separated = np.zeros(candidates.shape, np.bool_)
    for b in range(len(los)):  # one pass per node box, over the shapes its bounds admit
        idx = np.flatnonzero(candidates[b])
        if len(idx):
            rows, first, _, _ = segments(starts[idx], counts[idx])
            separated[b, idx] = _edges_separate(verts[rows], first, counts[idx], los[b], his[b])
    return separated


def holders(scene: SceneData, los: np.ndarray, his: np.ndarray) -> np.ndarray:
    """(boxes, objects) bool: which boxes each object touches, objects in the engine's local
    order (spheres, triangles, polygons, cones). Bounds must overlap; spheres must also reach
    the box; triangles and polygons must pass the separating-axis tests (their plane, and
    their edges crossed with the box axes); cones only their bounds (conservative: a node may
    hold an object it never meets, never miss one it does)."""
    tb = build_tables(scene)
    touch = (tb.lo[None] <= his[:, None]) & (tb.hi[None] >= los[:, None])
    touch = touch.all(axis=2)
    centre, half = (los + his) / 2, (his - los) / 2
    if tb.spheres is not None:
        s = tb.spheres
        gap = np.maximum(np.abs(s[None, :, :3] - centre[:, None]) - half[:, None], 0.0)
        reach = (gap**2).sum(axis=2) <= (s[None, :, 3] * (1 + 1e-9)) ** 2
        touch[:, : len(s)] &= reach
    for table, first, n_col in ((tb.triangles, tb.offsets[1], 9), (tb.polygons, tb.offsets[2], 3)):
        if table is None:
            continue
        p0, n = table[:, :3], table[:, n_col : n_col + 3]
        dist = np.abs(((centre[:, None] - p0[None]) * n[None]).sum(axis=2))
        reach = (np.abs(n)[None] * half[:, None]).sum(axis=2)
        touch[:, first : first + len(table)] &= dist <= reach * (1 + 1e-9) + 1e-12
    a, b = tb.offsets[1], tb.offsets[3]  # triangles and polygons
    if b > a:
        touch[:, a:b] &= ~_edge_separated(scene, tb, los, his, touch[:, a:b])
    return touch


def subset(scene: SceneData, keep: np.ndarray) -> SceneData:
    """The scene restricted to objects `keep` (engine local order), gids and materials kept."""
    counts = [len(scene.spheres), len(scene.triangles), len(scene.polygons), len(scene.cones)]
    parts = np.split(keep, np.cumsum(counts)[:-1])
    polys = scene.polygons[parts[2]].copy()
    rows, new_start, _, _ = segments(polys["start"], polys["count"])  # kept vertices, in order
    polys["start"] = new_start
    return replace(
        scene,
        spheres=scene.spheres[parts[0]],
        triangles=scene.triangles[parts[1]],
        polygons=polys,
        vertices=scene.vertices[rows].reshape(-1, 3),
        cones=scene.cones[parts[3]],
    )


def partition(
    scene: SceneData, spec: RenderSpec, xs=None, ys=None, cells=None, occupancy: bool = True
) -> tuple[Partition, np.ndarray]:
    """The plan made concrete: every node's rectangles of the sample grid and its box, and
    which objects each node holds (nodes x objects, bool). Object space: one rectangle a
    node, cut at `xs`, `ys` (default even); cells (los, his) as given (cut where the work
    lies: `host.planning.balance`), else cut to match the rectangles; the scene's occupancy map
    unless `occupancy` is False (where walking it costs more than the passes it saves:
    `host.planning.balance`). Image space: tiles, every box the scene's, every object on every
    node."""
    plan, (width, height) = spec.plan, spec.image.size
    gw, gh = spec.sample_grid
    box = scene_box(scene)
    if plan.mode == "image":
        rects, owner = tiles(gw, gh, plan)
        los, his = np.tile(box[0], (plan.nodes, 1)), np.tile(box[1], (plan.nodes, 1))
        keep = np.ones((plan.nodes, build_tables(scene).n), bool)
        return Partition.make(rects, los, his, box, owner), keep
    if cells is None:
        cells = node_cells(scene, box, width, height, plan.rows, plan.cols, xs, ys)
    los, his = grown(*cells, plan.overlap)
    occ = occupancy_map(scene, box) if plan.nodes > 1 and occupancy else EVERYWHERE
    rects, owner, takers = rectangles(gw, gh, plan.rows, plan.cols, xs, ys), None, ()
    if plan.nodes > 1 and not spec.adaptive:
        rects, owner = taker_tiles(scene, spec, cells, rects, box, occupancy_arrays(*box, *occ))
        if plan.copies:
            takers, owner = owner, spread(owner, plan)
    return (
        Partition.make(rects, los, his, box, owner, cells, occ, takers),
        holders(scene, *traced(los, his)),
    )


def traced(los: np.ndarray, his: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The space each node traces: its box padded as its engine pads it (`grow_box`). A
    node holds every object that reaches this, not only its box: an object in the padding
    was missed there while the node traced past it and sent the ray on beyond it (balls
    2x2 at 1024x1024, 6 spp: 4 shadow rays in 33 M lit that one node found blocked)."""
    lo, hi = zip(*(grow_box(lo, hi) for lo, hi in zip(los, his, strict=True)), strict=True)
    return np.array(lo), np.array(hi)  # a box at a time, once a plan


ENGINE_BYTES_PER_RECORD_BYTE = 8  # tables and grid of a whole-scene engine (balls: 1.4 MB of
# grid and 0.6 MB of tables over 0.3 MB of records; gears, tetra and teapot alike or less)


def engine_bytes(scene: SceneData) -> int:
    """An engine's memory, estimated from the object records it is built from."""
    tables = (
        scene.spheres,
        scene.triangles,
        scene.polygons,
        scene.vertices,
        scene.cones,
        scene.materials,
        scene.lights,
    )
    return ENGINE_BYTES_PER_RECORD_BYTE * sum(t.nbytes for t in tables)


OCC_VOXELS = 64**3  # voxels in the occupancy map (32^3 skipped less: teapot 3x3 5.78 vs 5.91)


def occupancy_map(scene: SceneData, box, voxels: int = OCC_VOXELS) -> tuple[tuple, bytes]:
    """(voxels per axis, packed bits) of the scene's occupancy map over `box`: about
    `voxels` near-cubic voxels (a flat scene gets layers too), a voxel set where some
    object's bounds, padded as the grid pads a box, reach it (`meshnode.engine.occupancy`:
    conservative, so a node that skips what the map calls empty misses nothing). Every
    object's range of voxels is marked at its eight corners and summed along the three
    axes: no loop per object."""
    tb = build_tables(scene)
    lo, hi = (np.asarray(b, float) for b in box)
    ext = hi - lo
    thick = np.maximum(ext, 1e-3 * ext.max())
    res = np.clip(np.round(thick * (voxels / thick.prod()) ** (1 / 3)), 1, MAX_OCC_SIDE)
    res = res.astype(np.int64)
    diff = np.zeros(tuple((res + 1)[::-1]), np.int64)  # z, y, x: x fastest once flattened
    if tb.n:
        pad = 1e-6 * float(ext.max()) + 1e-12 * np.maximum(np.abs(tb.lo), np.abs(tb.hi))
        cell = ext / res
        first = np.clip(np.floor((tb.lo - pad - lo) / cell), 0, res - 1).astype(np.int64)
        last = np.clip(np.floor((tb.hi + pad - lo) / cell), 0, res - 1).astype(np.int64) + 1
        for corner in range(8):
            at = [np.where(corner >> a & 1, last[:, a], first[:, a]) for a in range(3)]
            np.add.at(diff, (at[2], at[1], at[0]), (-1) ** bin(corner).count("1"))
    full = diff.cumsum(0).cumsum(1).cumsum(2)[:-1, :-1, :-1] > 0
    return tuple(res.tolist()), np.packbits(full.ravel()).tobytes()


PROBE = 256  # eye rays along the longer image side that vote for each tile's maker


def taker_tiles(
    scene: SceneData, spec: RenderSpec, cells, fallback, box, occ: Occupancy
) -> tuple[list, list]:
    """Object space: tiles of `plan.tile` samples, each made by the node whose cell most of
    its eye rays enter (a probe of pinhole rays votes, each from the first voxel of the
    occupancy map `occ` over the scene's `box` it meets, as nodes route them), so eye rays
    are made where they are taken on: a node's rectangle's eye rays mostly entered other
    cells (through the scene's top, or cells cut on the work map) and each went there first
    as a passed ray. A tile no probe ray enters goes to the node whose rectangle in
    `fallback` holds its corner."""
    (gw, gh), t, nodes = spec.sample_grid, spec.plan.tile, spec.plan.nodes
    scale = max(1, max(gw, gh) // PROBE)
    cw, ch = max(1, gw // scale), max(1, gh // scale)
    probe = eye_rays(scene.view, ImageSpec(width=cw, height=ch))
    skip_empty(probe, *(np.asarray(b, float) for b in box), *occ, np.zeros(N_COUNTERS, np.int64))
    taker = owners(probe, *cells)
    ntx, nty = -(-gw // t), -(-gh // t)
    tile = (
        (np.arange(ch) * gh // ch // t)[:, None] * ntx + (np.arange(cw) * gw // cw // t)[None, :]
    ).ravel()
    votes = np.zeros((ntx * nty, nodes), np.int64)
    np.add.at(votes, (tile[taker >= 0], taker[taker >= 0]), 1)
    rects = tile_grid(gw, gh, t)
    owner = votes.argmax(axis=1)
    for i in np.flatnonzero(votes.sum(axis=1) == 0).tolist():
        x0, _, y0, _ = rects[i]
        owner[i] = next(n for n, (a, b, c, d) in enumerate(fallback) if a <= x0 < b and c <= y0 < d)
    return rects, owner.tolist()


def spread(takers: list[int], plan) -> list[int]:
    """MeshPlan.copies: each tile to the node with the fewest tiles so far among the one
    taking its eye rays on and those holding its engine (its torus neighbours, and every
    node for a shared cell: each traces the tile without passing its rays), ties to the
    taker: the cells the eye rays enter (all at the scene's top, say) no longer decide
    which nodes start with work. Tiles held by fewest nodes are dealt first, so a shared
    cell's (held by all) fill whatever the others left uneven."""
    near = {t: plan.holders(t) for t in set(takers)}
    count = [0] * plan.nodes
    owner = [0] * len(takers)
    for i in sorted(range(len(takers)), key=lambda i: len(near[takers[i]])):  # once per tile
        t = takers[i]
        owner[i] = min(near[t], key=lambda m: (count[m], m != t))
        count[owner[i]] += 1
    return owner


def tiles(width: int, height: int, plan) -> tuple[list, list]:
    """Image-space rectangles of a width x height sample grid and their nodes: "none", one
    band of rows a node; "static", near-square tiles of `plan.tile` dealt round-robin
    (`static_owners`)."""
    if plan.tiles == "none":
        ys = splits(height, plan.nodes)
        return [(0, width, ys[i], ys[i + 1]) for i in range(plan.nodes)], list(range(plan.nodes))
    rects = tile_grid(width, height, plan.tile)
    return rects, static_owners(-(-width // plan.tile), len(rects), plan.nodes)


def static_owners(columns: int, count: int, nodes: int) -> list[int]:
    """Tiles dealt round-robin in row order; where the tile columns divide the nodes, that
    gives each node one column of the image (predicted 8x8 on 64 columns: 29-42 against
    about 60 with dynamic tiles), so there they are dealt round-robin along the
    anti-diagonals instead: as even a count, every node across the columns. (Where they
    only share a factor, each node keeps several columns: the anti-diagonals predicted
    worse there, 4x4 on 26 columns 12.8 against 14.0 on balls.)"""
    i = np.arange(count)
    if nodes % columns:
        return (i % nodes).tolist()
    order = np.lexsort((i // columns, i // columns + i % columns))  # by diagonal, then row
    owner = np.empty(count, np.int64)
    owner[order] = i % nodes
    return owner.tolist()


def tile_grid(width: int, height: int, t: int) -> list[tuple[int, int, int, int]]:
    """Tiles of t x t samples (the last of a row or column cut short), row by row."""
    return [
        (x, min(x + t, width), y, min(y + t, height))
        for y in range(0, height, t)
        for x in range(0, width, t)
    ]
