"""Soak: renders back to back on a local 3x3 mesh with a fault injected at random into most of
them, counting what went wrong (issue 41).

    python -m bench.soak [--renders 200] [--seed 1] [--size 48] [--json FILE] [--plot FILE]

Every render is of the same small generated scene (tetra 5) and must give one node's image and
ray counts, or fail with a clear one-line error when its fault makes it fail (never hang: each
is bounded by a timeout, and never leave processes behind). Faults: none; a node killed
mid-render (the host re-plans on the nodes left; the mesh is started again after); a node
paused for a second (SIGSTOP, then SIGCONT); a stranger flooding a node with idle sockets; a
host without the secret trying at the same time; a host that vanishes mid-render (the next
render, on the same nodes, must still work). Prints a line per fault kind: renders, exact
images, clear failures, hangs, then the processes left; and after every render each node's
resident memory and open descriptors are read (`soak_plot`): within a mesh's life (beyond its
first three renders) the busiest node's median RSS may not rise by more than GROWTH_MB nor
its median open descriptors by more than GROWTH_FDS (`soak_plot.growth`); `--plot` draws
them.
"""

import argparse
import asyncio
import os
import random
import signal
import socket
import sys
from collections import Counter
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench import finish  # noqa: E402
from host.planning.request import Request  # noqa: E402
from host.run.connections import Nodes  # noqa: E402

FAULTS = ("none", "kill", "pause", "flood", "stranger host", "host vanishes")
RENDER_SECONDS = 60.0  # a render that takes longer has hung
GROWTH_MB = 50.0  # the busiest node's median RSS may rise this much within a mesh's renders
GROWTH_FDS = 1.0  # ... and its median open descriptors this many
STARTED: list = []  # every node process this run started: none may be left at the end


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.soak", description=__doc__.split("\n\n")[0])
    p.add_argument("--renders", type=int, default=200)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--size", type=int, default=48)
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", type=Path, help="PNG of every node's RSS and descriptors")
    args = p.parse_args(argv)
    from bench.generate import tetra
    from bench.soak_plot import growth, node_resources, plot
    from host.run.oneprocess import render
    from meshnode.engine.counters import RAY_COUNTS
    from protocols.render import EngineSpec, ImageSpec

    scene = tetra(5)
    image = ImageSpec(width=args.size, height=args.size, spp=4)
    ref, ref_stats = render(Request(scene, image, EngineSpec(threads=1)), progress=False)
    want = {k: ref_stats["rays"][k] for k in RAY_COUNTS}
    rng = random.Random(args.seed)
    tally: dict[str, Counter] = {f: Counter() for f in FAULTS}
    messages: list[str] = []
    secret = os.urandom(32).hex().encode()
    mesh, meshes, samples = None, 0, []
    try:
        for i in range(args.renders):
            fault = rng.choice(FAULTS)
            if mesh is None:
                mesh, meshes = _start(secret), meshes + 1
            outcome, text = asyncio.run(
                _one(scene, image, mesh, secret, fault, rng, ref, want, RAY_COUNTS)
            )
            tally[fault][outcome] += 1
            if text:
                messages.append(f"render {i} ({fault}): {text}")
            rss, fds = node_resources(p.pid for p in mesh[0].procs)
            if rss:
                samples.append(
                    {"render": i, "mesh": meshes, "rss_max_mb": max(rss), "fds_max": max(fds)}
                )
            if fault == "kill" or outcome == "hang":
                _stop(mesh)  # killed nodes are gone: a fresh mesh for the next render
                mesh = None
            print(f"render {i:>3} {fault:>14}: {outcome}", flush=True)
    finally:
        if mesh is not None:
            _stop(mesh)
    left = sum(p.poll() is None for p in STARTED)
    print(f"\n{'fault':>14} {'renders':>7} {'exact':>5} {'clear':>5} {'hang':>4} {'wrong':>5}")
    for fault, c in tally.items():
        print(
            f"{fault:>14} {sum(c.values()):>7} {c['exact']:>5} {c['clear failure']:>5} "
            f"{c['hang']:>4} {c['wrong image']:>5}"
        )
    print(f"meshnode processes left: {left}")
    rise_mb, rise_fd = growth(samples)
    print(
        f"busiest node within a mesh's life, after its first 3 renders, second half against "
        f"first: median RSS rose at most {rise_mb:.1f} MB, median descriptors at most "
        f"{rise_fd:g} ({meshes} meshes, "
        f"RSS {min(s['rss_max_mb'] for s in samples):.0f}-"
        f"{max(s['rss_max_mb'] for s in samples):.0f} MB, descriptors "
        f"{min(s['fds_max'] for s in samples)}-{max(s['fds_max'] for s in samples)})"
    )
    if args.plot:
        plot(samples, args.plot)
    for m in messages[-10:]:
        print("  " + m)
    bad = [f"{f}: {c['hang']} hangs, {c['wrong image']} wrong" for f, c in tally.items()]
    bad = [b for b, c in zip(bad, tally.values(), strict=True) if c["hang"] or c["wrong image"]]
    if left:
        bad.append(f"{left} meshnode processes left")
    if rise_mb > GROWTH_MB or rise_fd > GROWTH_FDS:
        bad.append(f"resources grew: RSS {rise_mb:.1f} MB, descriptors {rise_fd:g}")
    rows = [{"fault": f, **dict(c)} for f, c in tally.items()] + [{"samples": samples}]
    return finish(rows, args.json, bad, "FAILED:\n", "no hang, no wrong image, nothing left")


