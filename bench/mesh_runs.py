"""Renders on a local mesh of `meshnode` processes, taking turns with one node in this process
or measured at the same time as it: this machine's speed moves by the minute and each core's
by the second, so both sides of a speedup must share the same spells."""

import asyncio
import json
import pickle
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.mesh_reference import single
from host.planning.request import Auto, Request
from host.run.connections import Nodes

AT_ONCE_RENDERS = 1000  # mesh renders while one node renders, at most
AT_ONCE_WAIT = 600  # seconds one node's process may take to finish after them


def on_mesh(
    scene,
    image,
    rows,
    cols,
    overlap,
    threads=1,
    balance="even",
    mode="object",
    tiles="static",
    steal=False,
    repeat=1,
    tile=32,
    copies=False,
    together=0,
    order="rows",
    camera=None,
    max_share=1.0,
    budget_copies=True,
    nodes_cpu=None,
    share_claims=True,
):
    """(wall seconds, stats, one node's run) of the render on a local mesh: of `repeat`
    renders on the same running nodes, the one whose busiest node traced least; its
    `setup_seconds` are the first render's (engines built), `setup_reused_seconds` its own
    (engines kept). One node renders in this process before each mesh render, taking turns
    with it, and the best of those runs is the row's reference: this machine's speed moves
    by up to 1.6x for minutes at a time, so the two sides are measured over the same span.
    Then `together` times both at once (`at_once`): the stats' `together` holds each
    window's one-node CPU seconds and its mesh renders' mean busiest-node CPU seconds.
    `nodes_cpu`: every node runs on that one CPU (`pinned`); `share_claims`: under the
    budget's copies, each copied cell's own work shared over its holders."""
    from host.planning.holding import OVERLAPS
    from host.run.localmesh import LocalMesh
    from host.run.meshclient import render_on_mesh
    from protocols.render import MeshPlan

    auto = overlap == "auto"  # the pre-pass chooses (`--overlap auto`)
    plan = MeshPlan(
        rows,
        cols,
        OVERLAPS[0] if auto else overlap,
        balance,
        mode,
        tiles,
        tile=tile,
        steal=steal,
        copies=copies,
        order=order,
        max_share=max_share,
    )
    runs, singles, windows = [], [], []

    def mesh_render():
        start = time.perf_counter()
        _, stats = asyncio.run(
            render_on_mesh(
                Request(
                    scene,
                    image,
                    camera=camera,
                    plan=plan,
                    auto=Auto(
                        overlaps=OVERLAPS if auto else (),
                        budget_copies=budget_copies,
                        share_claims=share_claims,
                    ),
                ),
                Nodes(addresses),
            )
        )
        if stats["lost_nodes"]:  # re-planned on fewer nodes: not the row's mesh
            raise RuntimeError(f"{rows}x{cols}: nodes lost {stats['lost_nodes']}")
        return start, time.perf_counter(), stats

    with LocalMesh(rows * cols, threads=threads, once=False, wrap=pinned(nodes_cpu)) as addresses:
        for _ in range(repeat):
            singles.append(single(scene, image, warm=False, camera=camera))
            start, end, stats = mesh_render()
            runs.append((end - start, stats))
        for _ in range(together):
            windows.append(at_once((scene, image, camera), mesh_render))
    wall, best = min(runs, key=lambda r: r[1]["busiest_node_cpu_seconds"])
    best["together"] = windows
    best["setup_reused_seconds"] = best["setup_seconds"]
    best["setup_seconds"] = runs[0][1]["setup_seconds"]
    best["paired_speedups"] = [
        one[1]["trace_cpu_seconds"] / run[1]["busiest_node_cpu_seconds"]
        for one, run in zip(singles, runs, strict=True)
    ]
    return wall, best, min(singles, key=lambda r: r[1]["trace_cpu_seconds"])


def at_once(job: tuple, mesh_render) -> dict:
    """One node and the mesh measured over the same seconds: one node renders `job` (scene,
    image, camera) in a process of its own (`bench.one_process`) while the mesh renders
    again and again until it is done; the mesh renders that ended within its measured frame
    (at least the one that overlapped it most) give the mean busiest-node CPU seconds.
    This machine's cores change speed by up to 25% within seconds, each on its own, so one
    node measured before or after the mesh can land on a fast spell and the mesh on a slow
    one; at once, both share the same spells of both cores and the same load (every core
    busy, the tracing threads time-shared). In a process of its own, one node's whole
    process CPU for the frame is its own, the figure a node's frame CPU compares with (on a
    thread of this process it was mixed with the mesh's host)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "job.pickle"
        path.write_bytes(pickle.dumps(job))
        ref = subprocess.Popen(
            [sys.executable, "-m", "bench.one_process", str(path)],
            stdout=subprocess.PIPE,
            cwd=Path(__file__).resolve().parents[1],
        )
        try:
            renders = [mesh_render()]
            while ref.poll() is None and len(renders) < AT_ONCE_RENDERS:
                renders.append(mesh_render())
            out, _ = ref.communicate(timeout=AT_ONCE_WAIT)
        finally:
            if ref.poll() is None:
                ref.kill()
                ref.wait()
    if ref.returncode != 0:
        raise RuntimeError(f"at once: one node's process failed (exit {ref.returncode})")
    one = json.loads(out.decode().strip().splitlines()[-1])
    inside = _within(renders, one["began"], one["ended"])
    busiest = [r[2]["busiest_node_cpu_seconds"] for r in inside]
    frame = [r[2]["busiest_node_frame_cpu_seconds"] for r in inside]
    return {
        "one_node_cpu_seconds": one["trace_cpu_seconds"],
        "one_node_frame_cpu_seconds": one["frame_cpu_seconds"],
        "busiest_cpu_seconds": statistics.fmean(busiest),
        # the whole process's CPU of the busiest node (`frame_cpu_seconds`), against one
        # node's whole process for the frame
        "busiest_frame_cpu_seconds": statistics.fmean(frame),
        "mesh_renders": len(inside),
        "window": (one["began"], one["ended"]),  # one node's measured frame (perf_counter)
    }


def _within(renders: list, began: float, ended: float) -> list:
    """The mesh renders (start, end, stats) that ended within began..ended, else the one
    that overlapped it most."""
    inside = [r for r in renders if began <= r[1] <= ended]
    if inside:
        return inside
    return [max(renders, key=lambda r: min(r[1], ended) - max(r[0], began))]


def pinned(cpu: int | None):
    """LocalMesh's `wrap` running every node on CPU `cpu` (None: where the system puts it).
    Nodes on one run queue share its CPU evenly; spread over two, an odd count leaves those on
    the fuller queue less (4x4 image space, dynamic tiles: the nodes' CPU 0.384-0.446 s spread
    over both cores, 0.413-0.424 on one), and a dealer that deals by arrival gives the
    others more work."""
    if cpu is None:
        return None
    if shutil.which("taskset") is None:
        raise SystemExit("--nodes-on-cpu needs taskset (util-linux)")
    return lambda node: ["taskset", "--cpu-list", str(cpu)]
