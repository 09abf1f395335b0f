"""Stress: a render of over 10^7 rays on a 3x3 mesh over real (virtual) network devices, the
link from node 0 to node 1 delayed and node 2's cable rate-limited, a node killed mid-frame
and, once the frame has been re-planned and is tracing again, another paused (SIGSTOP) until
the host gives it up.

    sudo python -m bench.stress [--scene balls.nff] [--scenes DIR] [--size 768] [--spp 4]
                                [--delay 0.02] [--rate 200mbit] [--silence 5]

Nodes run in network namespaces (tests/netns.py: root and iproute2 needed), the host in this
one. The rate limit is the kernel's token bucket on node 2's cable; the delay holds every ray
message node 0 sends node 1 DELAY seconds (tests/faultnode.py: the kernels here have no netem
qdisc to delay packets).

Printed: the single node's and the mesh's ray counts and the rays lost (count differences
plus rays created but never ended: must be 0), the largest pixel difference to the single
node's image (must be 0 within float round-off), each lost node with the reason and when, the
recovery time (first loss to the frame's end), and the peak resident memory of the host and
of every node process. Exits 1 if a ray was lost or the image differs.
"""

import argparse
import asyncio
import os
import resource
import signal
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option  # noqa: E402 (after the path is set)
from host.planning.request import Request  # noqa: E402
from host.run.connections import Nodes  # noqa: E402
from meshnode.engine.counters import RAY_COUNTS

COUNTS = RAY_COUNTS


def vm_hwm(pid: int) -> int:
    """Peak resident bytes of a live process (Linux /proc), 0 when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


async def faulted_render(scene, image, engine, mesh, addresses, silence: float) -> tuple:
    """The mesh render with the two faults; returns (image, stats, peaks by node)."""
    from host.run.meshclient import render_on_mesh
    from protocols.render import MeshPlan

    n = len(addresses)
    killed, paused = n - 1, n - 2
    traced = {"attempt": 0, "rays": 0}
    first_rays, replanned = asyncio.Event(), asyncio.Event()
    peaks: dict[int, int] = {}

    def progress(k: int) -> None:
        traced["rays"] += k
        if k > 0:
            first_rays.set()
            if traced["attempt"] == 1 and traced["rays"] > 0:
                replanned.set()

    def notice(text: str) -> None:
        print(f"host: {text}", file=sys.stderr)
        traced["attempt"] += 1
        traced["rays"] = 0

    task = asyncio.create_task(
        render_on_mesh(
            Request(scene, image, engine, plan=MeshPlan(3, 3, 2)),
            Nodes(addresses, secret=mesh.secret),
            progress=progress,
            notice=notice,
            silence=silence,
        )
    )
    await asyncio.wait_for(first_rays.wait(), 300)
    peaks[killed] = vm_hwm(mesh.procs[killed].pid)
    print(f"killing node {killed} (pid {mesh.procs[killed].pid}) mid-frame", file=sys.stderr)
    os.kill(mesh.procs[killed].pid, signal.SIGKILL)
    await asyncio.wait_for(replanned.wait(), 300)
    print(
        f"pausing node {paused} (pid {mesh.procs[paused].pid}) in the re-planned frame",
        file=sys.stderr,
    )
    os.kill(mesh.procs[paused].pid, signal.SIGSTOP)
    try:
        img, stats = await asyncio.wait_for(task, 1800)
    finally:
        os.kill(mesh.procs[paused].pid, signal.SIGCONT)
    for i, proc in enumerate(mesh.procs):
        peaks.setdefault(i, vm_hwm(proc.pid))
    return img, stats, peaks


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.stress", description=__doc__.splitlines()[0])
    add_scenes_option(p)
    p.add_argument("--scene", default="balls.nff")
    p.add_argument("--size", type=int, default=768)
    p.add_argument("--spp", type=int, default=4)
    p.add_argument(
        "--delay",
        type=float,
        default=0.02,
        help="seconds each ray message from node 0 to node 1 is held",
    )
    p.add_argument("--rate", default="200mbit", help="rate limit on node 2's cable")
    p.add_argument(
        "--silence", type=float, default=5.0, help="seconds before a silent node is given up"
    )
    args = p.parse_args(argv)

    import numpy as np

    from host.run.oneprocess import render
    from host.scene.nff import read_nff
    from protocols.render import EngineSpec, ImageSpec
    from tests import netns

    if not netns.available():
        print("bench.stress: network namespaces need root and iproute2", file=sys.stderr)
        return 2
    scene = read_nff(args.scenes / args.scene)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    start = time.perf_counter()
    ref, ref_stats = render(Request(scene, image, EngineSpec(threads=0)))
    single_s = time.perf_counter() - start
    total = sum(
        ref_stats["rays"][k]
        for k in ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")
    )
    print(f"single node: {total:,} rays in {single_s:.1f} s", file=sys.stderr)

    root = str(Path(__file__).resolve().parents[1])
    slow = {
        "module": "tests.faultnode",
        "options": ["--slow-link", f"0,1,{args.delay},1000000000"],
        "env": {"PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")},
    }
    start = time.perf_counter()
    with netns.namespaced_mesh(9, lambda net: net.shape(2, rate=args.rate), **slow) as (
        _,
        mesh,
        addresses,
    ):
        img, stats, peaks = asyncio.run(
            faulted_render(scene, image, EngineSpec(threads=1), mesh, addresses, args.silence)
        )
    wall = time.perf_counter() - start
    r = stats["rays"]
    created = r["eye_rays"] + r["reflected_rays"] + r["refracted_rays"] + r["shadow_rays"]
    ended = r["hits"] + r["escaped"] + r["shadow_rays_blocked"] + r["shadow_rays_lit"]
    lost = sum(abs(r[k] - ref_stats["rays"][k]) for k in COUNTS) + abs(created - ended)
    diff = float(np.abs(img - ref).max())
    print(
        f"\n{args.scene} {args.size}x{args.size} spp {args.spp}: 3x3 mesh in namespaces, "
        f"ray messages node 0 -> 1 held {args.delay:g} s each, node 2's cable limited to "
        f"{args.rate}"
    )
    print(f"{'count':22} {'single node':>14} {'mesh':>14}")
    for k in COUNTS:
        print(f"{k:22} {ref_stats['rays'][k]:>14,} {r[k]:>14,}")
    print(f"rays created {created:,}, ended {ended:,}; rays lost: {lost}")
    print(f"largest pixel difference to the single node: {diff:.3g}")
    for d in stats["lost_nodes"]:
        print(f"lost node {d['node']} ({d['address']}) at {d['at_seconds']:.1f} s: {d['reason']}")
    print(
        f"final mesh {stats['mesh']['rows']}x{stats['mesh']['cols']}; recovery (first loss "
        f"to frame end) {stats['recovery_seconds']:.1f} s; render wall "
        f"{stats['wall_seconds']:.1f} s, with namespaces and processes {wall:.1f} s; single "
        f"node {single_s:.1f} s"
    )
    host_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(
        f"peak RSS: host {host_peak / 2**20:.0f} MiB; nodes "
        + ", ".join(f"{i}: {peaks[i] / 2**20:.0f} MiB" for i in sorted(peaks))
    )
    return 0 if lost == 0 and diff <= 1e-5 and len(stats["lost_nodes"]) == 2 else 1


if __name__ == "__main__":
    sys.exit(main())