def _start(secret: bytes):
    from host.run.localmesh import LocalMesh

    mesh = LocalMesh(9, secret=secret, once=False)
    addresses = mesh.__enter__()
    STARTED.extend(mesh.procs)
    return mesh, addresses


def _stop(mesh) -> None:
    mesh[0].__exit__(None, None, None)


async def _one(scene, image, mesh, secret, fault, rng, ref, want, keys):
    """(outcome, message) of one render under `fault`."""
    from host.run.errors import MeshError
    from host.run.meshclient import render_on_mesh
    from protocols.render import EngineSpec, MeshPlan

    lm, addresses = mesh
    procs = lm.procs
    victim = rng.randrange(1, len(procs))  # node 0 too would do; the others keep the host's view
    started = asyncio.Event()

    def progress(n):
        if n > 0:
            started.set()

    job = asyncio.create_task(
        render_on_mesh(
            Request(scene, image, EngineSpec(threads=1), plan=MeshPlan(3, 3)),
            Nodes(addresses, secret=secret, wait=10.0),
            progress=progress,
            silence=5.0,
        )
    )
    side = asyncio.create_task(_inject(fault, procs[victim], addresses[victim], started, job))
    try:
        img, stats = await asyncio.wait_for(job, RENDER_SECONDS)
    except asyncio.CancelledError:
        return "clear failure", "the host vanished mid-render (as injected)"
    except TimeoutError:
        return "hang", f"no end within {RENDER_SECONDS:g} s"
    except MeshError as e:
        return "clear failure", str(e)[:200]
    finally:
        side.cancel()
        await asyncio.gather(side, return_exceptions=True)
    counts = {k: stats["rays"][k] for k in keys}
    if counts == want and np.allclose(img, ref, rtol=0, atol=1e-5):
        return "exact", ""
    return "wrong image", f"counts {counts} against {want}"


async def _inject(fault, proc, address, started, job) -> None:
    """The fault, once the render has started tracing."""
    if fault == "none":
        return
    await started.wait()
    if fault == "kill":
        proc.send_signal(signal.SIGKILL)
    elif fault == "pause":
        proc.send_signal(signal.SIGSTOP)
        try:
            await asyncio.sleep(1.0)  # the fault itself: a node that stops for a second
        finally:
            proc.send_signal(signal.SIGCONT)
    elif fault == "flood":
        host, port = address.rsplit(":", 1)
        socks = []
        for _ in range(80):
            s = socket.socket()
            s.setblocking(False)
            s.bind(("127.0.0.7", 0))
            try:
                s.connect((host, int(port)))
            except BlockingIOError:
                pass
            socks.append(s)
        try:
            await asyncio.shield(job)
        finally:
            for s in socks:
                s.close()
    elif fault == "stranger host":
        from meshnode.transport.link import LinkClosed, dial

        try:
            await dial(address, "stranger", "meshtrace", b"not the secret" * 3, "host")
        except LinkClosed:
            pass
    elif fault == "host vanishes":
        job.cancel()


if __name__ == "__main__":
    sys.exit(main())
