"""Cells cut by the objects and evened on the work the cost pre-pass measures
(`MeshPlan.balance` "objects"): memory first, then work.

Cells that divide the objects evenly can still leave one node most of the work (gears on a
3x3: the busiest node's work 0.95 above the least's). So the mesh is simulated on a coarse
image (`host.planning.prepass`) and the cells re-cut where the measured work says, each cut
kept within the objects a node may hold (`host.planning.objectcells`).
"""

import numpy as np

from host.planning.cells import scene_box
from host.planning.objectcells import WorkGrid, object_cells
from host.planning.prepass import node_costs
from meshnode.engine.tables import build_tables
from protocols.render import RenderSpec
from protocols.scene import SceneData

ROUNDS = 3  # re-cuts on the pre-pass's measured work
GRID = 16  # voxels along each axis of the grid the measured work is spread on


def balanced_object_cells(scene: SceneData, spec: RenderSpec, limit=None, rounds=ROUNDS):
    """(cells, costs, report): cells cut by the objects (`object_cells`), then re-cut
    `rounds` times on the work the cost pre-pass measured (`node_costs`: the mesh simulated
    on a coarse image), each node's measured work spread over its cell on a grid of where
    the work was thought to lie (`WorkGrid`); the cuts whose simulated busiest node is least
    are kept. `limit`: the objects a node may hold (the budget's), else a little over the
    fewest."""
    plan, box = spec.plan, scene_box(scene)
    cells = object_cells(scene, box, plan.rows, plan.cols, limit=limit)
    cost = node_costs(scene, spec, None, None, cells)
    tried = [(float(cost.max()), cells, cost)]
    grid = WorkGrid(*box, _object_density(scene, box))
    for _ in range(rounds):
        grid = WorkGrid(*box, _measured(grid, cells, cost))
        cells = object_cells(scene, box, plan.rows, plan.cols, grid, limit)
        cost = node_costs(scene, spec, None, None, cells)
        tried.append((float(cost.max()), cells, cost))
    busiest, cells, cost = min(tried, key=lambda t: t[0])
    return (
        cells,
        cost,
        {
            "simulated_busiest_by_round": [t[0] for t in tried],
            "simulated_busiest_vs_objects_only": busiest / tried[0][0] if tried[0][0] else 1.0,
        },
    )


def _object_density(scene: SceneData, box) -> np.ndarray:
    """The first guess of where work lies: the objects' centres per voxel, and a little
    everywhere (rays cross empty space too)."""
    tb = build_tables(scene)
    lo, hi = box
    centres = 0.5 * (tb.lo + tb.hi) if tb.n else np.zeros((0, 3))
    count, _ = np.histogramdd(centres, bins=GRID, range=list(zip(lo, hi, strict=True)))
    return count + 0.05 * max(count.mean(), 1e-9)


def _measured(grid: WorkGrid, cells, cost) -> np.ndarray:
    """Work per voxel with each node's measured `cost` spread over its cell in proportion
    to the work the grid put there (so what earlier rounds learnt of where inside a cell
    the work lies is kept)."""
    out = np.zeros_like(grid.density)
    for lo, hi, c in zip(*cells, cost, strict=True):
        mass = grid.density * grid.fractions(lo, hi)
        total = float(mass.sum())
        if total > 0:
            out += mass * (c / total)
    return np.maximum(out, 1e-9 * max(float(out.max()), 1e-300))


def object_limit(scene: SceneData, plan) -> float | None:
    """The objects a node may hold under the plan's `max_share` (None: no bound)."""
    return plan.max_share * build_tables(scene).n if plan.max_share < 1 else None
