"""Object-space kernel benchmark: what an object-space mesh's tracing costs per unit of work
against one node's, free of process and machine noise. A mesh is simulated in this process
(`meshnode.mesh.simulator`, planned as `host render` plans it: cost cuts, stealing, copies),
every engine call its nodes make is kept (engine and rays), and so are one node's calls for
the same render; then both sets are traced again on this thread in turns, `--rounds` times.

    python -m bench.object_kernel [--scenes DIR] [--only tetra] [--mesh 3x3] [--overlap 100]
                                  [--size 768] [--spp 4] [--rounds 15] [--json FILE]

Timed as `bench.timing` says: this thread's CPU seconds, pinned to one core, one node's calls
and the mesh's taking turns. Printed per scene: one node's and the mesh's tracing CPU seconds
(median, least-most), the mesh's work units over one node's
(`meshnode.mesh.stats.work_units`: what the model counts), and the mesh's CPU over one node's
(the median of the rounds' paired ratios, with their quartiles and least-most: each round's
two sides share the same spell of this machine's speed); then per engine its calls, rays,
CPU seconds, and CPU nanoseconds per work unit beside one node's (one more replay). A mesh
CPU ratio above its work ratio is the cost the mesh kernel adds per unit (box spans,
occupancy look-ups, rays written out).
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_simulated_mesh_options, finish  # noqa: E402 (after the path is set)
from bench.timing import Turns, pin_one_core, pinned_text, turns  # noqa: E402
from host.planning.request import Request  # noqa: E402

# Counted once where they happen, on one node and on a mesh alike.
ONCE = ("eye_hits", "escaped", "shadow_rays", "shadow_rays_blocked", "reflected_rays")


def captured(scene, rows: int, cols: int, size: int, spp: int, overlap: float, plan: dict):
    """(engine, rays, mesh kernel?) of every engine call of a simulated render."""
    from host.planning.plan import plan_render
    from host.scene.subset import subset
    from meshnode.engine import engine as engine_module
    from meshnode.mesh.simulator import simulate
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    calls = []
    trace = engine_module.Engine._trace

    def keep(engine, rays, out_rgb, out):
        calls.append((engine, rays.copy(), out is not None))
        return trace(engine, rays, out_rgb, out)

    image = ImageSpec(width=size, height=size, spp=spp)
    mesh = MeshPlan(rows, cols, overlap, tile=max(2, size // 24), **plan)
    planned = plan_render(Request(scene, image, EngineSpec(), plan=mesh))
    engine_module.Engine._trace = keep
    try:
        simulate([subset(scene, k) for k in planned.holders], planned.spec, planned.partition)
    finally:
        engine_module.Engine._trace = trace
    return calls


def replay(calls, per_engine: dict | None = None):
    """(tracing CPU seconds, work units, counts) of tracing every call again; with
    `per_engine`, each engine's [CPU, units] added there."""
    from collections import Counter

    from meshnode.mesh.stats import work_units

    cpu, units, counts = 0.0, 0, Counter()
    for engine, rays, passing in calls:
        start = time.thread_time()
        done = (engine.trace_passing(rays) if passing else engine.trace_node(rays))[1]
        spent = time.thread_time() - start
        done_units = work_units(done)
        cpu += spent
        units += done_units
        counts.update({k: done[k] for k in ONCE})
        if per_engine is not None:
            row = per_engine.setdefault(id(engine), [engine, 0, 0, 0.0, 0])
            row[1] += 1
            row[2] += len(rays)
            row[3] += spent
            row[4] += done_units
    return cpu, units, counts


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.object_kernel", description=__doc__.split("\n\n")[0])
    add_simulated_mesh_options(p, only="tetra", size=768, spp=4)
    p.add_argument("--rounds", type=int, default=15)
    args = p.parse_args(argv)
    from bench import read_scene

    rows_, cols = (int(v) for v in args.mesh.lower().split("x"))
    plan = {"mode": "object", "steal": True, "balance": "cost", "copies": True}
    core = pin_one_core()
    print(
        f"{args.size}x{args.size} at {args.spp} spp, {args.mesh} object space at overlap "
        f"{args.overlap:g} (cost cuts, stealing, copies), simulated; {args.rounds} rounds "
        f"in turns on one thread, {pinned_text(core)}; CPU seconds median (least-most)"
    )
    rows, bad = [], []
    for name in args.only.split(","):
        scene = read_scene(args.scenes, name)
        one = captured(scene, 1, 1, args.size, args.spp, args.overlap, {})
        mesh = captured(scene, rows_, cols, args.size, args.spp, args.overlap, plan)
        times, got = Turns(), {}
        for _, side in turns(["one", "mesh"], args.rounds):
            cpu, *got[side] = replay(one if side == "one" else mesh)
            times.add(side, cpu)
        (w1, n1), (wm, nm) = got["one"], got["mesh"]
        if n1 != nm:
            bad.append(f"{name}: one node {dict(n1)}, mesh {dict(nm)}")
        ratio = times.ratio("mesh", "one")
        ratios = ratio.samples
        q1, _, q3 = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else [ratios[0]] * 3
        c_one, c_mesh = times.figure("one"), times.figure("mesh")
        per_engine: dict = {}
        replay(mesh, per_engine)
        print(
            f"\n== {name}: one node {c_one.text()} s, mesh {c_mesh.text()} s; "
            f"work mesh / one {wm / w1:.3f}; CPU mesh / one median {ratio.median:.3f} "
            f"(quartiles {q1:.3f}-{q3:.3f}, least-most {ratio.low:.3f}-{ratio.high:.3f})"
        )
        print(f"{'engine':>8} {'kernel':>7} {'calls':>6} {'rays':>9} {'CPU s':>7} {'ns/unit':>8}")
        engines = []
        for i, (engine, calls, n_rays, cpu, units) in enumerate(per_engine.values()):
            kernel = "one" if engine.holds_scene else "mesh"
            ns = 1e9 * cpu / max(units, 1)
            engines.append(
                {
                    "kernel": kernel,
                    "calls": calls,
                    "rays": n_rays,
                    "cpu_seconds": cpu,
                    "work_units": units,
                }
            )
            print(f"{i:>8} {kernel:>7} {calls:>6} {n_rays:>9} {cpu:>7.3f} {ns:>8.2f}")
        print(
            f"{'one node':>8} {'one':>7} {len(one):>6} {sum(len(c[1]) for c in one):>9} "
            f"{c_one.median:>7.3f} {1e9 * c_one.median / w1:>8.2f}"
        )
        rows.append(
            {
                "scene": name,
                "mesh": args.mesh,
                "clock": "thread CPU seconds, in turns",
                **c_one.fields("one_cpu_seconds"),
                **c_mesh.fields("mesh_cpu_seconds"),
                "work_ratio": wm / w1,
                "cpu_ratio_median": ratio.median,
                "cpu_ratio_quartiles": [q1, q3],
                "cpu_ratio_least_most": [ratio.low, ratio.high],
                "engines": engines,
            }
        )
    return finish(
        rows,
        args.json,
        bad,
        "MISMATCH (ray counts) between the mesh and one node:\n",
        "the mesh's calls counted the same hits, escapes and shadow rays as one node's",
    )


if __name__ == "__main__":
    sys.exit(main())
