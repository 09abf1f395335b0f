"""The image's side of a partition: which samples each node makes eye rays for.

Object space gives each node a rectangle of the sample grid (cut even, or where the cost
pre-pass puts the work), or tiles each made by the node whose cell their eye rays enter; image
space deals tiles or bands of rows. Cuts here are sample-grid integers; the cells they lead to
in world space are `host.planning.cells`'.
"""

import numpy as np

from host.scene.derived import kept
from meshnode.engine.camera import eye_rays
from meshnode.engine.counters import N_COUNTERS
from meshnode.engine.locator import owners
from meshnode.engine.mapwalk import skip_empty
from meshnode.engine.occupancy import Occupancy
from meshnode.engine.sky import whole_tiles
from protocols.render import ImageSpec, RenderSpec
from protocols.scene import SceneData

# CPU in ns a node spends on each eye ray it makes, outside the kernels' work units (making,
# routing, depositing it: EYE_NS), and on an eye ray of the sky all in (its kernel's miss
# too: SKY_NS). Fitted on tetra 3x3's nine nodes at 573 spp (1.9-6.8 M eye rays each, 0-3.5 M
# of the sky): frame CPU 0.45 s + 70 ns an eye ray, own or the sky's alike; outside the
# kernels 45 ns an own eye ray, 51 a sky ray; the kernels 19 ns a sky ray.
EYE_NS = 45.0
SKY_NS = 70.0


def splits(n: int, parts: int) -> list[int]:
    """Boundaries of `parts` near-equal ranges of range(n)."""
    return [round(i * n / parts) for i in range(parts + 1)]


def bands(inner, n: int) -> list[int]:
    """Boundaries 0, inner..., n rounded to samples, kept ordered with every band non-empty."""
    out = [0]
    for k, b in enumerate(inner, 1):
        out.append(min(max(int(b), out[-1] + 1), n - (len(inner) + 1 - k)))
    return [*out, n]


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


PROBE = 256  # eye rays along the longer image side that vote for each tile's maker


def _probe(scene: SceneData, cw: int, ch: int, box, occ: Occupancy) -> np.ndarray:
    """`taker_tiles`' cw x ch pinhole eye rays, each from the first voxel of `occ` it meets:
    the same whatever the cells, so made once for a scene, size and map (each of a plan's
    simulations partitions its coarse image: 1 ms of balls 3x3's 16 each); the map held with
    them, so no other takes its id (`partition` hands the scene's kept one). Not to be
    changed."""
    lo, hi = (np.asarray(b, float) for b in box)
    key = ("taker probe", cw, ch, lo.tobytes(), hi.tobytes(), id(occ))
    return kept(scene, key, lambda: (occ, _walked(scene, cw, ch, lo, hi, occ)))[1]


def _walked(scene: SceneData, cw: int, ch: int, lo, hi, occ: Occupancy) -> np.ndarray:
    """`_probe`'s rays, made."""
    probe = eye_rays(scene.view, ImageSpec(width=cw, height=ch))
    skip_empty(probe, lo, hi, *occ, np.zeros(N_COUNTERS, np.int64))
    return probe


