"""What losing a node costs: one frame in dynamic image space on a local mesh, with and without
a node killed once about half of its primary rays are traced, side by side (issue 41).

    python -m bench.loss [--mesh 3x3] [--runs 3] [--size 256] [--spp 16] [--scene balls]

Each run starts a fresh local mesh for each of the two renders (so the killed node's mesh is
not reused), taking turns: no loss, loss, no loss, loss, ... Prints each render's wall seconds
(plan, setup and frame, as `render_on_mesh` reports them), the tiles the host kept from the
lost try, and the ratio loss / no loss per run and its median. Both images must equal one
node's (checked).
"""

import argparse
import asyncio
import os
import signal
import statistics
import sys
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from host.planning.request import Request  # noqa: E402
from host.run.connections import Nodes  # noqa: E402


async def render_losing(
    scene, image, addresses, plan, engine, total: int, victim, wait=300.0, share=0.5
):
    """(image, stats) of a render on running nodes at `addresses`, process `victim` (None:
    none) killed once `share` of the `total` primary rays are reported traced (the sky's,
    which the host deposits as the frame starts, among them); `wait` bounds each step."""
    from host.run.meshclient import render_on_mesh

    half, traced = asyncio.Event(), [0]

    def progress(rays: int) -> None:
        traced[0] += rays
        if traced[0] >= share * total:
            half.set()

    task = asyncio.create_task(
        render_on_mesh(
            Request(scene, image, engine, plan=plan),
            Nodes(addresses),
            silence=4.0,
            progress=progress,
        )
    )
    if victim is not None:
        await asyncio.wait_for(half.wait(), wait)
        os.kill(victim.pid, signal.SIGKILL)
    return await asyncio.wait_for(task, 2 * wait)


def one_render(scene, image, plan, engine, total: int, kill: bool):
    """(image, stats) of one render on a fresh local mesh, a node killed at half the primary
    rays when `kill`."""
    from host.run.localmesh import LocalMesh

    mesh = LocalMesh(plan.nodes)
    with mesh as addresses:
        victim = mesh.procs[plan.nodes // 2] if kill else None
        return asyncio.run(render_losing(scene, image, addresses, plan, engine, total, victim))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.loss", description=__doc__.split("\n\n")[0])
    p.add_argument("--mesh", default="3x3")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--scene", default="balls", help="a generated SPD scene (bench.generate)")
    args = p.parse_args(argv)
    from bench.generate import spd
    from host.run.oneprocess import render
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    rows, cols = (int(v) for v in args.mesh.split("x"))
    scene = spd(args.scene)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    engine = EngineSpec(threads=1)
    plan = MeshPlan(rows, cols, mode="image", tiles="dynamic")
    ref, ref_stats = render(Request(scene, image, engine))
    total = ref_stats["rays"]["eye_rays"]
    print(f"{args.scene} {args.size}x{args.size} at {args.spp} spp on {args.mesh}, image dynamic")
    print(f"{'run':>3} {'no loss s':>9} {'loss s':>7} {'kept tiles':>11} {'ratio':>6}")
    ratios = []
    for run in range(1, args.runs + 1):
        walls, kept = [], None
        for kill in (False, True):
            img, stats = one_render(scene, image, plan, engine, total, kill)
            np.testing.assert_allclose(img, ref, rtol=0, atol=1e-5)
            walls.append(stats["wall_seconds"])
            if kill:
                kept = stats["recovery"]
        ratios.append(walls[1] / walls[0])
        shown = f"{kept.get('tiles_kept', 0)}/{kept.get('tiles', '-')}"
        print(f"{run:>3} {walls[0]:>9.2f} {walls[1]:>7.2f} {shown:>11} {ratios[-1]:>6.2f}")
    print(f"median ratio loss / no loss: {statistics.median(ratios):.2f} (every image one node's)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
