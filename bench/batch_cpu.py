"""Where an object-space node's CPU for its batches goes: the tracing kernels, routing rays to
the nodes that take them on (`Engine.routed`: where each eye ray's work starts on the
occupancy map, the cell that takes it, grouped by node), deposits (`lit_deposits`,
`per_cell`) and the rest of `NodeCore.trace` (Python). A mesh is simulated in this process
(`meshnode.mesh.simulator`, planned as `host render` plans it: cost cuts, stealing, copies),
once to compile and load, then timed on this thread.

    python -m bench.batch_cpu [--scenes DIR] [--only tetra,balls] [--mesh 3x3] [--overlap 100]
                              [--size 384] [--spp 32] [--copies-eye-batch N] [--json FILE]
                              [--max-share F]

Printed per scene: the nodes' summed CPU seconds in each part, each part's share, and the
whole batches' CPU over the kernels' (what `bench.mesh`'s "batch" column divides out: the
speedup counted on the kernels alone, as one node's is, over that counted on whole
batches). The mesh's hits, escapes and shadow rays are checked against one node's.
`--copies-eye-batch N` sets how many eye rays a node makes a batch under copies
(`meshnode.mesh.node.COPIES_EYE_BATCH`), to measure that choice. `--max-share F` plans as
`bench.mesh --balance objects --max-share F --budget-copies hottest` does instead (cells cut
by the objects, no node holding more than F of them, the budget's copies): the mesh that
divides the scene. Printed beside the parts: the routing's nanoseconds a ray routed.
"""

import argparse
import sys
import time
from collections import Counter
from functools import partial
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_simulated_mesh_options, finish  # noqa: E402 (after the path is set)
from host.planning.request import Request  # noqa: E402

ONCE = ("eye_hits", "escaped", "shadow_rays", "shadow_rays_blocked", "reflected_rays")
PARTS = ("kernels", "routing", "deposits")


def timed_parts(run):
    """CPU seconds of `run()` on this thread in each part of a node's batches, and the whole
    of `NodeCore.trace`, by wrapping the functions each part calls."""
    from meshnode.engine import engine
    from meshnode.mesh import node

    spent: Counter = Counter()
    hooks = [
        (engine.Engine, "trace_node", "kernels"),
        (engine.Engine, "routed", "routing"),
        (node, "lit_deposits", "deposits"),
        (node, "per_cell", "deposits"),
        (node.NodeCore, "trace", "batches"),
    ]
    saved = [(owner, name, getattr(owner, name)) for owner, name, _ in hooks]

    def wrap(f, part):
        def timed(*args, **kwargs):
            start = time.thread_time()
            try:
                return f(*args, **kwargs)
            finally:
                spent[part] += time.thread_time() - start
                if part == "routing":  # Engine.routed(self, rays, ...)
                    spent["routed_rays"] += len(args[1])

        return timed

    for (owner, name, part), (_, _, f) in zip(hooks, saved, strict=True):
        setattr(owner, name, wrap(f, part))
    try:
        result = run()
    finally:
        for owner, name, f in saved:
            setattr(owner, name, f)
    return spent, result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.batch_cpu", description=__doc__.split("\n\n")[0])
    add_simulated_mesh_options(p, only="tetra,balls", size=384, spp=32)
    p.add_argument("--copies-eye-batch", type=int, help="eye rays per batch under copies")
    p.add_argument("--max-share", type=float, help="plan under this memory budget instead")
    args = p.parse_args(argv)
    if args.copies_eye_batch:
        from meshnode.mesh import node

        node.COPIES_EYE_BATCH = args.copies_eye_batch
    from bench import read_scene
    from host.planning.plan import plan_render
    from host.planning.request import Auto
    from host.run.oneprocess import render
    from host.scene.subset import subset
    from meshnode.mesh.simulator import simulate
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    rows_, cols = (int(v) for v in args.mesh.lower().split("x"))
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    if args.max_share:
        plan = MeshPlan(rows_, cols, args.overlap, "objects", "object", max_share=args.max_share)
        how = f"cells cut by the objects, at most {args.max_share:g} of them a node, copies"
    else:
        plan = MeshPlan(
            rows_,
            cols,
            args.overlap,
            balance="cost",
            mode="object",
            steal=True,
            copies=True,
            tile=max(2, args.size // 24),
        )
        how = "cost cuts, stealing, copies"
    print(
        f"{args.size}x{args.size} at {args.spp} spp, {args.mesh} object space at overlap "
        f"{args.overlap:g} ({how}), simulated on one thread"
    )
    print(
        f"{'scene':>10} {'batches s':>9} "
        + " ".join(f"{p:>15}" for p in PARTS)
        + f" {'rest':>15} {'batch/kernels':>13} {'ns a ray routed':>15}"
    )
    rows, bad = [], []
    for name in args.only.split(","):
        scene = read_scene(args.scenes, name)
        auto = Auto(budget_copies=bool(args.max_share))
        planned = plan_render(Request(scene, image, EngineSpec(), plan=plan, auto=auto))
        scenes = [subset(scene, k) for k in planned.holders]

        run = partial(simulate, scenes, planned.spec, planned.partition, clock="work")
        run()  # kernels compiled or loaded, engines built
        spent, outcome = timed_parts(run)
        counts = outcome.totals()
        _, one = render(Request(scene, image, EngineSpec(threads=1)))
        if any(counts[k] != one["rays"][k] for k in ONCE):
            bad.append(
                f"{name}: mesh {[counts[k] for k in ONCE]}, one node "
                f"{[one['rays'][k] for k in ONCE]}"
            )
        total = spent["batches"]
        rest = total - sum(spent[p] for p in PARTS)
        cells = " ".join(f"{spent[p]:>7.3f} ({spent[p] / total:>4.0%})" for p in PARTS)
        print(
            f"{name:>10} {total:>9.3f} {cells} {rest:>7.3f} ({rest / total:>4.0%}) "
            f"{total / spent['kernels']:>13.2f} "
            f"{1e9 * spent['routing'] / max(spent['routed_rays'], 1):>15.1f}"
        )
        rows.append(
            {
                "scene": name,
                "mesh": args.mesh,
                "batch_cpu_seconds": total,
                **{f"{p}_cpu_seconds": spent[p] for p in PARTS},
                "rest_cpu_seconds": rest,
                "batch_over_kernels": total / spent["kernels"],
                "routing_ns_per_ray": 1e9 * spent["routing"] / max(spent["routed_rays"], 1),
            }
        )
    return finish(
        rows,
        args.json,
        bad,
        "MISMATCH (ray counts) between the mesh and one node:\n",
        "the mesh counted the same hits, escapes and shadow rays as one node",
    )


if __name__ == "__main__":
    sys.exit(main())
