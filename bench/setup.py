"""Setup against mesh size: how long a mesh takes from the host's plan to every node built and
linked, measured on local meshes and simulated for meshes this machine cannot run (issue 38).

    python -m bench.setup [--scenes DIR] [--only tetra8,balls,gears] [--measured 1x2,2x2,3x3,4x4]
                          [--simulated 8x8,16x16] [--mode object] [--bandwidth 1e9] [--json FILE]

Measured: one render of a 16x16 image (tracing negligible) on a fresh local mesh of each size
(warm kernel cache, no engine reused), its summary's plan seconds (the host's planning:
cells, clipping, holders), configure seconds (CONFIG and every node's objects sent: the host
sends them node after node) and setup seconds (from the plan's start until every node has
built its engine and linked its neighbours). Simulated: the same plan made in this process
(real seconds), every node's objects sent one after the other at `--bandwidth` bytes a second
(the host's link), and the slowest node's build (each node's NodeCore made here, one after
another, timed on its own) and a fresh process's start (importing, loading the kernels from
the disk cache and building a small engine, measured once in a subprocess): plan + send +
slowest build + start, the figure a mesh of that size would show on machines of its own,
builds in parallel. (Measured meshes share this machine's two cores: a 4x4's sixteen
processes load their kernels and build at once, so its setup is mostly waiting for a core.)
`tetra8` is the SPD tetrahedron at size factor 8 (65,536 triangles), generated.
"""

import argparse
import asyncio
import json
import subprocess
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option  # noqa: E402 (after the path is set)
from host.planning.request import Request  # noqa: E402
from host.run.connections import Nodes  # noqa: E402

SIZE = 16  # image side: tracing takes no time next to setup


def load(name: str, scenes: Path):
    """An SPD scene by name: `tetra8` generated, others read from `scenes` or generated
    where an SPD program makes them (`bench.read_scene`: the full mountain)."""
    if name == "tetra8":
        from bench.generate import tetra

        return tetra(8)
    from bench import read_scene

    return read_scene(scenes, name)


def measured(scene, rows: int, cols: int, mode: str) -> dict:
    """Plan, configure and setup seconds of one render on a fresh local mesh."""
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    with LocalMesh(rows * cols) as addresses:
        _, stats = asyncio.run(
            render_on_mesh(
                Request(
                    scene,
                    ImageSpec(width=SIZE, height=SIZE),
                    EngineSpec(threads=1),
                    plan=MeshPlan(rows, cols, mode=mode),
                ),
                Nodes(addresses),
            )
        )
    return {
        "plan": stats["plan_seconds"],
        "configure": stats["configure_seconds"],
        "setup": stats["setup_seconds"],
        "build_max": max(n["engine"]["preprocess_seconds"] for n in stats["nodes"]),
    }


def simulated(scene, rows: int, cols: int, mode: str, bandwidth: float, process: float) -> dict:
    """Plan (real), send (bytes / bandwidth, node after node), the slowest build and a
    `process`'s start."""
    from host.planning.plan import plan_render
    from host.scene.subset import subset
    from meshnode.mesh.node import NodeCore
    from protocols.render import EngineSpec, ImageSpec, MeshPlan
    from protocols.scene import SCENE_TABLES

    engine = EngineSpec(threads=1)
    planned = plan_render(
        Request(
            scene, ImageSpec(width=SIZE, height=SIZE), engine, plan=MeshPlan(rows, cols, mode=mode)
        )
    )
    part, sent, slowest = planned.partition, 0, 0.0
    for n in range(part.nodes):
        held = subset(scene, planned.holders[n])
        sent += sum(getattr(held, t).nbytes for t in SCENE_TABLES)
        start = time.perf_counter()
        NodeCore(n, held, planned.spec, part)  # as the node builds it (a cache of its own)
        slowest = max(slowest, time.perf_counter() - start)
    plan = planned.seconds
    return {
        "plan": plan,
        "configure": sent / bandwidth,
        "setup": plan + sent / bandwidth + slowest + process,
        "build_max": slowest,
    }


def process_start() -> float:
    """Seconds a fresh process takes to import the engine, load a variant's kernels from the
    disk cache and build and warm a one-sphere engine (what every node pays once)."""
    code = (
        "import time; t = time.perf_counter(); "
        "from bench.generate import balls; from meshnode.engine import Engine; "
        "e = Engine(balls(0)); e.warmup(); print(time.perf_counter() - t)"
    )
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=root, check=True
    )
    return float(out.stdout.split()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.setup", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="tetra8,balls,gears")
    p.add_argument("--measured", default="1x2,2x2,3x3,4x4")
    p.add_argument("--simulated", default="8x8,16x16")
    p.add_argument("--mode", default="object", choices=("object", "image"))
    p.add_argument("--bandwidth", type=float, default=1e9, help="host link, bytes a second")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    rows_out = []
    start = process_start()
    print(f"a fresh process's start (imports, kernels loaded, a small engine): {start:.2f} s")
    print(
        f"{'scene':>8} {'mesh':>6} {'how':>9} {'plan s':>7} {'send s':>7} {'build s':>8} "
        f"{'setup s':>8}"
    )
    for name in args.only.split(","):
        scene = load(name, args.scenes)
        meshes = [(m, "measured") for m in args.measured.split(",") if m] + [
            (m, "simulated") for m in args.simulated.split(",") if m
        ]
        for mesh, how in meshes:
            rows, cols = (int(v) for v in mesh.split("x"))
            if how == "measured":
                got = measured(scene, rows, cols, args.mode)
            else:
                got = simulated(scene, rows, cols, args.mode, args.bandwidth, start)
            print(
                f"{name:>8} {mesh:>6} {how:>9} {got['plan']:>7.3f} {got['configure']:>7.3f} "
                f"{got['build_max']:>8.3f} {got['setup']:>8.3f}",
                flush=True,
            )
            rows_out.append({"scene": name, "mesh": mesh, "how": how, **got})
    if args.json:
        args.json.write_text(json.dumps(rows_out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
