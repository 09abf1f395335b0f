"""Link throughput: rays per second over one TCP link between two processes, end to end
(encode a RAY batch into a frame, send, receive, decode back into a RAY array), next to a raw
socket copy of the same bytes between two processes (the machine's limit), in turns (link, raw,
link, raw ...: this machine's speed moves by the minute, so each pair shares its spell), each
pair's ratio and their median printed. Beside it, what a passed ray costs: the CPU of both
processes per ray through the link, against the CPU of one traced segment (one node tracing a
generated tetra and balls in this process).

    python -m bench.link [--rays-per-batch 65536] [--batches 200] [--runs 3]
"""

import argparse
import asyncio
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from host.planning.request import Request  # noqa: E402


def _loop_run(coro):
    try:
        import uvloop

        return uvloop.run(coro)
    except ImportError:
        return asyncio.run(coro)


def receiver(mode: str) -> None:
    """Child process: accept one connection, consume everything, print rays and seconds."""
    from meshnode.transport.link import Link, LinkClosed
    from protocols.messages import Kind

    if mode == "raw":
        srv = socket.create_server(("127.0.0.1", 0))
        print(srv.getsockname()[1], flush=True)
        conn, _ = srv.accept()
        buf = bytearray(1 << 22)
        total, start, cpu = 0, None, None
        while True:
            n = conn.recv_into(buf)
            if not n:
                break
            if start is None:
                start, cpu = time.perf_counter(), time.process_time()
            total += n
        print(total, time.perf_counter() - start, time.process_time() - cpu, flush=True)
        return

    async def main():
        done = asyncio.Event()
        result = {}

        async def accept(reader, writer):
            link = Link(reader, writer, "sender")
            rays, start = 0, None
            try:
                while True:
                    kind, f = await link.recv()
                    if start is None:  # from the first frame: not the interpreter's start
                        start, result["cpu"] = time.perf_counter(), time.process_time()
                    if kind is Kind.SHUTDOWN:
                        break
                    rays += len(f["rays"])
            except LinkClosed:
                pass
            result.update(rays=rays, seconds=time.perf_counter() - start)
            done.set()

        server = await asyncio.start_server(accept, "127.0.0.1", 0)
        print(server.sockets[0].getsockname()[1], flush=True)
        await done.wait()
        cpu = time.process_time() - result["cpu"]
        print(result["rays"], result["seconds"], cpu, flush=True)

    _loop_run(main())


def _spawn(mode):
    p = subprocess.Popen(
        [sys.executable, "-m", "bench.link", "--role", mode],
        stdout=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    return p, int(p.stdout.readline())


def run_link(batch: np.ndarray, batches: int) -> tuple[float, float]:
    """(rays per second, CPU seconds of both processes) through Link: the sender encodes
    every batch afresh. Each side's CPU counts from its first frame to its last, not its
    start-up (the receiver's interpreter and imports had doubled the CPU a ray at 200
    batches: 91-103 ns against 51-69 at 1000)."""
    from meshnode.transport.link import Link
    from protocols.messages import Kind, make

    proc, port = _spawn("link")
    cpu = 0.0

    async def send():
        nonlocal cpu
        link = await Link.connect(f"127.0.0.1:{port}", "receiver")
        cpu = time.process_time()  # the sending only: both ends count from their first frame
        for _ in range(batches):
            await link.send(make(Kind.RAYS, rays=batch, dest=1, cell=1))
        await link.send(make(Kind.SHUTDOWN))
        await link.writer.drain()
        cpu = time.process_time() - cpu
        await link.close()

    _loop_run(send())
    rays, seconds, theirs = proc.stdout.readline().split()
    proc.wait()
    return int(rays) / float(seconds), cpu + float(theirs)


def run_raw(frame: bytes, batches: int, rays_per_batch: int) -> float:
    """The same bytes by plain sendall / recv_into: rays per second it could carry."""
    proc, port = _spawn("raw")
    with socket.create_connection(("127.0.0.1", port)) as s:
        for _ in range(batches):
            s.sendall(frame)
    total, seconds, _ = proc.stdout.readline().split()
    proc.wait()
    assert int(total) == len(frame) * batches
    return rays_per_batch * batches / float(seconds)


def segment_ns() -> dict[str, float]:
    """CPU nanoseconds of one traced segment, one node in this process (after a warm run),
    on generated SPD scenes: what a pass must cost well under."""
    from bench.generate import balls, tetra
    from host.run.oneprocess import render
    from protocols.render import EngineSpec, ImageSpec

    out = {}
    for name, scene in (("tetra 6", tetra(6)), ("balls 3", balls(3))):
        image = ImageSpec(width=256, height=256)
        render(Request(scene, image, EngineSpec(threads=1)), progress=False)
        _, stats = render(Request(scene, image, EngineSpec(threads=1)), progress=False)
        out[name] = 1e9 * stats["trace_cpu_seconds"] / stats["rays"]["ray_segments"]
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.link", description=__doc__.split("\n\n")[0])
    p.add_argument("--role", choices=("link", "raw"), help=argparse.SUPPRESS)
    p.add_argument("--rays-per-batch", type=int, default=65536)
    p.add_argument("--batches", type=int, default=200)
    p.add_argument("--runs", type=int, default=3, help="link / raw pairs, in turns")
    args = p.parse_args(argv)
    if args.role:
        receiver(args.role)
        return 0
    from protocols.dtypes import RAY
    from protocols.framing import encode
    from protocols.messages import Kind, make

    batch = np.zeros(args.rays_per_batch, RAY)
    batch["d"] = (0.0, 0.0, 1.0)
    batch["pixel"] = np.arange(len(batch))
    frame = encode(make(Kind.RAYS, rays=batch, dest=1, cell=1))
    mb = len(frame) * args.batches / 1e6
    rays = args.batches * args.rays_per_batch
    print(
        f"{args.batches} batches of {args.rays_per_batch} rays ({len(frame):,} bytes a frame, "
        f"{mb:,.0f} MB in all), {args.runs} pairs in turns"
    )
    print(
        f"{'run':>3} {'link M rays/s':>13} {'raw M rays/s':>12} {'link/raw':>8} {'CPU ns/ray':>10}"
    )
    ratios, costs = [], []
    for run in range(args.runs):
        link, cpu = run_link(batch, args.batches)
        raw = run_raw(frame, args.batches, args.rays_per_batch)
        ratios.append(link / raw)
        costs.append(1e9 * cpu / rays)
        print(
            f"{run + 1:>3} {link / 1e6:>13.2f} {raw / 1e6:>12.2f} {link / raw:>8.2f} "
            f"{costs[-1]:>10.0f}"
        )
    print(
        f"link / raw: median {statistics.median(ratios):.2f}, least {min(ratios):.2f} "
        f"(goal at least 0.6 in every run: {'met' if min(ratios) >= 0.6 else 'NOT met'})"
    )
    pass_ns = statistics.median(costs)
    for name, ns in segment_ns().items():
        print(
            f"a pass (both ends' CPU) {pass_ns:.0f} ns against a traced segment of {name} "
            f"{ns:.0f} ns: {pass_ns / ns:.2f} segments"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
