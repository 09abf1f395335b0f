"""Where to cut the work between mesh nodes, in the image or in object space (DESIGN.md 6,
"cut positions chosen from a cheap pre-pass that estimates cost per region").

A node's work is the rays it traces inside its box, wherever they came from, so the pre-pass
runs the mesh itself on a coarse image: the simulated mesh of `meshnode.mesh.simulator`, whose
nodes decide with the same scheduler as real ones, each node's cost counted as its
intersection tests, voxel steps and segments, with each segment sent on weighted
(`meshnode.mesh.stats.work_units`). The column cuts then move so that the columns of
nodes share the measured cost evenly (cost spread evenly over the pixels of each column band),
the row cuts likewise, and the pass repeats; the cuts with the smallest busiest node win. Two
image families are tried: row cuts shared by every column (boxes in a grid), and row cuts of each
column's own (each column's nodes share that column's work evenly: where the work gathers in
one place, cuts common to all columns leave the node over it with most of it).
A third family cuts object space itself where the work lies, apart from the image: a work
map (the scene's box cut into FINE x FINE cells of equal size along the two cut axes, each
simulated as a node of its own) gives each column of cells an equal share of the work, and
each column's rows likewise (a teapot on a wide floor, a mountain seen from above: cells cut
from the image at the scene's near face leave one node with most of the work). The image's
tiles then follow the cells (`host.planning.partition.taker_tiles`).
Correctness never depends on the cuts, only the balance of work does.
"""

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from host.planning.partition import (
    cell_axes,
    cells_from_cuts,
    column_rows,
    engine_bytes,
    node_cells,
    partition,
    scene_box,
    splits,
    subset,
)
from meshnode.mesh.simulator import simulate
from protocols.camera import CameraSampling, Generation
from protocols.render import ImageSpec, RenderSpec

COARSE = 64  # coarse samples along the longer image axis
FINE = 12  # work map cells along each cut axis
FITS = 0.25  # the share of a node's memory its engine may take (image space when the whole
# scene's does; `--overlap auto` picks among the overlaps whose largest node's does)
OVERLAPS = (2.0, 30.0, 60.0, 100.0)  # `--overlap auto`'s candidates, percent


class Cuts(NamedTuple):
    """Where the pre-pass cuts: the image (`xs`, `ys` as `host.planning.partition.rectangles` takes
    them; None: even), object space (`cells` (los, his), None: from the image cuts), whether
    the nodes get the scene's occupancy map (`occupancy`), the overlap they hold with
    (`overlap`, percent), and why (`report`, for the statistics)."""

    xs: list | None
    ys: list | None
    report: dict
    cells: tuple | None = None
    occupancy: bool = True
    overlap: float = 1.0
    shared: tuple = ()


def _bands(inner, n: int) -> list[int]:
    """Boundaries 0, inner..., n rounded to samples, kept ordered with every band non-empty."""
    out = [0]
    for k, b in enumerate(inner, 1):
        out.append(min(max(int(b), out[-1] + 1), n - (len(inner) + 1 - k)))
    return [*out, n]


def _coarse(bounds: list, n: int, coarse_n: int) -> list:
    """Boundaries on an n-sample axis scaled to a coarse_n-sample one (a list of them: each)."""
    if len(bounds) and isinstance(bounds[0], list):
        return [_coarse(b, n, coarse_n) for b in bounds]
    return _bands([round(b * coarse_n / n) for b in bounds[1:-1]], coarse_n)


def coarse_spec(spec: RenderSpec) -> RenderSpec:
    """The render at COARSE samples across, pixel centres, one centre ray through a camera:
    where work lies, at a fraction of the cost; its tiles (stealing's chunks, the tiles
    dealt under copies) scaled with it, so it deals as many as the render (at 32 samples
    a tile, a 768-sample render's coarse pass had 4 tiles to spread over a 3x3)."""
    width, height = spec.sample_grid
    scale = COARSE / max(width, height)
    plan = replace(spec.plan, tile=max(1, round(spec.plan.tile * scale)))
    image = ImageSpec(
        width=max(plan.cols, round(width * scale)),
        height=max(plan.rows, round(height * scale)),
        depth=spec.image.depth,
    )
    camera = spec.camera
    if camera is not None:
        camera = replace(
            camera,
            sampling=CameraSampling(generation=Generation.CENTRE, rays=1, sampling="uniform"),
        )
    return RenderSpec(image, spec.engine, plan, camera)