def taker_tiles(
    scene: SceneData, spec: RenderSpec, cells, fallback, box, occ: Occupancy, loads=None
) -> tuple[list, list]:
    """Object space: tiles of `plan.tile` samples, each made by the node whose cell most of
    its eye rays enter (a probe of pinhole rays votes, each from the first voxel of the
    occupancy map `occ` over the scene's `box` it meets, as nodes route them), so eye rays
    are made where they are taken on: a node's rectangle's eye rays mostly entered other
    cells (through the scene's top, or cells cut on the work map) and each went there first
    as a passed ray. A tile no probe ray enters goes to the node whose rectangle in
    `fallback` holds its corner, or with `loads` (each node's estimated CPU seconds for the
    render) to the least loaded (`_sky_tiles`), each node's own tiles' eye rays counted in
    (`_eye_seconds`)."""
    (gw, gh), t, nodes = spec.sample_grid, spec.plan.tile, spec.plan.nodes
    scale = max(1, max(gw, gh) // PROBE)
    cw, ch = max(1, gw // scale), max(1, gh // scale)
    taker = owners(_probe(scene, cw, ch, box, occ), *cells)
    ntx, nty = -(-gw // t), -(-gh // t)
    tile = (
        (np.arange(ch) * gh // ch // t)[:, None] * ntx + (np.arange(cw) * gw // cw // t)[None, :]
    ).ravel()
    votes = np.zeros((ntx * nty, nodes), np.int64)
    np.add.at(votes, (tile[taker >= 0], taker[taker >= 0]), 1)
    rects = tile_grid(gw, gh, t)
    owner = votes.argmax(axis=1)
    seen = votes.sum(axis=1) > 0
    sky = np.flatnonzero(~seen)
    if loads is not None:
        made = _eye_seconds(rects, owner, seen, nodes, spec.rays_per_pixel)
        load = np.asarray(loads, float) + made
        owner[sky] = _sky_tiles([rects[i] for i in sky], load, spec.rays_per_pixel)
    else:
        for i in sky.tolist():
            x0, _, y0, _ = rects[i]
            owner[i] = next(
                n for n, (a, b, c, d) in enumerate(fallback) if a <= x0 < b and c <= y0 < d
            )
    return rects, owner.tolist()


def _eye_seconds(rects: list, owner: np.ndarray, seen: np.ndarray, nodes: int, rpp: int):
    """Each node's CPU seconds, at EYE_NS an eye ray, making the eye rays of the tiles it
    takes on (`seen`: those some probe ray enters): outside the pre-pass's work units, which
    count their kernel work only. Left out, the node whose cell the eye faces got the sky
    as well (tetra 3x3: 6.8 M eye rays against 1.9-5.9 M, the busiest by frame CPU)."""
    r = np.asarray(rects, np.int64).reshape(-1, 4)
    area = (r[:, 1] - r[:, 0]) * (r[:, 3] - r[:, 2]) * seen
    return np.bincount(owner, area.astype(float), nodes) * rpp * EYE_NS * 1e-9


def _sky_tiles(rects: list, loads, rays_per_pixel: int) -> np.ndarray:
    """The nodes that make the eye rays of tiles no probe ray enters (the sky), each to the
    node least loaded so far, its `loads` (estimated CPU seconds) plus SKY_NS a sample of
    the sky tiles it was given. Those rays end at once on whatever node makes them, with no
    kernel work to speak of, but making, routing and depositing them costs: left with the
    even rectangles' corner nodes, they made those tetra 3x3's busiest by frame CPU (1.06 s
    against kernels of 0.43 s), and dealt evenly they loaded the node over a teapot too."""
    load = np.asarray(loads, float).copy()
    out = np.empty(len(rects), np.int64)
    for i, (x0, x1, y0, y1) in enumerate(rects):
        n = int(np.argmin(load))
        out[i] = n
        load[n] += (x1 - x0) * (y1 - y0) * rays_per_pixel * SKY_NS * 1e-9
    return out


def spread(takers: list[int], plan, weights=None) -> list[int]:
    """MeshPlan.copies: each tile to the node with the fewest tiles so far among the one
    taking its eye rays on and those holding its engine (its torus neighbours, and every
    node for a shared cell: each traces the tile without passing its rays), ties to the
    taker: the cells the eye rays enter (all at the scene's top, say) no longer decide
    which nodes start with work. Tiles held by fewest nodes are dealt first, so a shared
    cell's (held by all) fill whatever the others left uneven. With `weights` (a tile's
    estimated work, `host.planning.replicas`), the least work so far instead of the fewest
    tiles, the dearest tiles first within each group: a hot cell's holders then share its
    work, not its tile count (teapot 3x3 under a quarter share: the holder dealt the
    spout's tiles carried 0.85 s against its co-holders' 0.21-0.62 s)."""
    near = {t: plan.holders(t) for t in set(takers)}
    w = np.ones(len(takers)) if weights is None else np.asarray(weights, float)
    load = [0.0] * plan.nodes
    owner = [0] * len(takers)
    order = sorted(range(len(takers)), key=lambda i: (len(near[takers[i]]), -w[i]))
    for i in order:  # once per tile
        t = takers[i]
        owner[i] = min(near[t], key=lambda m: (load[m], m != t))
        load[owner[i]] += w[i]
    return owner


def tiles(width: int, height: int, plan, sky=None) -> tuple[list, list]:
    """Image-space rectangles of a width x height sample grid and their nodes: "none", one
    band of rows a node; "static", near-square tiles of `plan.tile` dealt round-robin
    (`static_owners`); "dynamic", dealt by the host (`guided_tiles`, the tiles all `sky`
    not dealt)."""
    if plan.tiles == "none":
        ys = splits(height, plan.nodes)
        return [(0, width, ys[i], ys[i + 1]) for i in range(plan.nodes)], list(range(plan.nodes))
    if plan.dynamic and plan.order == "rows":
        rects = guided_tiles(width, height, plan.tile, plan.nodes * plan.buffer, sky)
        return rects, [i % plan.nodes for i in range(len(rects))]  # dealt by the host
    rects = tile_grid(width, height, plan.tile)
    return rects, static_owners(-(-width // plan.tile), len(rects), plan.nodes)


def guided_tiles(
    width: int, height: int, t: int, last: int, sky=None
) -> list[tuple[int, int, int, int]]:
    """Dynamic tiles, row by row, of t x t samples and, in the last rows (those holding the
    last `last` of them dealt or more), of half that: the tiles dealt last decide how evenly
    the nodes finish, so they are small (simulated 4x4, 256 x 256: gears 15.46 -> 15.93 of
    16, rings 15.37 -> 15.49, the others +0.06-0.09). The tiles all `sky` are dealt to no
    node (`host.planning.skytiles`), so they are not counted: tetra's last rows are sky, and
    its last tiles dealt were t x t (4x4, frame CPU spread 0.25-0.30 s). Where those rows
    would be the whole image, the tiles stay t x t (the tile side is the user's)."""
    per_row, rows = -(-width // t), -(-height // t)
    grid = tile_grid(width, height, t)
    dealt = np.ones(len(grid), bool)
    dealt[whole_tiles(sky, grid)] = False
    from_end = np.cumsum(dealt.reshape(rows, per_row).sum(axis=1)[::-1])
    tail = int(np.searchsorted(from_end, last)) + 1  # tile rows cut in half-size tiles
    if t < 2 or tail >= rows:
        return grid
    split = (rows - tail) * t
    small = tile_grid(width, height - split, t // 2)
    return tile_grid(width, split, t) + [(a, b, c + split, d + split) for a, b, c, d in small]


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
