"""Setup against mesh size: how long a mesh takes from the host's plan to every node built and
linked, measured on local meshes and simulated for meshes this machine cannot run (issue 38).

    python -m bench.setup [--scenes DIR] [--only tetra8,balls,gears] [--measured 1x2,2x2,3x3,4x4]
                          [--simulated 8x8,16x16] [--mode object] [--max-share F]
                          [--bandwidth 1e9] [--json FILE]

Measured: a fresh local mesh of each size renders a 16x16 image (tracing negligible) twice,
keeping no engine between its renders (`meshnode serve --keep-engines 1`). The first render
is the cold start: each node loads its kernels from the disk cache as it builds (once in a
node's life). The second, of the scene read again (no plan, clip or table kept on the host),
is setup on nodes that are up: what every later render of a running cluster pays. Each gives
its summary's plan seconds (the host's planning: cells, clipping, holders, and under
`--max-share` the budget's cells and copies; a 16x16 render affords the cost pre-pass no
simulation, `host.planning.allowance`, where a larger one adds at most a tenth of its
tracing), configure seconds (CONFIG and every node's objects sent: the
host sends them node after node) and setup seconds (from the plan's start until every node
has built its engine and linked its neighbours). Simulated: the same plan made in this process
(real seconds), every node's objects sent one after the other at `--bandwidth` bytes a second
(the host's link), and the slowest node's build (each node's NodeCore made here, one after
another, timed on its own): plan + send + slowest build, the figure a mesh of that size would
show on machines of their own, builds in parallel; its cold start adds a fresh process's start
(importing, loading the kernels from the disk cache and building a small engine, measured once
in a subprocess). (Measured meshes share this machine's two cores: a 4x4's sixteen processes
load their kernels and build at once, so its cold setup is mostly waiting for a core.)
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
from host.planning.budget import BudgetError  # noqa: E402
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


def measured(name: str, scenes: Path, rows: int, cols: int, mode: str, share=None) -> dict:
    """Plan, configure and setup seconds of a fresh local mesh's first render (`cold`) and of
    its second (`warm`: kernels loaded, no engine kept, the scene read anew)."""
    from host.run.localmesh import LocalMesh

    with LocalMesh(rows * cols, once=False, options=["--keep-engines", "1"]) as addresses:
        cold = _timed(load(name, scenes), rows, cols, mode, share, addresses)
        warm = _timed(load(name, scenes), rows, cols, mode, share, addresses)
    return {**warm, "cold": cold}


def _timed(scene, rows: int, cols: int, mode: str, share, addresses) -> dict:
    """One render's setup figures from its summary."""
    from host.run.meshclient import render_on_mesh

    request = _request(scene, rows, cols, mode, share)
    _, stats = asyncio.run(render_on_mesh(request, Nodes(addresses)))
    if any(n["engine_reused"] for n in stats["nodes"]):
        raise RuntimeError("a node reused an engine: setup would not count its build")
    return {
        "plan": stats["plan_seconds"],
        "configure": stats["configure_seconds"],
        "setup": stats["setup_seconds"],
        "build_max": max(n["engine"]["preprocess_seconds"] for n in stats["nodes"]),
    }


def _request(scene, rows: int, cols: int, mode: str, share=None) -> Request:
    """A 16x16 render on a rows x cols mesh; under a budget of `share` (balance "objects",
    the budget's copies chosen) where one is given."""
    from host.planning.request import Auto
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    budget = {"balance": "objects", "max_share": share} if share else {}
    return Request(
        scene,
        ImageSpec(width=SIZE, height=SIZE),
        EngineSpec(threads=1),
        plan=MeshPlan(rows, cols, mode=mode, **budget),
        auto=Auto(budget_copies=bool(share)),
    )


def simulated(
    scene, rows: int, cols: int, mode: str, bandwidth: float, process: float, share=None
) -> dict:
    """Plan (real), send (bytes / bandwidth, node after node: its cell's objects and its
    copies') and the slowest build (its engines, copies too); cold, a `process`'s start
    added. `share`: planned under that budget."""
    from host.planning.plan import plan_render
    from host.scene.subset import subset
    from meshnode.mesh.node import NodeCore
    from protocols.scene import SCENE_TABLES

    planned = plan_render(_request(scene, rows, cols, mode, share))
    part, spec, sent, slowest = planned.partition, planned.spec, 0, 0.0
    cells = [subset(scene, planned.holders[n]) for n in range(part.nodes)]
    for n in range(part.nodes):
        copies = {m: cells[m] for m in spec.plan.holds[n]} if spec.plan.holds else {}
        for held in (cells[n], *copies.values()):
            sent += sum(getattr(held, t).nbytes for t in SCENE_TABLES)
        start = time.perf_counter()
        NodeCore(n, cells[n], spec, part, copies=copies)  # as the node builds them
        slowest = max(slowest, time.perf_counter() - start)
    setup = planned.seconds + sent / bandwidth + slowest
    return {
        "plan": planned.seconds,
        "configure": sent / bandwidth,
        "setup": setup,
        "build_max": slowest,
        "cold": {"setup": setup + process},
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
    p.add_argument(
        "--max-share",
        type=float,
        help="plan under this memory budget (balance objects, copies chosen)",
    )
    p.add_argument("--bandwidth", type=float, default=1e9, help="host link, bytes a second")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    rows_out = []
    start = process_start()
    print(f"a fresh process's start (imports, kernels loaded, a small engine): {start:.2f} s")
    print(
        f"{'scene':>8} {'mesh':>6} {'how':>9} {'plan s':>7} {'send s':>7} {'build s':>8} "
        f"{'setup s':>8} {'cold s':>7}   (nodes up, no engine kept; cold: their first render)"
    )
    for name in args.only.split(","):
        meshes = [(m, "measured") for m in args.measured.split(",") if m] + [
            (m, "simulated") for m in args.simulated.split(",") if m
        ]
        for mesh, how in meshes:
            rows, cols = (int(v) for v in mesh.split("x"))
            try:
                if how == "measured":
                    got = measured(name, args.scenes, rows, cols, args.mode, args.max_share)
                else:
                    scene = load(name, args.scenes)
                    got = simulated(
                        scene, rows, cols, args.mode, args.bandwidth, start, args.max_share
                    )
            except BudgetError as e:  # the plan's refusal, before any work: named
                print(f"{name:>8} {mesh:>6} {how:>9}  {str(e).split(': ', 1)[1]}")
                rows_out.append({"scene": name, "mesh": mesh, "how": how, "refused": str(e)})
                continue
            print(
                f"{name:>8} {mesh:>6} {how:>9} {got['plan']:>7.3f} {got['configure']:>7.3f} "
                f"{got['build_max']:>8.3f} {got['setup']:>8.3f} {got['cold']['setup']:>7.3f}",
                flush=True,
            )
            rows_out.append({"scene": name, "mesh": mesh, "how": how, **got})
    if args.json:
        args.json.write_text(json.dumps(rows_out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
