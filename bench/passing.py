"""How rays are gathered for passing, measured where it matters: a budgeted object-space render
that passes millions of rays, on local meshes whose nodes each gather another way, in turns.
A setting is RAYS/AGE/BATCH/EYE/SET/PROG/IDLE/RELAY/INLINE: rays leaving for a neighbour are
sent once RAYS wait (`meshnode.mesh.driver.PASS_RAYS`) or they have waited AGE batches
(`PASS_AGE`), queued incoming messages are merged into batches of up to BATCH rays
(`meshnode.mesh.scheduler.PASSED_BATCH`), eye rays are made EYE a batch
(`meshnode.mesh.node.EYE_BATCH`), and with SET 1 the RAYS that leave over one link together
go as one RAYS_SET frame, with 0 a frame each (`meshnode.service.sends.RAYS_SETS`), a node
tells the host its progress at most every PROG milliseconds
(`meshnode.service.session.PROGRESS_EVERY`), and with IDLE 1 it sends the deposits it holds
for the host each time it idles, with 0 once a packet's worth or the oldest has waited
(`IDLE_DEPOSITS`), and with RELAY 1 rays relayed through a node wait for its next send over
their link, with 0 each message's go on at once (`meshnode.service.sends.RELAYS_WAIT`), and
a passed batch of fewer than INLINE rays is traced on the event loop's thread
(`meshnode.service.session.INLINE_RAYS`); an absent part keeps the production value.

    python -m bench.passing [--scenes DIR] [--only balls,tetra] [--mesh 3x3] [--share 0.25]
                            [--size 384] [--spp 16] [--passing 16384/4/4096,16384/16/16384]
                            [--turns 2]

Each turn renders the scene once on every setting's mesh (after a first, warming render on
each), in the same order, so the machine's noise falls on all of them alike. Printed per
render: the nodes' user and system CPU summed from /proc over the render, the host's CPU
(this process's), the nodes' minor page faults, the busiest node's frame CPU, the rays
passed, the RAYS and PIXELS messages the nodes sent each other, and the PIXELS and PROGRESS
they sent the host; then each setting's medians over the turns and the ratio of its summed
CPU and of its busiest node's frame CPU to the first setting's. Every render's ray counts
must equal the first's and its image be within 1e-5 of it (object space sums a pixel's
deposits in the order they arrive; exit 1 if not).

`python -m bench.passing serve ... --passing SETTING` is such a node: the production service
with only those constants changed.
"""

import argparse
import asyncio
import statistics
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench import add_scenes_option, finish  # noqa: E402

SETTING = "RAYS/AGE/BATCH/EYE/SET/PROG/IDLE/RELAY/INLINE"


def serve(argv: list[str]) -> int:
    """A node that gathers rays as its `--passing` setting says."""
    from meshnode.mesh import driver, node, scheduler
    from meshnode.service import cli, sends, session

    at = argv.index("--passing")
    rays, age, batch, eye, sets, prog, idle, relay, inline = setting(argv[at + 1])
    driver.PASS_RAYS, driver.PASS_AGE, scheduler.PASSED_BATCH = rays, age, batch
    node.EYE_BATCH, sends.RAYS_SETS = eye, bool(sets)
    session.PROGRESS_EVERY, session.IDLE_DEPOSITS = prog / 1000, bool(idle)
    sends.RELAYS_WAIT, session.INLINE_RAYS = bool(relay), inline
    del argv[at : at + 2]
    return cli.main(argv)


def setting(text: str) -> tuple[int, ...]:
    """(PASS_RAYS, PASS_AGE, PASSED_BATCH, EYE_BATCH, RAYS_SETS, PROGRESS_EVERY in ms,
    IDLE_DEPOSITS, RELAYS_WAIT, INLINE_RAYS) of a setting (SETTING), absent parts the
    production values."""
    from meshnode.mesh import driver, node, scheduler
    from meshnode.service import sends, session

    parts = text.split("/")
    default = (
        driver.PASS_RAYS,
        driver.PASS_AGE,
        scheduler.PASSED_BATCH,
        node.EYE_BATCH,
        int(sends.RAYS_SETS),
        round(session.PROGRESS_EVERY * 1000),
        int(session.IDLE_DEPOSITS),
        int(sends.RELAYS_WAIT),
        session.INLINE_RAYS,
    )
    if len(parts) > len(default) or not all(p.isdigit() or p == "" for p in parts):
        raise SystemExit(f"bench.passing: {text!r} is not {SETTING} (whole numbers)")
    parts += [""] * (len(default) - len(parts))
    return tuple(int(p) if p else d for p, d in zip(parts, default, strict=True))


