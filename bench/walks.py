"""What a walk of the occupancy map costs: the walks an object-space mesh's nodes made from
their boxes' exits, replayed and timed. The mesh (`host render`'s plan under a memory budget)
is simulated in this process; every segment a node passed on is replayed from where it left
the node's box (`meshnode.engine.mapwalk.first_occupied`, the walk the kernel made), and each
replayed walk must resume the ray where the node's kernel resumed it.

    python -m bench.walks [--scenes DIR] [--only rings,balls,teapot,gears,tetra]
                          [--mesh 3x3] [--max-share 0.25] [--size 256] [--spp 16]
                          [--repeat 5] [--json FILE]

Printed per scene: the walks replayed, their steps a walk, and the thread CPU a walk and a
step takes (the least of `--repeat` passes over all of them, the scenes in turn).
"""

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, finish  # noqa: E402 (after the path is set)


def _replay():
    """The jitted replay loop (made on first use: numba is imported only when it runs)."""
    import numba

    from meshnode.engine.counters import N_COUNTERS
    from meshnode.engine.mapwalk import first_occupied

    @numba.njit(cache=True, nogil=True)
    def replay(o, d, t0, t1, lo, cell, res, clear, fine):
        counters = np.zeros(N_COUNTERS, np.int64)
        out = np.empty(o.shape[0])
        for i in range(o.shape[0]):
            dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
            rx = 1.0 / dx if dx != 0.0 else math.inf
            ry = 1.0 / dy if dy != 0.0 else math.inf
            rz = 1.0 / dz if dz != 0.0 else math.inf
            ray = (o[i, 0], o[i, 1], o[i, 2], dx, dy, dz, rx, ry, rz)
            out[i] = first_occupied(*ray, t0[i], t1[i], lo, cell, res, clear, fine, counters)
        return out, counters

    return replay


def exit_walks(scene, planned) -> list:
    """Per passed batch of the simulated mesh: (the rays, where each left the node's box,
    where it leaves the scene's, where the kernel resumed it, the node's map)."""
    from host.scene.subset import subset
    from meshnode.engine.engine import Engine
    from meshnode.mesh.simulator import simulate

    got, traced = [], Engine.trace_passing

    def keep(engine, rays):
        rgb, counts, passed = traced(engine, rays)
        if len(passed):
            got.append((engine, passed.copy()))
        return rgb, counts, passed

    Engine.trace_passing = keep
    try:
        simulate([subset(scene, k) for k in planned.holders], planned.spec, planned.partition)
    finally:
        Engine.trace_passing = traced
    walks = []
    for engine, rays in got:
        lo, cell, res = engine.box
        o, d = np.ascontiguousarray(rays["o"]), np.ascontiguousarray(rays["d"])
        t0 = _exits(o, d, rays["t_max"], lo, lo + cell * res)
        t1 = _exits(o, d, rays["t_max"], engine.scene_lo, engine.scene_hi)
        walked = np.isfinite(t0) & (t0 <= rays["t_min"])
        walks.append(
            (o[walked], d[walked], t0[walked], t1[walked], rays["t_min"][walked], engine.occupancy)
        )
    return walks


def _exits(o, d, t_max, lo, hi) -> np.ndarray:
    """Where each ray (rows of o, d) leaves the box lo..hi, at most t_max: the far end of
    `traverse.box_span`'s slabs, computed as it computes them."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(d != 0.0, 1.0 / d, math.inf)
        far = np.where(d != 0.0, np.maximum((lo - o) * r, (hi - o) * r), math.inf)
    return np.minimum(t_max, far.min(axis=1))


def timed(replay, walks) -> tuple[float, int, int, int]:
    """One pass over `walks`: (thread CPU seconds, steps, walks, walks resumed elsewhere than
    the kernel resumed them)."""
    from meshnode.engine.counters import OCC_STEPS, OCC_WALKS

    cpu, steps, count, wrong = 0.0, 0, 0, 0
    for o, d, t0, t1, want, occ in walks:
        began = time.thread_time()
        out, counters = replay(o, d, t0, t1, occ.lo, occ.cell, occ.res, occ.clear, occ.fine)
        cpu += time.thread_time() - began
        steps += int(counters[OCC_STEPS])
        count += int(counters[OCC_WALKS])
        wrong += int(np.sum(np.maximum(out, t0) != want))
    return cpu, steps, count, wrong


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.walks", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="rings,balls,teapot,gears,tetra")
    p.add_argument("--mesh", default="3x3")
    p.add_argument("--max-share", type=float, default=0.25)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    from bench import read_scene
    from host.planning.plan import plan_render
    from host.planning.request import Auto, Request
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    rr, cc = (int(v) for v in args.mesh.lower().split("x"))
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    plan = MeshPlan(rr, cc, 1.0, "objects", "object", max_share=args.max_share)
    scenes = {}
    for name in args.only.split(","):
        scene = read_scene(args.scenes, name)
        request = Request(scene, image, EngineSpec(), plan=plan, auto=Auto(budget_copies=True))
        scenes[name] = exit_walks(scene, plan_render(request))
    replay = _replay()
    passes = {name: [] for name in scenes}
    for _ in range(args.repeat):  # the scenes in turn, so a slow spell reaches each
        for name, walks in scenes.items():
            passes[name].append(timed(replay, walks))
    print(f"{args.mesh} under {args.max_share}, {args.size}x{args.size} at {args.spp} spp")
    print(f"{'scene':>9} {'walks':>9} steps/walk  ns/walk  ns/step")
    rows, bad = [], []
    for name, runs in passes.items():
        cpu, steps, count, wrong = min(runs)
        if wrong:
            bad.append(f"{name}: {wrong} of {count} walks resumed elsewhere than the kernel's")
        per_walk, per_step = cpu / max(count, 1) * 1e9, cpu / max(steps, 1) * 1e9
        each = steps / max(count, 1)
        print(f"{name:>9} {count:>9,} {each:>10.2f} {per_walk:>8.0f} {per_step:>8.1f}")
        rows.append(
            {
                "scene": name,
                "mesh": args.mesh,
                "max_share": args.max_share,
                "walks": count,
                "steps": steps,
                "ns_per_walk": per_walk,
                "ns_per_step": per_step,
            }
        )
    return finish(
        rows,
        args.json,
        bad,
        "MISMATCH: replayed walks resumed elsewhere:\n",
        "every replayed walk resumed its ray where the node's kernel did",
    )


if __name__ == "__main__":
    sys.exit(main())
