"""What choosing a cell's taker among the nodes holding its engine could buy, at most.

Under a memory budget the plan gives some cells copies on other nodes (`--budget-copies
hottest`), and a ray entering a cell goes to the holder fewest hops from the node that has
it (`MeshPlan.takers`), the same holder whatever the holders have to do. R2E2 (Fouladi et
al. 2022) hands each ray to whichever holder of its data is least loaded. This bench bounds
what such a run-time choice could gain on the plan's own copies: `host render`'s plan
(cells cut by the objects, the budget, its copies) is simulated in this process in work
units (`meshnode.mesh.simulator`, `clock="work"`), each node's units are split by the engine
it traced them with, and a linear program then spreads each cell's work over its holders
freely, for the least busiest node. No choice made ray by ray can do better with the same
copies; a static split of each cell's rays in the program's proportions would approach it
where a cell's rays cost alike.

    python -m bench.holder_split [--scenes DIR] [--only balls,mount,teapot] [--mesh 3x3]
                                 [--max-share 0.25] [--size 256] [--spp 16] [--json FILE]

Needs scipy (`pip install -e ".[bench]"`). Printed per scene: the copies each node holds,
the busiest node's work units and the balance (the mean over the busiest), the same with
each cell's work spread over its holders, their ratio (the most a run-time choice of holders
gains on these copies) and the largest cell's share of the work. Work units, not CPU: the
figures do not move with the machine.
"""

import argparse
import sys
from collections import Counter
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench import add_simulated_mesh_options, finish  # noqa: E402 (after the path is set)


def traced_by_engine(scene, image, plan):
    """(the planned RenderSpec, Counter of work units by (node, cell whose engine traced
    them)) of `host render`'s plan of `scene` under `plan`, simulated in work units: each
    engine call's units go to the cell it holds (a primary batch traces with its own
    engine and its copies alike)."""
    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from host.scene.subset import subset
    from meshnode.engine.engine import Engine
    from meshnode.mesh import simulator
    from meshnode.mesh.node import NodeCore
    from meshnode.mesh.stats import work_units
    from protocols.render import EngineSpec

    planned = plan_render(
        Request(scene, image, EngineSpec(), plan=plan, auto=Auto(budget_copies=True))
    )
    units: Counter = Counter()
    cells: dict[int, int] = {}  # id(engine) -> the cell it holds (a simulated mesh shares them)
    tracing = [-1]  # the node whose batch is being traced
    made, trace, trace_node = NodeCore.__init__, NodeCore.trace, Engine.trace_node

    def registered(core, *args, **kwargs):
        made(core, *args, **kwargs)
        cells[id(core.engine)] = core.node
        cells.update({id(e): c for c, e in core.copies.items()})

    def traced(core, *args, **kwargs):
        tracing[0] = core.node
        return trace(core, *args, **kwargs)

    def counted(engine, rays):
        out = trace_node(engine, rays)
        units[tracing[0], cells[id(engine)]] += work_units(out[1])
        return out

    NodeCore.__init__, NodeCore.trace, Engine.trace_node = registered, traced, counted
    try:
        scenes = [subset(scene, k) for k in planned.holders]
        simulator.simulate(scenes, planned.spec, planned.partition, clock="work")
    finally:
        NodeCore.__init__, NodeCore.trace, Engine.trace_node = made, trace, trace_node
    return planned.spec, units


def split_bound(cell_work: np.ndarray, holders: list[list[int]]) -> float:
    """The least busiest node's work when cell c's work `cell_work[c]` may be spread in any
    proportions over the nodes `holders[c]` (a linear program: minimise T, every node's
    share at most T, every cell's shares summing to its work)."""
    from scipy.optimize import linprog

    pairs = [(c, h) for c, hs in enumerate(holders) for h in hs]
    n, v = len(holders), len(pairs) + 1
    at_node, of_cell = np.zeros((n, v)), np.zeros((n, v))
    for k, (c, h) in enumerate(pairs):
        at_node[h, k] = 1.0
        of_cell[c, k] = 1.0
    at_node[:, -1] = -1.0
    goal = np.zeros(v)
    goal[-1] = 1.0
    found = linprog(goal, A_ub=at_node, b_ub=np.zeros(n), A_eq=of_cell, b_eq=cell_work)
    if not found.success:
        raise RuntimeError(f"holder split: the linear program failed: {found.message}")
    return float(found.x[-1])


def row(name: str, spec, units: Counter) -> dict:
    """One scene's figures from its simulated units by (node, engine)."""
    plan = spec.plan
    load, work = np.zeros(plan.nodes), np.zeros(plan.nodes)
    for (node, cell), u in units.items():
        load[node] += u
        work[cell] += u
    holders = plan.holders_table()
    split = split_bound(work, holders)
    total = load.sum()
    return {
        "scene": name,
        "mesh": f"{plan.rows}x{plan.cols}",
        "max_share": plan.max_share,
        "copies_held": [len(plan.held(n)) - 1 for n in range(plan.nodes)],
        "busiest_units": float(load.max()),
        "balance": float(total / plan.nodes / load.max()),
        "split_busiest_units": split,
        "split_balance": float(total / plan.nodes / split),
        "gain": float(load.max() / split),
        "largest_cell_share": float(work.max() / total),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.holder_split", description=__doc__.split("\n\n")[0])
    add_simulated_mesh_options(p, only="balls,mount,teapot", size=256, spp=16)
    p.add_argument("--max-share", type=float, default=0.25, help="the plan's memory budget")
    args = p.parse_args(argv)
    from bench import read_scene
    from protocols.render import ImageSpec, MeshPlan

    rows_, cols = (int(v) for v in args.mesh.lower().split("x"))
    plan = MeshPlan(rows_, cols, 1, "objects", "object", max_share=args.max_share)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    print(
        f"{args.size}x{args.size} at {args.spp} spp, {args.mesh} object space under "
        f"{args.max_share:g} of the objects a node (cells cut by the objects, the budget's "
        "copies), simulated in work units"
    )
    print(
        f"{'scene':>10} {'copies held':>28} {'busiest':>10} {'balance':>7} "
        f"{'split':>10} {'balance':>7} {'gain':>5} {'largest cell':>12}"
    )
    rows, bad = [], []
    for name in args.only.split(","):
        spec, units = traced_by_engine(read_scene(args.scenes, name), image, plan)
        r = row(name, spec, units)
        print(
            f"{name:>10} {str(r['copies_held']):>28} {r['busiest_units']:>10.4g} "
            f"{r['balance']:>7.2f} {r['split_busiest_units']:>10.4g} {r['split_balance']:>7.2f} "
            f"{r['gain']:>5.2f} {r['largest_cell_share']:>12.0%}"
        )
        if not 1.0 - 1e-6 <= r["gain"] or r["split_balance"] > 1.0 + 1e-6:
            bad.append(
                f"{name}: the split bound {r['split_busiest_units']:.6g} is not between "
                f"the mean and the busiest node's {r['busiest_units']:.6g}"
            )
        rows.append(r)
    return finish(
        rows,
        args.json,
        bad,
        "INCONSISTENT split bounds:\n",
        "gain: the busiest node's work units over the least a free split among holders allows",
    )


if __name__ == "__main__":
    sys.exit(main())