def node_costs(scene, spec: RenderSpec, xs, ys, cells=None, occupancy=True) -> np.ndarray:
    """Cost of every node on a coarse image cut at `xs`, `ys` (given on the full sample
    grid; None: even), its cells `cells` (None: from the image cuts), with or without the
    occupancy map: the mesh simulated in this process."""
    coarse, part, scenes = _coarse_mesh(scene, spec, xs, ys, cells, occupancy)
    return np.array([r.cost for r in simulate(scenes, coarse, part).nodes], float)


def _coarse_mesh(scene, spec: RenderSpec, xs, ys, cells=None, occupancy=True):
    """(coarse spec, partition, each node's objects) of the mesh `node_costs` simulates."""
    coarse = coarse_spec(spec)
    (width, height), (cw, ch) = spec.sample_grid, coarse.sample_grid
    xs, ys = xs or splits(width, spec.plan.cols), ys or splits(height, spec.plan.rows)
    part, keep = partition(
        scene, coarse, _coarse(xs, width, cw), _coarse(ys, height, ch), cells, occupancy
    )
    return coarse, part, [subset(scene, keep[n]) for n in range(part.nodes)]


def largest_engine(scene, spec: RenderSpec, xs, ys, cells=None) -> int:
    """Bytes of the largest node's engines with these cuts (`host.planning.partition.engine_bytes`):
    its own, and under MeshPlan.copies its linked neighbours' too."""
    own = [engine_bytes(s) for s in _coarse_mesh(scene, spec, xs, ys, cells)[2]]
    return max(sum(own[m] for m in spec.plan.held(n)) for n in range(spec.plan.nodes))


def choose_holding(
    scene, spec: RenderSpec, xs, ys, cells, busiest: float, overlaps=(), memory: int = 0
) -> tuple[float, bool, dict]:
    """(overlap, occupancy map, report) for the nodes on these cuts, whose busiest node
    simulates at `busiest` with the plan's overlap and the map: the plan's overlap, or
    of `overlaps` (with the plan's) the one whose busiest node simulates least among
    those whose largest node's engine takes at most FITS of `memory` (0: not known, every
    overlap); with the map or without, whichever lightens the busiest node (the map's walk
    costs, in a fractal of many small empty cubes, more than the passes it saves)."""
    plan = spec.plan
    tried, too_big = {}, []
    for overlap in sorted({plan.overlap, *overlaps}):
        at = _at(spec, overlap)
        if overlap != plan.overlap and _too_big(scene, at, xs, ys, cells, memory, too_big):
            continue
        with_map = (
            busiest if overlap == plan.overlap else node_costs(scene, at, xs, ys, cells).max()
        )
        tried[overlap, True] = float(with_map)
        tried[overlap, False] = float(node_costs(scene, at, xs, ys, cells, False).max())
    # ties: the smaller overlap (less held), then the map (fewer rays passed)
    (overlap, occupancy), _ = min(tried.items(), key=lambda t: (t[1], t[0][0], not t[0][1]))
    report = {
        "occupancy_map": occupancy,
        "simulated_busiest_without_map_vs_with": _ratio(
            tried[overlap, False], tried[overlap, True]
        ),
    }
    if overlaps:
        report["overlap"] = _overlap_report(
            overlap, {o: b for (o, m), b in tried.items() if m == occupancy}, too_big, memory
        )
    return overlap, occupancy, report


def _at(spec: RenderSpec, overlap: float) -> RenderSpec:
    return replace(spec, plan=replace(spec.plan, overlap=overlap))


