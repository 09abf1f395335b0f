"""The work map: object space cut where the work lies, apart from the image.

The scene's box is cut into FINE x FINE cells of equal size along the two cut axes, each
simulated as a node of its own; each column of cells then gets an equal share of the work, and
each column's rows likewise (a teapot on a wide floor, a mountain seen from above: cells cut
from the image at the scene's near face leave one node with most of the work). The image's
tiles then follow the cells (`host.planning.rectangles.taker_tiles`).
"""

from dataclasses import replace

import numpy as np

from host.planning.cells import cell_axes, cells_from_cuts, node_cells, scene_box
from host.planning.prepass import node_costs
from protocols.render import RenderSpec

FINE = 12  # work map cells along each cut axis


def work_map(scene, spec: RenderSpec, fine: int = FINE):
    """(axes, column edges, row edges, cost[row, column]): the scene's box cut into fine x
    fine cells of equal size along the cut axes (`host.planning.cells.cell_axes`), each
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


def map_tries(scene, spec: RenderSpec, rounds: int, cache: dict) -> list[tuple]:
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
