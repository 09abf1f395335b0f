"""A scene no single node can hold, rendered on a mesh whose every node holds a part of it:
the mission of object space, measured.

    python -m bench.divided [--tetra 8] [--mesh 3x3] [--fraction 4.5] [--size 256] [--spp 64]
                            [--json FILE]

Generates the SPD tetra at size factor `--tetra` in memory (8: 65,536 triangles), gives every
node of a local `--mesh` a memory budget (`--node-memory`) of its whole engine divided by
`--fraction` (at least 4: no node could hold the scene), renders it there with cells cut by
the objects and evened on the pre-pass's work, and renders it on one node in this process
without a budget. Prints the whole engine and the budget, every node's engine bytes (by its
own report), share of the objects and frame CPU, setup seconds, the speedup on the busiest
node's whole process CPU for the frame (one process's frame CPU over it; the kernels' beside
it), rays passed per ray traced, and whether the image and the ray counts equal one node's.
Exit 1 when they differ or a node went over its budget.
"""

import argparse
import asyncio
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench import finish  # noqa: E402
from host.planning.request import Auto, Request  # noqa: E402
from host.run.connections import Nodes  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.divided", description=__doc__.split("\n\n")[0])
    p.add_argument("--tetra", type=int, default=8, help="SPD tetra size factor (4^n triangles)")
    p.add_argument("--mesh", default="3x3")
    p.add_argument("--fraction", type=float, default=4.5, help="whole engine / node budget")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    if args.fraction < 4:
        p.error("--fraction must be at least 4: the point is a scene no node can hold")
    from bench.generate import tetra
    from host.planning.holding import engine_bytes
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh
    from host.run.oneprocess import render
    from meshnode.engine.counters import RAY_COUNTS
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    rows, cols = (int(v) for v in args.mesh.split("x"))
    scene = tetra(args.tetra)
    whole = engine_bytes(scene)
    budget = int(whole / args.fraction)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    one = EngineSpec(threads=1)
    render(Request(scene, ImageSpec(width=16, height=16), one), progress=False)  # kernels loaded
    ref, ref_stats = render(Request(scene, image, one), progress=False)
    print(
        f"tetra {args.tetra}: {len(scene.triangles):,} triangles, whole engine about "
        f"{whole / 2**20:.1f} MiB; each of {rows}x{cols} nodes may hold {budget / 2**20:.1f} MiB "
        f"(1/{args.fraction:g}); {args.size}x{args.size} at {args.spp} spp"
    )
    print(
        f"one node, no budget: frame CPU {ref_stats['frame_cpu_seconds']:.2f} s, kernels "
        f"{ref_stats['trace_cpu_seconds']:.2f} s"
    )
    with LocalMesh(rows * cols) as addresses:
        start = time.perf_counter()
        img, stats = asyncio.run(
            render_on_mesh(
                Request(
                    scene,
                    image,
                    one,
                    plan=MeshPlan(rows, cols, balance="objects"),
                    auto=Auto(mode="auto", node_memory=budget),
                ),
                Nodes(addresses),
            )
        )
        wall = time.perf_counter() - start
    nodes = stats["nodes"]
    total = len(scene.triangles)
    print(f"{'node':>4} {'engine MiB':>10} {'objects':>8} {'share':>6} {'frame CPU s':>11}")
    for n, held in zip(nodes, stats["objects_held_per_node"], strict=True):
        print(
            f"{n['node']:>4} {n['engine_bytes_held'] / 2**20:>10.2f} {held:>8,} "
            f"{held / total:>6.1%} {n['frame_cpu_seconds']:>11.2f}"
        )
    traced = sum(stats["rays"][k] for k in ("eye_rays", "reflected_rays", "shadow_rays"))
    row = {
        "tetra": args.tetra,
        "mesh": args.mesh,
        "whole_engine_bytes": whole,
        "node_budget_bytes": budget,
        "mode": stats["mesh"]["mode"],
        "node_engine_bytes": [n["engine_bytes_held"] for n in nodes],
        "objects_held_max_share": stats["objects_held_max_share"],
        "setup_seconds": stats["setup_seconds"],
        "wall_seconds": wall,
        "frame_speedup": ref_stats["frame_cpu_seconds"] / stats["busiest_node_frame_cpu_seconds"],
        "kernel_speedup": ref_stats["trace_cpu_seconds"] / stats["busiest_node_cpu_seconds"],
        "passes_per_ray": stats["rays_passed"] / max(traced, 1),
        "image_max_difference": float(np.abs(img - ref).max()),
        "counts_equal": all(stats["rays"][k] == ref_stats["rays"][k] for k in RAY_COUNTS),
    }
    print(
        f"mode {row['mode']}, fullest node {row['objects_held_max_share']:.1%} of the objects; "
        f"setup {row['setup_seconds']:.2f} s, wall {wall:.2f} s; speedup on frame CPU "
        f"{row['frame_speedup']:.2f} (kernels {row['kernel_speedup']:.2f}) on {rows * cols} "
        f"nodes; {row['passes_per_ray']:.3f} passes per ray; largest pixel difference "
        f"{row['image_max_difference']:.2g}, counts {'equal' if row['counts_equal'] else 'DIFFER'}"
    )
    bad = []
    if not row["counts_equal"] or row["image_max_difference"] > 1e-5:
        bad.append("the image or the ray counts differ from one node's")
    if max(row["node_engine_bytes"]) > budget or row["mode"] != "object":
        bad.append(f"a node went over its budget of {budget} bytes, or the mode was not object")
    return finish(
        [row], args.json, bad, "FAILED:\n", "every node within its budget; one node's image"
    )


if __name__ == "__main__":
    sys.exit(main())
