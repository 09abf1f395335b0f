"""The room a memory budget leaves, filled by growing each node's box (after the copies of
`host.planning.replicas`, which fill it a whole cell at a time).

A node traces every ray inside its box, its cell grown by the overlap: a wider box keeps rays
on the node instead of passing them, at the price of the objects around its cell held twice.
A plan's overlap is one for all nodes, set for the fullest; under a budget, nodes whose cells
hold fewer objects can grow further. Each node's box is grown by the widest of GROWTHS that
keeps every node holding it (itself, and the holders of its copies) within the budget, the
least loaded first: all nodes, or only those not among the busiest (a wider box keeps more
of its rays, and takes work off its neighbours or on, as they lie), whichever the simulated
mesh finds lightens its busiest node; none if neither does.
"""

from dataclasses import replace

import numpy as np

from host.planning.budget import cell_bytes
from host.planning.cells import grown, traced
from host.planning.clip import holders
from host.planning.prepass import allowance, costs, partition_pass, rays_passed
from protocols.partition import Partition
from protocols.render import RenderSpec
from protocols.scene import SceneData

GROWTHS = (80.0, 40.0, 20.0, 10.0, 5.0)  # percent of a cell's size, the widest tried first
BUSY = 0.8  # nodes whose simulated load is above this share of the busiest's are not grown


def grown_within(
    scene: SceneData, spec: RenderSpec, part: Partition, keep: np.ndarray
) -> tuple[Partition, np.ndarray, dict]:
    """(partition, holders, report): the nodes' boxes grown as far as GROWTHS and the budget
    allow, all of them or only those not among the busiest (BUSY), whichever the simulated
    mesh finds lightens its busiest node more (or as much, with fewer rays passed); else the
    partition as it was; skipped where the pre-pass's allowance affords no two simulations
    (`host.planning.allowance`)."""
    if not allowance().affords("growth", 2):
        why = "skipped: " + allowance().why
        return part, keep, {"chosen": [0.0] * spec.plan.nodes, "why": why}
    before = partition_pass(scene, spec, part, keep)
    load = costs(before)
    busiest, passed = float(load.max()), rays_passed(before)
    order = np.argsort(load, kind="stable").tolist()  # the least loaded first to take room
    tried, best = [], (busiest, passed, part, keep, [0.0] * spec.plan.nodes)
    for who in ("all", "not the busiest"):
        nodes = order if who == "all" else [n for n in order if load[n] <= BUSY * busiest]
        wider, kept, growth = _grown(scene, spec, part, keep, nodes)
        if not any(growth) or any(growth == t["growth"] for t in tried):
            continue
        if tried and not allowance().affords("growth: the nodes not among the busiest"):
            break
        after = partition_pass(scene, spec, wider, kept)
        now = float(costs(after).max())
        tried.append({"nodes": who, "growth": growth, "simulated_busiest_vs_plan": now / busiest})
        if (now, rays_passed(after)) < best[:2]:
            best = (now, rays_passed(after), wider, kept, growth)
    report = {"tried": tried, "simulated_rays_passed": passed}
    if best[2] is part:
        why = "no node has room to grow" if not tried else "no growth lightened the busiest"
        return part, keep, {**report, "chosen": best[4], "why": why}
    why = f"the simulated busiest node carries {best[0] / busiest:.2f} of what it did"
    return best[2], best[3], {**report, "chosen": best[4], "why": why}


def _grown(scene, spec, part, keep, nodes) -> tuple[Partition, np.ndarray, list]:
    """(partition, holders, growth per node): each of `nodes` in turn grown by the widest of
    GROWTHS that keeps every node holding it within the budget (its copies' holders too:
    only their holdings change, so only they are checked, the grown box's bytes counted
    anew)."""
    plan = spec.plan
    los, his = np.array(part.los, float), np.array(part.his, float)
    cells = np.array(part.cell_los, float), np.array(part.cell_his, float)
    kept, chosen = keep.copy(), [0.0] * plan.nodes
    size = cell_bytes(scene, part, keep) if plan.node_bytes else [0] * plan.nodes
    limit = plan.max_share * keep.shape[1] + 1e-9

    def fits(trial: np.ndarray, sizes: list, n: int) -> bool:
        for h in plan.holders(n):
            held = plan.held(h)
            if np.count_nonzero(trial[held].any(axis=0)) > limit:
                return False
            if plan.node_bytes and sum(sizes[m] for m in held) > plan.node_bytes:
                return False
        return True

    for n in nodes:
        for growth in GROWTHS:
            if growth <= plan.overlap:
                break
            lo, hi = grown(cells[0][n : n + 1], cells[1][n : n + 1], growth)
            trial = kept.copy()
            trial[n] = holders(scene, *traced(lo, hi))[0]
            sizes = list(size)
            if plan.node_bytes:
                (sizes[n],) = cell_bytes(scene, part, trial, [n])
            if fits(trial, sizes, n):
                los[n], his[n], kept, size, chosen[n] = lo[0], hi[0], trial, sizes, growth
                break
    return replace(part, los=_rows(los), his=_rows(his)), kept, chosen


def _rows(a: np.ndarray, n: int | None = None, row=None) -> tuple:
    """The boxes' corners (node n's replaced by `row`), as Partition holds them."""
    b = a.copy()
    if n is not None:
        b[n] = row
    return tuple(tuple(float(v) for v in r) for r in b)