def _proc(pid: int) -> tuple[int, float, float]:
    """(minor page faults, user seconds, system seconds) of process `pid` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[7]), int(fields[11]) / 100, int(fields[12]) / 100


def _render(request, mesh, addresses) -> tuple[np.ndarray, dict, tuple]:
    """One render on the running `mesh`: (image, stats, (faults, user, system) of its nodes,
    and the host's CPU: this process's, which renders as `host render` does)."""
    from host.run.connections import Nodes
    from host.run.meshclient import render_on_mesh

    before = [_proc(p.pid) for p in mesh.procs]
    host = time.process_time()
    img, stats = asyncio.run(render_on_mesh(request, Nodes(addresses, wait=60)))
    host = time.process_time() - host
    after = [_proc(p.pid) for p in mesh.procs]
    spent = tuple(sum(a[i] - b[i] for a, b in zip(after, before, strict=True)) for i in range(3))
    return img, stats, (*spent, host)


def _messages(stats: dict) -> tuple[int, int, int]:
    """Messages the nodes sent each other (RAYS and PIXELS), and the host (PIXELS;
    PROGRESS, heartbeats included) over the frame."""
    nodes = stats["nodes"]
    return (
        sum(link["messages_out"] for n in nodes for link in n["links"].values()),
        sum(n.get("host_packets", 0) for n in nodes),
        sum(n.get("progress_sent", 0) for n in nodes),
    )


def _counts(stats: dict) -> dict:
    from meshnode.engine.counters import RAY_COUNTS

    return {k: stats["rays"][k] for k in RAY_COUNTS}


def bench_scene(args, name: str, rows: list, bad: list) -> None:
    """Every --passing setting's mesh up at once, rendered in turns."""
    from contextlib import ExitStack

    from bench import read_scene
    from host.planning.request import Request
    from host.run.localmesh import LocalMesh
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    r, c = (int(v) for v in args.mesh.split("x"))
    plan = MeshPlan(r, c, 1, balance="objects", max_share=args.share)
    image = ImageSpec(width=args.size, height=args.size, spp=args.spp)
    request = Request(read_scene(args.scenes, name), image, EngineSpec(threads=1), None, plan)
    sizes = [v.strip() for v in args.passing.split(",")]
    for v in sizes:
        setting(v)
    print(
        f"\n{name} {args.mesh}, at most {args.share:.0%} of the objects a node, "
        f"{args.size}x{args.size} at {args.spp} spp"
    )
    print(
        f"{'setting':>16} {'turn':>4} {'user s':>7} {'sys s':>6} {'host s':>6} {'faults':>7} "
        f"{'busiest frame s':>15} {'rays passed':>11} {'messages':>8} "
        f"{'host PIXELS':>11} {'PROGRESS':>8}"
    )
    with ExitStack() as stack:
        meshes = []
        for size in sizes:
            mesh = LocalMesh(r * c, once=False, module="bench.passing", options=["--passing", size])
            meshes.append((size, mesh, stack.enter_context(mesh)))
        ref = None
        for _, mesh, addresses in meshes:  # kernels loaded, engines built and cached
            img, stats, _ = _render(request, mesh, addresses)
            ref = (img, _counts(stats)) if ref is None else ref
        got = {size: [] for size in sizes}
        for turn in range(args.turns):
            for size, mesh, addresses in meshes:
                img, stats, (faults, user, system, host) = _render(request, mesh, addresses)
                off = float(np.abs(img - ref[0]).max())
                if off > 1e-5 or _counts(stats) != ref[1]:
                    bad.append(f"{name} setting {size} turn {turn}: {off:.3g} off, or counts")
                busiest = stats["busiest_node_frame_cpu_seconds"]
                got[size].append((user + system, busiest))
                links, packets, progress = _messages(stats)
                print(
                    f"{size:>16} {turn:>4} {user:7.2f} {system:6.2f} {host:6.2f} {faults:7d} "
                    f"{busiest:15.3f} {stats['rays_passed']:>11} {links:>8} "
                    f"{packets:>11} {progress:>8}"
                )
    first = statistics.median(t for t, _ in got[sizes[0]])
    first_busiest = statistics.median(b for _, b in got[sizes[0]])
    for size in sizes:
        total = statistics.median(t for t, _ in got[size])
        busiest = statistics.median(b for _, b in got[size])
        print(
            f"{size:>16} median: nodes' CPU {total:.2f} s ({total / first:.2f} of "
            f"{sizes[0]}'s), busiest node's frame {busiest:.3f} s "
            f"({busiest / first_busiest:.2f} of {sizes[0]}'s)"
        )
        rows.append(
            {
                "scene": name,
                "setting": size,
                "nodes_cpu_seconds": got[size],
                "median_nodes_cpu_seconds": total,
                "median_busiest_frame_cpu": busiest,
            }
        )


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["serve"]:
        return serve(argv)
    p = argparse.ArgumentParser(prog="bench.passing", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,tetra")
    p.add_argument("--mesh", default="3x3")
    p.add_argument("--share", type=float, default=0.25, help="--max-share of every node")
    p.add_argument("--size", type=int, default=384)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument(
        "--passing",
        default="16384/4/4096,16384/16/16384",
        help=f"{SETTING} settings to compare, the first the base",
    )
    p.add_argument("--turns", type=int, default=2)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    rows, bad = [], []
    for name in args.only.split(","):
        bench_scene(args, name, rows, bad)
    return finish(
        rows,
        args.json,
        bad,
        "IMAGES DIFFER:\n",
        "every render's counts equal the first's, its image within 1e-5",
    )


if __name__ == "__main__":
    sys.exit(main())