def _too_big(scene, spec: RenderSpec, xs, ys, cells, memory: int, refused: list) -> bool:
    """Whether the largest node's engine would take more than FITS of `memory` (noted in
    `refused`); never when the memory is not known (0)."""
    if not memory:
        return False
    held = largest_engine(scene, spec, xs, ys, cells)
    if held <= FITS * memory:
        return False
    refused.append(
        {"overlap": spec.plan.overlap, "shared": list(spec.plan.shared), "largest_node_bytes": held}
    )
    return True


def _overlap_report(chosen: float, busiest: dict, too_big: list, memory: int) -> dict:
    """What the statistics say of an overlap choice: each overlap's simulated busiest node
    (work units) and against the chosen one's, and those refused for memory."""
    return {
        "chosen": chosen,
        "simulated_busiest": {f"{o:g}": b for o, b in busiest.items()},
        "simulated_busiest_vs_chosen": {
            f"{o:g}": _ratio(b, busiest[chosen]) for o, b in busiest.items()
        },
        "too_big_for_memory": too_big,
        "memory_bytes": memory,
    }


def _ratio(a: float, b: float) -> float:
    return float(a / b) if b else 1.0


def _even_out(seen: list, n: int) -> list[int]:
    """New boundaries giving each band an equal share of the cost, from every cut tried so far
    on this axis: `seen` holds (boundaries, cost of each band) pairs, each a measured point of
    the cost's cumulative share at every boundary; between the points the cost is taken as
    spread evenly. With the points of every round (not the last alone) the cuts close in on
    where the work lies instead of swinging across it (a teapot on a floor: 0.84 of the work
    in one node of a 2x2, and re-cuts from the last round alone never did better than even).
    Every band keeps at least one sample."""
    share = {0: 0.0, n: 1.0}
    for bounds, band_cost in seen:
        cum = np.cumsum(band_cost) / max(float(np.sum(band_cost)), 1e-300)
        share.update(zip(bounds[1:-1], cum[:-1], strict=True))
    at = sorted(share)
    cum = np.maximum.accumulate([share[b] for b in at])  # later rounds may disagree a little
    parts = len(seen[-1][1])
    return _bands(
        np.searchsorted(np.interp(np.arange(n + 1), at, cum), np.arange(1, parts) / parts), n
    )


def work_map(scene, spec: RenderSpec, fine: int = FINE):
    """(axes, column edges, row edges, cost[row, column]): the scene's box cut into fine x
    fine cells of equal size along the cut axes (`host.planning.partition.cell_axes`), each
    simulated as a node without overlap on the coarse image: where in object space the work lies."""
    box = scene_box(scene)
    axes = cell_axes(scene.view, *spec.image.size)
    ex, ey = (np.linspace(box[0][a], box[1][a], fine + 1) for a in axes)
    plan = replace(
        spec.plan,
        rows=fine,
        cols=fine,
        overlap=0.0,
        balance="even",
        steal=False,
        copies=False,
        shared=(),
    )
    cells = cells_from_cuts(box, axes, ex, [ey] * fine)
    cost = node_costs(scene, replace(spec, plan=plan), None, None, cells)
    return axes, ex, ey, cost.reshape(fine, fine)


def _shares(edges: np.ndarray, cost: np.ndarray, parts: int) -> list[float]:
    """Positions along `edges` splitting `cost` (per bin, spread evenly inside each) into
    `parts` equal shares, the ends included."""
    cum = np.concatenate([[0.0], np.cumsum(cost + 1e-9 * max(float(cost.sum()), 1.0))])
    inner = np.interp(np.arange(1, parts) / parts, cum / cum[-1], edges)
    return [float(edges[0]), *inner.tolist(), float(edges[-1])]


def _cover(edges: np.ndarray, a: float, b: float) -> np.ndarray:
    """The share of each bin between `edges` that lies in [a, b] (either order)."""
    a, b = min(a, b), max(a, b)
    return np.clip((np.minimum(edges[1:], b) - np.maximum(edges[:-1], a)) / np.diff(edges), 0, 1)


