"""Cells cut by the objects and evened on the work the cost pre-pass measures
(`MeshPlan.balance` "objects"): memory first, then work.

Cells that divide the objects evenly can still leave one node most of the work (gears on a
3x3: the busiest node's work 0.95 above the least's). So the mesh is simulated on a coarse
image (`host.planning.prepass`) and the cells re-cut where the measured work says, each cut
kept within the objects a node may hold (`host.planning.objectcells`).
"""

import numpy as np

from host.planning.cells import scene_box
from host.planning.objectcells import object_cells
from host.planning.prepass import node_costs
from meshnode.engine.tables import build_tables
from protocols.render import RenderSpec
from protocols.scene import SceneData

ROUNDS = 3  # re-cuts on the pre-pass's measured work


def balanced_object_cells(scene: SceneData, spec: RenderSpec, limit=None, rounds=ROUNDS):
    """(cells, report): cells cut by the objects (`object_cells`), then re-cut `rounds` times
    on the work the cost pre-pass measured (`node_costs`: the mesh simulated on a coarse
    image), each node's measured work spread over the objects whose centres its cell holds;
    the cuts whose simulated busiest node is least are kept. `limit`: the objects a node may
    hold (the budget's), else a little over the fewest."""
    plan, box = spec.plan, scene_box(scene)
    tb = build_tables(scene)
    centres = 0.5 * (tb.lo + tb.hi)
    cells = object_cells(scene, box, plan.rows, plan.cols, limit=limit)
    cost = node_costs(scene, spec, None, None, cells)
    tried = [(float(cost.max()), cells, cost)]
    weight = np.ones(tb.n)
    for _ in range(rounds if tb.n else 0):
        weight = _measured(weight, centres, cells, cost)
        cells = object_cells(scene, box, plan.rows, plan.cols, weight, limit)
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


def _measured(weight, centres, cells, cost) -> np.ndarray:
    """Work per object with each node's measured `cost` spread over the objects whose
    centres its cell holds, in proportion to their work so far (so a node's share keeps
    what earlier rounds learnt of where inside it the work lies)."""
    los, his = cells
    inside = np.all((centres[None] >= los[:, None]) & (centres[None] <= his[:, None]), axis=2)
    owner = np.argmax(inside, axis=0)  # the first cell holding each centre
    out = weight.copy()
    for n in range(len(los)):
        mine = owner == n
        total = float(weight[mine].sum())
        if total > 0:
            out[mine] = weight[mine] * (cost[n] / total)
    return np.maximum(out, 1e-9 * max(float(out.max()), 1e-300))


def object_limit(scene: SceneData, plan) -> float | None:
    """The objects a node may hold under the plan's `max_share` (None: no bound)."""
    return plan.max_share * build_tables(scene).n if plan.max_share < 1 else None
