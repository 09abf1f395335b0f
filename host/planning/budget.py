"""The memory budget a plan obeys in object space (`MeshPlan.max_share`, `node_bytes`): what
each node would hold, and the plan that keeps every node within the budget, or a clear error
naming the smallest share the cuts could reach.

Object space exists for scenes no single node can hold; a plan that copies the scene onto every
node (wide overlaps, neighbours' copies, shared cells) traces fast but divides nothing. So the
budget is checked on the plan as the nodes will receive it (their own cells, the overlap, the
copies), before any node is configured; where it is broken the plan gives up, in order, what
costs memory: cells that follow the view (for cells cut by the objects), the shared cells and
the neighbours' copies, and the overlap.
"""

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from host.planning.holding import held_bytes
from meshnode.engine.occupancy import FINE_BYTES, OCTANTS
from protocols.render import RenderSpec
from protocols.scene import SceneData

if TYPE_CHECKING:
    from protocols.partition import Partition


class BudgetError(ValueError):
    """No plan this host can make keeps every node within the memory budget."""


def budgeted(plan) -> bool:
    """Whether the plan carries a memory budget."""
    return plan.mode == "object" and (plan.max_share < 1.0 or plan.node_bytes > 0)


def holdings(scene: SceneData, spec: RenderSpec, part: "Partition", keep: np.ndarray) -> dict:
    """What each node would hold under this plan: the objects (its own box's and its copies',
    each counted once), their share of the scene's, and its engines' bytes (as
    `Engine.nbytes` counts them: `engine_bytes` of each box held, with the occupancy map)."""
    plan = spec.plan
    total = keep.shape[1]
    held = [keep[plan.held(n)].any(axis=0) for n in range(plan.nodes)]
    own = cell_bytes(scene, part, keep)
    counts = [int(h.sum()) for h in held]
    return {
        "objects": counts,
        "share": [c / total if total else 0.0 for c in counts],
        "engine_bytes": [sum(own[m] for m in plan.held(n)) for n in range(plan.nodes)],
    }


def cell_bytes(scene: SceneData, part: "Partition", keep: np.ndarray, cells=None) -> list[int]:
    """Each cell's engine bytes (of `cells`, default all) as a node holding it counts them:
    `engine_bytes` of its box's objects and the occupancy map, a byte a voxel and octant
    and, with sub-voxels (`Partition.occ_fine`), FINE_BYTES a voxel; its inner map's alike."""
    per = OCTANTS + (FINE_BYTES if part.occ_fine else 0)
    occ = per * (int(np.prod(part.occ_res)) + int(np.prod(part.inner_res or (0,))))
    cells = range(len(keep)) if cells is None else cells
    return [held_bytes(scene, keep[m]) + occ for m in cells]


def within(plan, held: dict) -> bool:
    """Whether every node's holding keeps to the plan's budget."""
    if max(held["share"]) > plan.max_share + 1e-12:
        return False
    return not plan.node_bytes or max(held["engine_bytes"]) <= plan.node_bytes


def retreats(plan):
    """The plans to fall back on, in order, while the budget is broken: cells cut by the
    objects (if the view's or the cost pre-pass's were asked for), without shared cells,
    without the neighbours' copies, then at overlap 0."""
    tried = [plan]
    if plan.balance != "objects":
        tried.append(replace(tried[-1], balance="objects"))
    if plan.shared:
        tried.append(replace(tried[-1], shared=()))
    if plan.copies:
        tried.append(replace(tried[-1], copies=False))
    if plan.overlap > 0:
        tried.append(replace(tried[-1], overlap=0.0))
    return tried[1:]


def report(plan, held: dict, gave_up: list[str]) -> dict:
    """What the statistics say of the budget: the bounds, each node's holding, what the plan
    gave up to keep within them."""
    return {
        "max_share": plan.max_share,
        "node_bytes": plan.node_bytes,
        "objects_held": held["objects"],
        "share_held": held["share"],
        "engine_bytes": held["engine_bytes"],
        "gave_up": gave_up,
    }


def refusal(scene: SceneData, plan, held: dict) -> BudgetError:
    """The error for a scene that cannot be divided within the budget: the smallest share
    (and engine) the last plan tried reached, and the bound it broke."""
    share, size = max(held["share"]), max(held["engine_bytes"])
    bounds = []
    if plan.max_share < 1:
        bounds.append(f"--max-share {plan.max_share:g}")
    if plan.node_bytes:
        bounds.append(f"--node-memory {plan.node_bytes} bytes")
    return BudgetError(
        f"{scene.source}: cannot divide the scene over {plan.rows}x{plan.cols} nodes within "
        f"{' and '.join(bounds)}: the best plan (cells cut by the objects, overlap "
        f"{plan.overlap:g}) leaves its fullest node {share:.1%} of the objects and about "
        f"{size} bytes of engine; use more nodes or a larger budget"
    )


def check_divisible(scene: SceneData, spec: RenderSpec) -> None:
    """BudgetError now, before any node starts, when even the plan's last retreat (cells
    cut by the objects, no copies, overlap 0) leaves a node over `max_share` (the byte bound
    needs the nodes' engines planned: `plan_render` checks it)."""
    plan = spec.plan
    if plan.mode != "object" or plan.max_share >= 1.0:
        return
    from host.planning.partition import partition  # only a share-bound object space cuts here

    last = ([plan, *retreats(plan)])[-1]  # what the plan gives up last is given up here
    at = replace(spec, plan=replace(last, node_bytes=0))
    part, keep = partition(scene, at)
    held = holdings(scene, at, part, keep)
    if not within(at.plan, held):
        raise refusal(scene, last, held)