def map_cells(scene, spec: RenderSpec, axes, ex, ey, cost) -> tuple[np.ndarray, np.ndarray]:
    """Cells giving each column of nodes an equal share of the work map `cost`, and each
    node of a column an equal share of its column's; numbered the way the image's even
    cells run, so where rectangles stay one a node (adaptive sampling) a rectangle's eye
    rays mostly enter its own node's cell."""
    plan, box = spec.plan, scene_box(scene)
    xcuts = _shares(ex, cost.sum(axis=0), plan.cols)
    ycuts = [
        _shares(ey, cost @ _cover(ex, a, b), plan.rows)
        for a, b in zip(xcuts[:-1], xcuts[1:], strict=True)
    ]
    los, _ = node_cells(scene, box, *spec.image.size, plan.rows, plan.cols)
    if plan.cols > 1 and los[0, axes[0]] > los[1, axes[0]]:  # the image runs against x
        xcuts, ycuts = xcuts[::-1], ycuts[::-1]
    if plan.rows > 1 and los[0, axes[1]] > los[plan.cols, axes[1]]:
        ycuts = [y[::-1] for y in ycuts]
    return cells_from_cuts(box, axes, xcuts, ycuts)


def _corrected(axes, ex, ey, cost, cells, measured) -> np.ndarray:
    """The work map with each node's part scaled to the cost the node was measured at:
    the map counts the work of small cells (more rays passed, none kept by an overlap)."""
    scale = np.zeros_like(cost)
    for lo, hi, got in zip(*cells, measured, strict=True):
        share = np.outer(_cover(ey, lo[axes[1]], hi[axes[1]]), _cover(ex, lo[axes[0]], hi[axes[0]]))
        mapped = float((share * cost).sum())
        scale += share * (got / mapped if mapped > 0 else 1.0)  # no mapped work: nothing to scale
    return cost * scale


FAMILIES = ("shared rows", "rows per column", "work map")


def balanced_cuts(
    scene, spec: RenderSpec, rounds: int = 2, families=FAMILIES, overlaps=(), memory: int = 0
) -> Cuts:
    """The cuts whose simulated busiest node is the least loaded, of those each family tried
    in `rounds` re-cuts: image cuts from even ones with row cuts shared by all columns or
    with each column's own (`ys` is then a list per column), and cells cut on the work map
    (`map_cells`), corrected by each round's measured costs; at the plan's overlap, or at
    each of `overlaps` too, keeping the overlap whose best cuts simulate least among those
    whose largest node's engine takes at most FITS of `memory` (a wider overlap keeps rays
    longer on a node at the price of objects held twice, and moves where the cuts are best:
    the teapot 3x3 simulated 3.51 at overlap 2 and 5.73 at 60, each on its own cuts); then,
    on those cuts, whether the nodes get the occupancy map (`choose_holding`) and under
    copies which cells every node holds (`choose_shared`)."""
    plan = spec.plan
    work: dict = {}  # the work map, simulated once: it has no overlap
    found, too_big = {}, []
    for overlap in sorted({plan.overlap, *overlaps}):
        at = _at(spec, overlap)
        tried = _tries(scene, at, rounds, families, work)
        best = min(tried, key=lambda t: t[0])
        if overlap != plan.overlap and _too_big(scene, at, *best[1:3], best[5], memory, too_big):
            continue
        found[overlap] = best, tried
    overlap = min(found, key=lambda o: (found[o][0][0], o))  # ties: the smaller overlap
    (best, bx, by, cost, family, cells), tried = found[overlap]
    base = tried[0][0] or 1.0
    _, occupancy, holding = choose_holding(scene, _at(spec, overlap), bx, by, cells, best)
    report = {
        "columns": bx,
        "rows": by,
        "family": family,
        "simulated_busiest_vs_even": best / base,
        "simulated_busiest_vs_even_by_family": {  # the best of each: why this one
            f: min((t[0] for t in tried if t[4] == f), default=base) / base for f in families
        },
        "simulated_imbalance": float((cost.max() - cost.min()) / cost.max()) if best else 0.0,
        **holding,
    }
    if overlaps:
        report["overlap"] = _overlap_report(
            overlap, {o: f[0][0] for o, f in found.items()}, too_big, memory
        )
    # the busiest node on these cuts with the map as chosen (`best` had the map)
    busiest = best if occupancy else best * holding["simulated_busiest_without_map_vs_with"]
    at = _at(spec, overlap)
    shared, report["shared"] = choose_shared(
        scene, at, bx, by, cells, occupancy, busiest, memory, _efficiency(cost)
    )
    if report["shared"].get("tried") and family != "even":  # maybe better on even cuts
        even_cost = (
            tried[0][3]
            if occupancy
            # even cuts were simulated with the map
            else node_costs(scene, at, None, None, None, occupancy)
        )
        base = float(even_cost.max())
        even, on_even = choose_shared(
            scene, at, None, None, None, occupancy, base, memory, _efficiency(even_cost)
        )
        if even and _best(on_even) * base < _best(report["shared"]) * busiest:
            bx = by = cells = None
            report.update(
                columns=None,
                rows=None,
                family="even",
                simulated_busiest_vs_even=base / tried[0][0] if tried[0][0] else 1.0,
                simulated_imbalance=float((even_cost.max() - even_cost.min()) / even_cost.max())
                if base
                else 0.0,
            )
            shared = even
            report["shared"] = {**on_even, "cuts": f"even: they do better shared than {family}'s"}
    return Cuts(bx, by, report, cells, occupancy, overlap, shared)


