"""Under MeshPlan.copies, the cells every node also holds (MeshPlan.shared): chosen on the
cuts already made, by simulating each candidate cell shared, since sharing a cell lifts its
work off its neighbours at the price of its objects held on every node.
"""

from dataclasses import replace

import numpy as np

from host.planning.budget import budgeted, holdings, within
from host.planning.holding import ratio, too_big_for_memory
from host.planning.partition import partition
from host.planning.prepass import allowance, node_costs
from protocols.render import RenderSpec

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
    `memory` (0: not known) for the largest node's engines, nor past the plan's memory
    budget (`host.planning.budget`: the hottest cells that fit are shared); not tried where
    the cuts' simulated `efficiency` is SHARE_BELOW or more already."""
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
        if too_big_for_memory(scene, at, xs, ys, cells, memory, too_big):
            return None
        if budgeted(plan) and not within(
            plan, holdings(scene, at, *partition(scene, at, xs, ys, cells))
        ):
            too_big.append({"shared": list(shared), "over": "the plan's memory budget"})
            return None
        if not allowance().affords("shared cells"):  # the pre-pass's allowance
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
            ",".join(map(str, k)) or "none": ratio(v, busiest) for k, v in tried.items()
        },
        "too_big_for_memory": too_big,
    }
    return chosen, report


def busiest_vs_none(report: dict) -> float:
    """The simulated busiest node with the shared cells chosen, against none shared."""
    return report["simulated_busiest_vs_none"][",".join(map(str, report["chosen"])) or "none"]
