"""The host's side of a mesh render: configuration, object download, pixel collection and
statistics, over one link per node (DESIGN.md 5).

The host talks to every node directly for control; rays and pixel packets use the torus. A
node that fails, or whose link breaks, stops the render with an error naming it; so does a
node that falls silent, or a mesh whose nodes all live but none works.
"""

import asyncio
import time
from dataclasses import asdict

import numpy as np

from host.camerasetup import CameraSetup
from host.framebuffer import Framebuffer
from host.partition import subset
from host.plan import Planned, plan_render
from meshnode.link import Link, LinkClosed, dial
from meshnode.scheduler import TileDealer
from protocols.errors import ProtocolError, describe
from protocols.messages import Kind, make
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from protocols.scene import SceneData

OBJECT_BATCH = 20000  # records per OBJECTS message


class MeshError(RuntimeError):
    """The render failed on the mesh; the message names the node."""


async def _download(link: Link, scene: SceneData) -> None:
    """The node's objects, table by table, in bounded messages."""
    tables = [("materials", scene.materials), ("lights", scene.lights),
              ("spheres", scene.spheres), ("triangles", scene.triangles),
              ("polygons", scene.polygons), ("vertices", scene.vertices.reshape(-1)),
              ("cones", scene.cones)]  # fmt: skip
    parts = [(n, t[i : i + OBJECT_BATCH])
             for n, t in tables for i in range(0, len(t), OBJECT_BATCH)]  # fmt: skip
    parts = parts or [("materials", scene.materials)]
    for i, (name, records) in enumerate(parts):
        last = i == len(parts) - 1
        await link.send(make(Kind.OBJECTS, table=name, records=np.ascontiguousarray(records),
                             last=last))  # fmt: skip


async def render_on_mesh(scene: SceneData, image: ImageSpec, addresses: list[str],
                         plan: MeshPlan = MeshPlan(), engine: EngineSpec = EngineSpec(),
                         camera: CameraSetup | None = None, *, cluster: str = "meshtrace",
                         secret: bytes | None = None, progress=None, silence: float = 15.0,
                         stall: float = 180.0, ready=None,
                         wait: float = 5.0) -> tuple[np.ndarray, dict]:  # fmt: skip
    """Render on running nodes (address i is node i); returns (image, statistics).
    `secret`: the cluster secret the nodes were started with (None: they have none);
    `progress(n)` is called as nodes report n more primary rays traced; `ready()` once every
    node has built its engine (compiled its kernels on a first run) and linked; `silence`: seconds
    without a message from a node (they send one a second) before the render is given up
    naming it; `stall`: seconds in which no node traces anything once all are built (all
    alive, none working, the render unfinished: a stuck kernel or a protocol fault); `wait`:
    seconds for every node to accept a connection (nodes still starting), then the first one
    that does not is named."""
    if len(addresses) != plan.nodes:
        raise ValueError(f"a {plan.rows}x{plan.cols} mesh needs {plan.nodes} node addresses, "
                         f"got {len(addresses)}")  # fmt: skip
    start = time.perf_counter()
    planned = plan_render(scene, image, engine, plan, camera)
    links = await _configure(scene, planned, addresses, cluster, secret, wait)
    setup = time.perf_counter() - start
    spec = planned.spec
    width, height = spec.image.size
    fb = Framebuffer(width, height, spec.corners, spec.image.spp)
    dealer = TileDealer(len(planned.partition.rects), plan.nodes, plan.buffer) \
        if plan.dynamic else None  # fmt: skip
    collector = _Collector(fb, addresses, progress, silence, stall, dealer, ready)
    try:
        if dealer is not None:
            for n, (tiles, last) in dealer.first().items():
                await links[n].send(make(Kind.TILES, tiles=tiles, last=last))
        await collector.run(links)
    finally:
        await _close(links)
    summary = _summary(collector.stats, plan, planned.holders, collector.deposits, setup,
                       time.perf_counter() - start)  # fmt: skip
    summary["render"] = spec.to_wire() | {"camera": None}
    summary["balance"] = planned.balance
    summary["plan_seconds"] = planned.seconds
    if dealer is not None:
        summary["tiles_per_node"] = np.bincount(list(dealer.dealt.values()),
                                                minlength=plan.nodes).tolist()  # fmt: skip
    if planned.camera is not None:
        summary["camera"] = planned.camera
        if "refined_pixels" in summary["rays"]:
            planned.camera["refined_pixels"] = summary["rays"].pop("refined_pixels")
    return fb.image(), summary


async def _configure(scene, planned: Planned, addresses, cluster, secret,
                     wait: float) -> list[Link]:  # fmt: skip
    """Connect to every node (both sides proving the secret) within `wait` seconds in all,
    send its CONFIG and objects."""
    links: list[Link] = []
    neighbours = {str(n): a for n, a in enumerate(addresses)}
    render, part = planned.spec.to_wire(), planned.partition.to_wire()
    deadline = time.monotonic() + wait
    try:
        for n, address in enumerate(addresses):
            left = max(deadline - time.monotonic(), 0.1)
            link, _ = await dial(address, f"node {n} ({address})", cluster, secret, "host",
                                 wait=left)  # fmt: skip
            links.append(link)
        for n, link in enumerate(links):
            await link.send(make(Kind.CONFIG, node=n, neighbours=neighbours, render=render,
                                 partition=part, view=asdict(scene.view),
                                 background=list(scene.background)))  # fmt: skip
            await _download(link, subset(scene, planned.holders[n]))
    except (LinkClosed, ProtocolError) as e:
        await _close(links, shutdown=False)
        raise MeshError(f"setting up the mesh: {describe(e)}") from e
    return links