def _best(report: dict) -> float:
    """The simulated busiest node with the shared cells chosen, against none shared."""
    return report["simulated_busiest_vs_none"][",".join(map(str, report["chosen"])) or "none"]


def _efficiency(cost: np.ndarray) -> float:
    """Sum of node costs / (nodes x busiest): 1 when every node works as long."""
    return float(cost.sum() / (len(cost) * cost.max())) if cost.max() > 0 else 1.0


SHARE_TRIES = 4  # cells tried alone as the shared one (those taking most tiles' eye rays)
SHARE_GAIN = 0.98  # a shared cell is kept when it lowers the simulated busiest node this much
SHARE_BELOW = 0.95  # ... tried only below this simulated parallel efficiency (gears' coarse
# pass takes seconds a try, and its cuts already even out its work)


def choose_shared(
    scene,
    spec: RenderSpec,
    xs,
    ys,
    cells,
    occupancy: bool,
    busiest: float,
    memory: int = 0,
    efficiency: float = 0.0,
) -> tuple[tuple, dict]:
    """(MeshPlan.shared, report): under copies, the cells whose engines every node also
    holds. Where the eye rays of most tiles enter one cell (a small scene under a wide
    view, a teapot on a floor), only that cell's four neighbours hold its engine, so at most
    five nodes share its work whatever is stolen. Each of the SHARE_TRIES cells taking the
    most tiles is simulated shared on its own, the best kept if it lowers the busiest node
    by SHARE_GAIN, and then the next ones added while each does so; never past FITS of
    `memory` (0: not known) for the largest node's engines; not tried where the cuts'
    simulated `efficiency` is SHARE_BELOW or more already."""
    plan = spec.plan
    if (
        not plan.copies
        or spec.adaptive
        or all(len(plan.held(n)) == plan.nodes for n in range(plan.nodes))
    ):
        return (), {}  # adaptive rectangles stay with their nodes; 1x2, 1x3: all held
    if efficiency >= SHARE_BELOW:
        return (), {"chosen": [], "tried": False, "simulated_efficiency": efficiency}
    part, _ = partition(scene, spec, xs, ys, cells, occupancy)
    taken = np.bincount(np.asarray(part.takers or part.owner, np.int64), minlength=plan.nodes)
    order = [int(c) for c in np.argsort(-taken, kind="stable")[:SHARE_TRIES] if taken[c]]
    tried, too_big = {(): float(busiest)}, []

    def cost(shared: tuple) -> float | None:
        at = replace(spec, plan=replace(plan, shared=shared))
        if _too_big(scene, at, xs, ys, cells, memory, too_big):
            return None
        tried[shared] = float(node_costs(scene, at, xs, ys, cells, occupancy).max())
        return tried[shared]

    alone = {c: b for c in order if (b := cost((c,))) is not None}
    chosen: tuple = ()
    if alone and min(alone.values()) <= SHARE_GAIN * busiest:
        first = min(alone, key=lambda c: (alone[c], c))
        chosen = (first,)
        for c in sorted(alone, key=lambda c: (alone[c], c)):
            if c == first:
                continue
            b = cost((*chosen, c))
            if b is None or b > SHARE_GAIN * tried[chosen]:
                break
            chosen = (*chosen, c)
    report = {
        "chosen": list(chosen),
        "tried": True,
        "simulated_efficiency": efficiency,
        "tiles_taken": taken.tolist(),
        "simulated_busiest_vs_none": {
            ",".join(map(str, k)) or "none": _ratio(v, busiest) for k, v in tried.items()
        },
        "too_big_for_memory": too_big,
    }
    return chosen, report


