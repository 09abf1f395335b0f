"""Where to cut the image between mesh nodes (DESIGN.md 6, "cut positions chosen from a cheap
pre-pass that estimates cost per region").

A node's work is the rays it traces inside its box, wherever they came from, so the pre-pass
runs the mesh itself on a coarse image: the simulated mesh of `meshnode.simulator`, whose
nodes decide with the same scheduler as real ones, each node's cost counted as its
intersection tests, voxel steps and rays. The column cuts then move so that the columns of
nodes share the measured cost evenly (cost spread evenly over the pixels of each column band),
the row cuts likewise, and the pass repeats; the cuts with the smallest busiest node win. Two
families are tried: row cuts shared by every column (boxes in a grid), and row cuts of each
column's own (each column's nodes share that column's work evenly: where the work gathers in
one place, cuts common to all columns leave the node over it with most of it).
Correctness never depends on the cuts, only the balance of work does.
"""

from dataclasses import replace

import numpy as np

from host.partition import column_rows, partition, splits, subset
from meshnode.simulator import simulate
from protocols.camera import CameraSampling, Generation
from protocols.render import ImageSpec, RenderSpec

COARSE = 64  # coarse samples along the longer image axis


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
    where work lies, at a fraction of the cost."""
    width, height = spec.sample_grid
    scale = COARSE / max(width, height)
    plan = spec.plan
    image = ImageSpec(width=max(plan.cols, round(width * scale)),
                      height=max(plan.rows, round(height * scale)), depth=spec.image.depth)
    camera = spec.camera
    if camera is not None:
        camera = replace(camera, sampling=CameraSampling(generation=Generation.CENTRE, rays=1,
                                                         sampling="uniform"))  # fmt: skip
    return RenderSpec(image, spec.engine, plan, camera)


def node_costs(scene, spec: RenderSpec, xs, ys) -> np.ndarray:
    """Cost of every node on a coarse image cut at `xs`, `ys` (given on the full sample
    grid): the mesh simulated in this process."""
    coarse = coarse_spec(spec)
    (width, height), (cw, ch) = spec.sample_grid, coarse.sample_grid
    part, keep = partition(scene, coarse, _coarse(xs, width, cw), _coarse(ys, height, ch))
    scenes = [subset(scene, keep[n]) for n in range(part.nodes)]
    return np.array([r.cost for r in simulate(scenes, coarse, part).nodes], float)


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
    return _bands(np.searchsorted(np.interp(np.arange(n + 1), at, cum),
                                  np.arange(1, parts) / parts), n)  # fmt: skip


def balanced_cuts(scene, spec: RenderSpec, rounds: int = 3):
    """(xs, ys, report): cuts of the sample grid whose simulated busiest node is the least
    loaded over `rounds` re-cuts from even cuts, with row cuts shared by all columns and
    with each column's own (`ys` is then a list per column)."""
    (width, height), plan = spec.sample_grid, spec.plan
    tried = []
    for own_rows in (False, True) if plan.rows > 1 and plan.cols > 1 else (False,):
        xs, ys = splits(width, plan.cols), splits(height, plan.rows)
        seen_x: list = []
        seen_y: list = [[] for _ in range(plan.cols)] if own_rows else []
        for _ in range(rounds + 1):
            cost = node_costs(scene, spec, xs, ys)
            tried.append((float(cost.max()), xs, ys, cost, own_rows))
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
    best, bx, by, cost, own_rows = min(tried, key=lambda t: t[0])
    even = tried[0][0] or 1.0
    report = {"columns": bx, "rows": by, "rows_per_column": own_rows,
              "simulated_busiest_vs_even": best / even,
              "simulated_busiest_vs_even_by_rows": {  # the best of each family: why this one
                  "shared": min(t[0] for t in tried if not t[4]) / even,
                  "per_column": min((t[0] for t in tried if t[4]), default=even) / even},
              "simulated_imbalance": float((cost.max() - cost.min()) / cost.max()) if best else 0.0}
    return bx, by, report
