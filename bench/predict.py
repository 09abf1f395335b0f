"""Predicted mesh speedups from the simulated mesh (meshnode.mesh.simulator: every node's NodeCore
and Scheduler in one process, work counted in the engine's own units: intersection tests,
hierarchy and occupancy map steps, segments and segments sent on, each weighted by its
fitted cost: `meshnode.mesh.stats.work_units`), for
meshes larger than this machine can run, next to measured ones.

    python -m bench.predict [--scenes DIR] [--only balls,gears] [--meshes 2x2,3x3,4x4,8x8,16x16]
                            [--size 128] [--modes object+steal,image dynamic] [--overlaps 2,24]
                            [--measured image.json object.json] [--json FILE]

Per scene, mesh and mode (object space at each overlap: with stealing, cuts even or from the cost
pre-pass, with or without the neighbours' copies, and cost cuts without stealing; image
space, dynamic tiles): the predicted
speedup = the one-node cost / the busiest node's cost, and rays passed. `--measured FILES`
(JSON that `bench.mesh --json` writes) puts the measured busiest-CPU speedups of the same
scene, mesh and mode beside the predictions, with their ratio, and the measured speedup in
work units (what the model counts): the model has no per-batch, per-process or per-message
cost, so it predicts an upper bound of the CPU speedup.
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option  # noqa: E402 (after the path is set)
from host.planning.request import Auto, Request  # noqa: E402

# A message's flight under --clock work, as a share of one node's whole render: on loopback
# taken as 60 us (an asyncio message between two local processes) against a render one node
# traces in about 6 s (what bench.mesh --min-trace 5 measures).
LATENCY_SHARE = 1e-5
TILES_PER_NODE = 32  # a 4x4 mesh of bench.mesh's tiles has 36 a node

MODES = {
    "object+steal": {"mode": "object", "steal": True},
    "object+steal+cost": {"mode": "object", "steal": True, "balance": "cost"},
    "object+cost": {"mode": "object", "balance": "cost"},
    "object+steal+copies": {"mode": "object", "steal": True, "copies": True},
    "object+steal+cost+copies": {
        "mode": "object",
        "steal": True,
        "balance": "cost",
        "copies": True,
    },
    "image none": {"mode": "image", "tiles": "none"},
    "image static": {"mode": "image", "tiles": "static"},
    "image dynamic": {"mode": "image", "tiles": "dynamic"},
}


def simulated(
    scene,
    rows: int,
    cols: int,
    size: int,
    plan: dict,
    overlap: float | str = 2,
    clock: str = "rounds",
    latency: float = 0.0,
):
    """(busiest node's cost, total cost, rays passed, overlap, makespan) of a simulated
    render, planned as `host render` plans it (`overlap` "auto": the pre-pass chooses, with
    no memory bound), on the simulator's `clock` (a message's `latency` in work units)."""
    from host.planning.holding import OVERLAPS
    from host.planning.plan import plan_render
    from host.scene.subset import subset
    from meshnode.mesh.simulator import simulate
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    image = ImageSpec(width=size, height=size)
    # tiles (and stealing's chunks) as bench.mesh's 32 px at 768 px (576 tiles), but at
    # least TILES_PER_NODE a node where 2 px tiles allow it (a 16x16 mesh of 128 px: 16 a
    # node): 1,024 tiles left a 16x16 mesh 4 each, too few to deal out
    tile = max(2, min(size // 24, int(size / math.sqrt(TILES_PER_NODE * rows * cols))))
    auto = overlap == "auto"
    mesh = MeshPlan(rows, cols, OVERLAPS[0] if auto else overlap, tile=tile, **plan)
    planned = plan_render(
        Request(scene, image, EngineSpec(), plan=mesh, auto=Auto(overlaps=OVERLAPS if auto else ()))
    )
    part, keep = planned.partition, planned.holders
    out = simulate(
        [subset(scene, keep[n]) for n in range(part.nodes)],
        planned.spec,
        part,
        clock=clock,
        latency=latency,
    )
    costs = [n.cost for n in out.nodes]
    return (
        max(costs),
        sum(costs),
        sum(n.rays_sent for n in out.nodes),
        planned.spec.plan.overlap,
        out.makespan,
    )


def measured_table(paths: list[Path]) -> dict:
    """(scene, mesh, mode, overlap) -> (measured CPU speedup, measured work speedup), from
    `bench.mesh --json` files (the later file wins; image space: overlap None)."""
    rows = [r for path in paths for r in json.loads(path.read_text())]
    out = {}
    for r in rows:
        overlap = None
        if r["mode"] == "image":
            mode = f"image {r['cuts']}" if f"image {r['cuts']}" in MODES else None
        else:
            mode = {
                "even+steal": "object+steal",
                "cost+steal": "object+steal+cost",
                "cost": "object+cost",
                "even+steal+copies": "object+steal+copies",
                "cost+steal+copies": "object+steal+cost+copies",
            }.get(r["cuts"])
            overlap = r["overlap"]
        if mode:
            out[(r["scene"], r["mesh"], mode, overlap)] = (r["speedup"], r.get("work_speedup"))
    return out


def runs(modes: list[str], overlaps: list[float]):
    """(mode, overlap) pairs to simulate: object-space modes at every overlap, image space
    once (overlap None: every node holds the whole scene)."""
    for mode in modes:
        for overlap in [None] if MODES[mode]["mode"] == "image" else overlaps:
            yield mode, overlap


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.predict", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,gears")
    p.add_argument("--meshes", default="2x2,3x3,4x4,8x8,16x16")
    p.add_argument("--size", type=int, default=128, help="simulated image side (coarse)")
    p.add_argument("--modes", default=",".join(MODES), help=f"of {', '.join(MODES)}")
    p.add_argument(
        "--overlaps",
        default="2",
        help="object space: box overlaps (percent; "
        "auto: the pre-pass chooses, as `--overlap auto` does)",
    )
    p.add_argument(
        "--clock",
        choices=("work", "rounds"),
        default="work",
        help="work: each node's clock moves by the work it does, so what stealing "
        "and dynamic tiles even out is seen; rounds: one batch a node a turn",
    )
    p.add_argument(
        "--latency",
        type=float,
        default=LATENCY_SHARE,
        help="clock work: a message's flight as a share of one node's whole render "
        f"(default {LATENCY_SHARE:g}: 60 us of a 6 s render)",
    )
    p.add_argument(
        "--measured",
        type=Path,
        nargs="+",
        default=[],
        help="bench.mesh --json outputs to compare with",
    )
    p.add_argument("--json", type=Path, help="write the rows to this JSON file")
    args = p.parse_args(argv)
    unknown = set(args.modes.split(",")) - set(MODES)
    if unknown:
        p.error(f"unknown modes {', '.join(sorted(unknown))}: choose from {', '.join(MODES)}")
    from bench import read_scene

    measured = measured_table(args.measured)
    overlaps = [v if v == "auto" else float(v) for v in args.overlaps.split(",")]
    table = []
    for name in args.only.split(","):
        scene = read_scene(args.scenes, name)
        one, *_ = simulated(scene, 1, 1, args.size, {})
        latency = args.latency * one if args.clock == "work" else 0.0
        print(
            f"\n== {name}: {args.size}x{args.size} simulated, one node's cost {one:,}, "
            f"clock {args.clock}" + (f", latency {latency:,.1f}" if latency else "")
        )
        print(
            f"{'mesh':>6} {'mode':>24} {'overlap':>7} {'predicted':>9} {'wall':>5} "
            f"{'measured':>8} {'ratio':>5} {'work':>5} {'rays passed':>11} "
            f"{'seconds':>7}"
        )
        for mesh in args.meshes.split(","):
            rows, cols = (int(v) for v in mesh.split("x"))
            for mode, overlap in runs(args.modes.split(","), overlaps):
                start = time.perf_counter()
                busiest, _, passed, used, makespan = simulated(
                    scene, rows, cols, args.size, MODES[mode], overlap or 0, args.clock, latency
                )
                predicted = one / busiest
                wall = f"{one / makespan:5.2f}" if makespan else f"{'-':>5}"
                got, got_work = measured.get((name, mesh, mode, overlap), (None, None))
                seen = f"{got:8.2f} {got / predicted:5.2f}" if got else f"{'-':>8} {'-':>5}"
                seen += f" {got_work:5.2f}" if got_work else f" {'-':>5}"
                shown = "-" if overlap is None else f"{used:g}"
                shown = f"auto:{shown}" if overlap == "auto" else shown
                print(
                    f"{mesh:>6} {mode:>24} {shown:>7} {predicted:>9.2f} {wall} {seen} "
                    f"{passed:>11,} "
                    f"{time.perf_counter() - start:>7.1f}",
                    flush=True,
                )
                table.append(
                    {
                        "scene": name,
                        "mesh": mesh,
                        "mode": mode,
                        "overlap": overlap,
                        "overlap_used": used if overlap is not None else None,
                        "predicted": predicted,
                        "clock": args.clock,
                        "predicted_wall": one / makespan if makespan else None,
                        "measured": got,
                        "measured_work": got_work,
                        "rays_passed": passed,
                    }
                )
    if args.json:
        args.json.write_text(json.dumps(table, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