def _tries(scene, spec: RenderSpec, rounds: int, families, work: dict) -> list[tuple]:
    """(busiest, xs, ys, costs, family, cells) of even cuts and of every family's re-cuts."""
    plan = spec.plan
    even = node_costs(scene, spec, None, None)
    tried = [(float(even.max()), None, None, even, "even", None)]
    for family in families:
        if family == "work map":
            tried += _map_tries(scene, spec, rounds, work)
        elif family == "shared rows" or plan.rows > 1 and plan.cols > 1:
            tried += _image_tries(scene, spec, rounds, family == "rows per column", even)
    return tried


def _image_tries(scene, spec: RenderSpec, rounds: int, own_rows: bool, cost) -> list[tuple]:
    """(busiest, xs, ys, costs, family, None) of each re-cut of the image from even cuts
    (whose node costs are `cost`)."""
    (width, height), plan = spec.sample_grid, spec.plan
    family = "rows per column" if own_rows else "shared rows"
    xs, ys = splits(width, plan.cols), splits(height, plan.rows)
    seen_x: list = []
    seen_y: list = [[] for _ in range(plan.cols)] if own_rows else []
    tried = []
    for _ in range(rounds):
        grid = cost.reshape(plan.rows, plan.cols)
        seen_x.append((xs, grid.sum(axis=0)))
        if own_rows:
            rows = column_rows(ys, height, plan.rows, plan.cols)
            for c in range(plan.cols):
                seen_y[c].append((rows[c], grid[:, c]))
            ys = [_even_out(seen_y[c], height) for c in range(plan.cols)]
        else:
            seen_y.append((ys, grid.sum(axis=1)))
            ys = _even_out(seen_y, height)
        xs = _even_out(seen_x, width)
        cost = node_costs(scene, spec, xs, ys)
        tried.append((float(cost.max()), xs, ys, cost, family, None))
    return tried


def _map_tries(scene, spec: RenderSpec, rounds: int, cache: dict) -> list[tuple]:
    """(busiest, None, None, costs, "work map", cells) of each cut of the work map (kept in
    `cache` for other overlaps)."""
    if "map" not in cache:
        cache["map"] = work_map(scene, spec)
    axes, ex, ey, work = cache["map"]
    tried = []
    for _ in range(rounds):
        cells = map_cells(scene, spec, axes, ex, ey, work)
        cost = node_costs(scene, spec, None, None, cells)
        tried.append((float(cost.max()), None, None, cost, "work map", cells))
        work = _corrected(axes, ex, ey, work, cells, cost)
    return tried