async def _close(links: list[Link], shutdown: bool = True) -> None:
    for link in links:
        if shutdown:
            try:
                await link.send(make(Kind.SHUTDOWN))
            except LinkClosed:
                pass
        await link.close()


class _Collector:
    """Pixels, progress and statistics from every node, and the watchdog over them."""

    def __init__(self, fb: Framebuffer, addresses, progress, silence: float, stall: float,
                 dealer: TileDealer | None = None, on_ready=None):  # fmt: skip
        self.fb, self.addresses, self.progress, self.dealer = fb, addresses, progress, dealer
        self.on_ready = on_ready  # called once, when every node is first ready
        self.silence, self.stall = silence, stall
        n = len(addresses)
        now = time.monotonic()
        self.stats: dict[int, dict] = {}
        self.deposits = 0
        self.last_heard = dict.fromkeys(range(n), now)
        self.work = dict.fromkeys(range(n), 0)
        self.ready = dict.fromkeys(range(n), False)  # engine built, links up
        self.last_work = now

    def name(self, n: int) -> str:
        return f"node {n} ({self.addresses[n]})"

    async def run(self, links: list[Link]) -> None:
        tasks = [asyncio.ensure_future(self.collect(n, link)) for n, link in enumerate(links)]
        guard = asyncio.ensure_future(self.watchdog())
        try:
            while not all(t.done() for t in tasks):
                pending = [t for t in tasks if not t.done()]
                done, _ = await asyncio.wait([*pending, guard],
                                             return_when=asyncio.FIRST_COMPLETED)  # fmt: skip
                for t in done:
                    if t.exception():
                        raise t.exception()
        finally:
            for t in [*tasks, guard]:
                t.cancel()
            await asyncio.gather(*tasks, guard, return_exceptions=True)

    async def collect(self, n: int, link: Link) -> None:
        while n not in self.stats:
            try:
                kind, f = await link.recv()
            except LinkClosed as e:
                raise MeshError(f"{self.name(n)}: {e.reason}") from e
            now = self.last_heard[n] = time.monotonic()
            if kind is Kind.PIXELS:
                d = f["deposits"]
                self.fb.add(d["pixel"], d["rgb"])
                self.deposits += len(d)
                self.last_work = now
            elif kind is Kind.PROGRESS:
                if f["work"] > self.work[n] or f["ready"] != self.ready[n]:
                    self.last_work = now
                self.work[n], self.ready[n] = f["work"], f["ready"]
                if self.on_ready and all(self.ready.values()):
                    self.on_ready, announce = None, self.on_ready
                    announce()
                if self.progress and f["rays"]:
                    self.progress(f["rays"])
            elif kind is Kind.TILE_DONE and self.dealer is not None:
                for _ in f["tiles"]:  # one more tile for each finished, while any are left
                    tiles, last = self.dealer.finished(n)
                    if tiles or last:
                        await link.send(make(Kind.TILES, tiles=tiles, last=last))
            elif kind is Kind.STATS:
                self.stats[n] = f["stats"]
            elif kind is Kind.ERROR:
                raise MeshError(f"{self.name(n)} failed: {f['reason']}")

    async def watchdog(self) -> None:
        """A node that stops talking (stopped, hung, cut off) fails the render, named; so
        does a mesh whose nodes are all built and talk but none works. Building takes as
        long as it takes (nodes still say they live)."""
        while True:
            await asyncio.sleep(min(1.0, self.silence / 4))
            now = time.monotonic()
            for n in self.last_heard:
                if n not in self.stats and now - self.last_heard[n] > self.silence:
                    raise MeshError(f"{self.name(n)}: no message for {self.silence:g} s "
                                    "(stopped, hung or cut off)")  # fmt: skip
            if not all(self.ready.values()):
                self.last_work = now
            elif now - self.last_work > self.stall:
                waiting = [n for n in self.last_heard if n not in self.stats]
                raise MeshError(f"no node has traced anything for {self.stall:g} s and nodes "
                                f"{waiting} have not finished (alive but stuck)")  # fmt: skip

def _summary(stats, plan: MeshPlan, keep, deposits, setup, wall) -> dict:
    nodes = [stats[n] for n in range(plan.nodes)]
    totals: dict[str, int] = {}
    for s in nodes:
        for k, v in s["rays"].items():
            totals[k] = totals.get(k, 0) + v
    busy = [s["busy_cpu_seconds"] for s in nodes]
    return {
        "mesh": plan.to_wire(),
        "rays": totals,
        "deposits_received": deposits,
        "rays_passed": sum(s["rays_sent"] for s in nodes),
        "setup_seconds": setup,
        "wall_seconds": wall,
        "busiest_node_cpu_seconds": max(busy),
        "imbalance": (max(busy) - min(busy)) / max(busy) if max(busy) > 0 else 0.0,
        "objects_per_node": keep.sum(axis=1).tolist(),
        "nodes": nodes,
    }
