"""The host's side of a mesh render: configuration, object download, pixel collection and
statistics, over one link per node (DESIGN.md 5).

The host talks to every node directly for control; rays and pixel packets use the torus. A
node whose link breaks or that falls silent is lost: under `on_node_loss="replan"` (the
default) the host gives the render up on every node (ABORT, answered by ABORTED), plans it
again on the nodes that answered and renders the frame from the start on them: the image and
ray counts are the single node's, whatever was lost. A node that reports an error (with every
node still there), or a mesh whose nodes all live but none works, fails the render, named.
"""

import asyncio
import math
import secrets
import ssl
import time
from dataclasses import asdict, replace

import numpy as np

from host.camera.setup import CameraSetup
from host.planning.plan import Planned, choose_mode, plan_render, smallest_memory
from host.run.framebuffer import Framebuffer
from host.scene.subset import subset
from meshnode.mesh.scheduler import TileDealer, deal_order
from meshnode.transport.link import Link, LinkClosed, dial
from protocols.errors import ProtocolError, describe
from protocols.handshake import RENDER_ID_BYTES
from protocols.messages import Kind, make
from protocols.render import EngineSpec, ImageSpec, MeshPlan
from protocols.scene import SceneData

OBJECT_BATCH = 20000  # records per OBJECTS message


class MeshError(RuntimeError):
    """The render failed on the mesh; the message names the node."""


class NodeLost(MeshError):
    """Node `node`'s link broke or it fell silent: a re-plan can go on without it."""

    def __init__(self, node: int, message: str):
        super().__init__(message)
        self.node = node


async def _download(link: Link, scenes: dict[int, SceneData]) -> None:
    """Objects for one node, table by table, in bounded messages: `scenes[m]` node m's (its
    own, and under MeshPlan.copies each linked neighbour's)."""
    parts = []
    for m, scene in scenes.items():
        tables = [
            ("materials", scene.materials),
            ("lights", scene.lights),
            ("spheres", scene.spheres),
            ("triangles", scene.triangles),
            ("polygons", scene.polygons),
            ("vertices", scene.vertices.reshape(-1)),
            ("cones", scene.cones),
        ]
        own = [
            (m, n, t[i : i + OBJECT_BATCH])
            for n, t in tables
            for i in range(0, len(t), OBJECT_BATCH)
        ]
        parts += own or [(m, "materials", scene.materials)]  # every node named at least once
    for i, (m, name, records) in enumerate(parts):
        last = i == len(parts) - 1
        await link.send(
            make(Kind.OBJECTS, table=name, records=np.ascontiguousarray(records), node=m, last=last)
        )


async def render_on_mesh(
    scene: SceneData,
    image: ImageSpec,
    addresses: list[str],
    plan: MeshPlan = MeshPlan(),
    engine: EngineSpec = EngineSpec(),
    camera: CameraSetup | None = None,
    *,
    cluster: str = "meshtrace",
    secret: bytes | None = None,
    progress=None,
    silence: float = 15.0,
    stall: float = 180.0,
    on_node_loss: str = "replan",
    notice=None,
    tls: ssl.SSLContext | None = None,
    mode: str | None = None,
    node_memory: int | None = None,
    overlaps=(),
    watch=None,
    ready=None,
    wait: float = 5.0,
) -> tuple[np.ndarray, dict]:
    """Render on running nodes (address i is node i); returns (image, statistics).
    `secret`: the cluster secret the nodes were started with (None: they have none);
    `progress(n)` is called as nodes report n more primary rays traced (negative when a
    re-plan starts the frame again); `silence`: seconds without a message from a node (they
    send one a second) before it is taken for lost; `stall`: seconds in which no node traces
    anything once all are built (all alive, none working: a stuck kernel or a protocol
    fault); `on_node_loss`: "replan" (finish the frame on the nodes left) or "fail";
    `notice(text)` hears of the plan chosen and of every lost node; `tls`: a client context
    (meshnode.transport.tls) when the nodes listen with TLS; `mode`: "auto", "object" or "image" to
    choose the plan's mode here (host.planning.plan.choose_mode: auto weighs the scene against the
    memory the nodes report, or `node_memory`), None to keep `plan.mode`; `overlaps`:
    object-space overlaps for the cost pre-pass to choose among within that memory
    (`--overlap auto`; empty: keep `plan.overlap`); `watch`: a
    `host.live.monitor.Monitor` told of pixels and of every node's PROGRESS; `ready()` once
    every node has built its engine (compiled its kernels on a first run) and linked;
    `wait`: seconds for every node to accept a connection (nodes still starting), then the
    first one that does not is named."""
    if len(addresses) != plan.nodes:
        raise ValueError(
            f"a {plan.rows}x{plan.cols} mesh needs {plan.nodes} node addresses, "
            f"got {len(addresses)}"
        )
    if on_node_loss not in NODE_LOSS:
        raise ValueError(f"on_node_loss = {on_node_loss!r}: want one of {NODE_LOSS}")
    start = time.perf_counter()
    alive = list(range(len(addresses)))  # the original index of each node still rendering
    links, memories = await _connect(addresses, cluster, secret, tls, wait)
    connect = time.perf_counter() - start
    memory = smallest_memory(memories, node_memory)
    why = f"MeshPlan.mode = {plan.mode}"
    if mode is not None:
        plan, why = choose_mode(plan, scene, memories, mode, node_memory)
    if notice is not None:
        notice(f"plan: {plan.mode} space on {plan.rows}x{plan.cols} ({why})")
    lost: list[dict] = []
    first_loss = None
    try:
        while True:
            names = [f"node {n} ({addresses[n]})" for n in alive]
            try:
                fb, summary = await _attempt(
                    scene,
                    image,
                    engine,
                    plan,
                    camera,
                    [links[n] for n in alive],
                    [addresses[n] for n in alive],
                    names,
                    progress,
                    silence,
                    stall,
                    watch,
                    ready,
                    (overlaps, memory),
                )
                break
            except MeshError as e:
                if on_node_loss == "fail":
                    raise
                t_loss = time.perf_counter()
                gone = await _give_up([links[n] for n in alive], e, silence)
                if not gone or len(gone) == len(alive):
                    raise
                first_loss = t_loss if first_loss is None else first_loss
                for i, reason in gone.items():
                    lost.append(
                        {
                            "node": alive[i],
                            "address": addresses[alive[i]],
                            "reason": reason,
                            "at_seconds": t_loss - start,
                        }
                    )
                    if notice is not None:
                        notice(
                            f"lost {names[i]}: {lost[-1]['reason']}; re-planning the frame "
                            f"on the {len(alive) - len(gone)} nodes left"
                        )
                alive = [n for i, n in enumerate(alive) if i not in gone]
                plan = shrink(plan, len(alive))
    finally:
        await _close([links[n] for n in alive])
    end = time.perf_counter()
    summary["wall_seconds"] = end - start
    summary["addresses"] = [addresses[n] for n in alive]
    summary["lost_nodes"] = lost
    summary["recovery_seconds"] = end - first_loss if first_loss is not None else 0.0
    summary["mode"] = {"choice": plan.mode, "why": why, "node_memory_bytes": memories}
    summary["connect_seconds"] = connect
    return fb.image(), summary


NODE_LOSS = ("replan", "fail")


def tiles_message(dealer: TileDealer, tiles: list[int], last: bool) -> dict:
    """TILES for a node: under adaptive sampling its last carries every tile's node."""
    return make(Kind.TILES, tiles=tiles, last=last, owners=dealer.owners_with(last))


def shrink(plan: MeshPlan, nodes: int) -> MeshPlan:
    """The plan on `nodes` nodes: the most nearly square rows x cols that uses them all
    (shared cells were the old mesh's: the pre-pass chooses again on the new one)."""
    rows = max(d for d in range(1, math.isqrt(nodes) + 1) if nodes % d == 0)
    return replace(plan, rows=rows, cols=nodes // rows, shared=())


async def _attempt(
    scene,
    image,
    engine,
    plan,
    camera,
    links: list[Link],
    addresses,
    names,
    progress,
    silence,
    stall,
    watch,
    ready,
    holding=((), 0),
):
    """One try at the frame on `links` (node i is links[i] at addresses[i], called
    names[i] in messages): (framebuffer, summary); `holding`: (overlaps, memory) for
    `plan_render`."""
    start, ticks = time.perf_counter(), time.monotonic()
    planned = plan_render(scene, image, engine, plan, camera, *holding)
    await _configure(scene, planned, links, addresses)
    sent = time.perf_counter() - start
    spec = planned.spec
    width, height = spec.image.size
    fb = Framebuffer(width, height, spec.corners, spec.image.spp)
    chosen = spec.plan
    dealer = (
        TileDealer(
            deal_order(planned.partition.rects, chosen.order),
            chosen.nodes,
            chosen.buffer,
            spec.adaptive,
        )
        if chosen.dynamic
        else None
    )
    collector = _Collector(fb, names, progress, silence, stall, dealer, watch, ready)
    if watch is not None:
        watch.start(
            fb,
            plan.rows,
            plan.cols,
            planned.holders.sum(axis=1).tolist(),
            primary_rays(spec.image, camera),
        )
    try:
        if dealer is not None:
            for n, (tiles, last) in dealer.first().items():
                await links[n].send(tiles_message(dealer, tiles, last))
        await collector.run(links)
    except LinkClosed as e:  # a TILES send to a node that is gone
        n = next(i for i, link in enumerate(links) if link.peer == e.peer)
        raise NodeLost(n, f"{names[n]}: {e.reason}") from e
    except MeshError:
        if progress and collector.traced:
            progress(-collector.traced)  # the frame starts again: so does the count
        raise
    ready = (collector.ready_at or time.monotonic()) - ticks
    summary = _summary(
        collector.stats,
        planned.spec.plan,
        planned.holders,
        collector.deposits,
        ready,
        time.perf_counter() - start,
    )
    summary["configure_seconds"] = sent - planned.seconds  # CONFIG and objects sent
    summary["render"] = spec.to_wire() | {"camera": None}
    summary["balance"] = planned.balance
    summary["plan_seconds"] = planned.seconds
    if dealer is not None:
        summary["tiles_per_node"] = dealer.tiles_per_node()
    if planned.camera is not None:
        summary["camera"] = planned.camera
        if "refined_pixels" in summary["rays"]:
            planned.camera["refined_pixels"] = summary["rays"].pop("refined_pixels")
    return fb, summary


async def _connect(addresses, cluster, secret, tls, wait: float) -> tuple[list[Link], list[int]]:
    """One link to every node within `wait` seconds in all, both sides proving the secret;
    and the memory each has."""
    links: list[Link] = []
    memories: list[int] = []
    deadline = time.monotonic() + wait
    try:
        for n, address in enumerate(addresses):
            left = max(deadline - time.monotonic(), 0.1)
            link, theirs = await dial(
                address, f"node {n} ({address})", cluster, secret, "host", tls=tls, wait=left
            )
            links.append(link)
            memories.append(theirs["memory"])
    except (LinkClosed, ProtocolError) as e:
        await _close(links, shutdown=False)
        raise MeshError(f"setting up the mesh: {describe(e)}") from e
    return links, memories


async def _configure(scene, planned: Planned, links: list[Link], addresses) -> None:
    """Every node's CONFIG (all of them first: a node links to its neighbours once its
    objects are in, and they must know the render by then), then its objects."""
    neighbours = {str(n): a for n, a in enumerate(addresses)}
    render, part = planned.spec.to_wire(), planned.partition.to_wire()
    render_id = secrets.token_bytes(RENDER_ID_BYTES)  # links of a given-up try cannot join
    n = 0
    try:
        for n, link in enumerate(links):
            await link.send(
                make(
                    Kind.CONFIG,
                    node=n,
                    neighbours=neighbours,
                    render=render,
                    partition=part,
                    view=asdict(scene.view),
                    background=list(scene.background),
                    render_id=render_id,
                )
            )
        for n, link in enumerate(links):
            held = planned.spec.plan.held(n)
            await _download(link, {m: subset(scene, planned.holders[m]) for m in held})
    except LinkClosed as e:
        raise NodeLost(n, f"setting up the mesh: {describe(e)}") from e


async def _give_up(links: list[Link], error: MeshError, deadline: float) -> dict[int, str]:
    """Tell every node the render is given up (ABORT) and wait up to `deadline` seconds for
    each to answer (ABORTED comes after everything it sent for the render); returns the
    nodes lost (the one the error names, links that broke, nodes that did not answer) with
    the reason for each, their links dropped."""
    lost = {error.node: str(error)} if isinstance(error, NodeLost) else {}

    async def aborted(link: Link) -> None:
        await link.send(make(Kind.ABORT, reason=str(error)))
        while (await link.recv())[0] is not Kind.ABORTED:
            pass  # what the node sent for the given-up render

    waits = {
        asyncio.ensure_future(aborted(link)): i for i, link in enumerate(links) if i not in lost
    }
    if waits:
        done, pending = await asyncio.wait(waits, timeout=deadline)
        for t in pending:
            t.cancel()
            lost[waits[t]] = f"no answer to the host's ABORT within {deadline:g} s"
        await asyncio.gather(*pending, return_exceptions=True)
        for t in done:
            if t.exception() is not None:
                lost[waits[t]] = describe(t.exception())
    for i in lost:
        links[i].abort()
    return lost


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

    def __init__(
        self,
        fb: Framebuffer,
        names: list[str],
        progress,
        silence: float,
        stall: float,
        dealer: TileDealer | None = None,
        watch=None,
        on_ready=None,
    ):
        self.fb, self.names, self.progress, self.dealer = fb, names, progress, dealer
        self.watch = watch
        self.on_ready = on_ready  # called once, when every node is first ready
        self.silence, self.stall = silence, stall
        self.traced = 0  # primary rays reported so far
        self.ready_at: float | None = None  # time.monotonic() when every node was ready
        n = len(names)
        now = time.monotonic()
        self.stats: dict[int, dict] = {}
        self.deposits = 0
        self.last_heard = dict.fromkeys(range(n), now)
        self.work = dict.fromkeys(range(n), 0)
        self.ready = dict.fromkeys(range(n), False)  # engine built, links up
        self.last_work = now

    def name(self, n: int) -> str:
        return self.names[n]

    async def run(self, links: list[Link]) -> None:
        tasks = [asyncio.ensure_future(self.collect(n, link)) for n, link in enumerate(links)]
        guard = asyncio.ensure_future(self.watchdog())
        try:
            while not all(t.done() for t in tasks):
                pending = [t for t in tasks if not t.done()]
                done, _ = await asyncio.wait([*pending, guard], return_when=asyncio.FIRST_COMPLETED)
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
                raise NodeLost(n, f"{self.name(n)}: {e.reason}") from e
            now = self.last_heard[n] = time.monotonic()
            if kind is Kind.PIXELS:
                d = f["deposits"]
                self.fb.add(d["pixel"], d["rgb"])
                self.deposits += len(d)
                self.last_work = now
                if self.watch is not None:
                    self.watch.pixels()
            elif kind is Kind.PROGRESS:
                if f["node"] != n:
                    raise MeshError(f"{self.name(n)} reports progress as node {f['node']}")
                if f["work"] > self.work[n] or f["ready"] != self.ready[n]:
                    self.last_work = now
                self.work[n], self.ready[n] = f["work"], f["ready"]
                if self.ready_at is None and all(self.ready.values()):
                    self.ready_at = now
                    if self.on_ready is not None:
                        self.on_ready()
                self.traced += f["rays"]
                if self.progress and f["rays"]:
                    self.progress(f["rays"])
                if self.watch is not None:
                    self.watch.node(n, f)
            elif kind is Kind.TILE_DONE and self.dealer is not None:
                for _ in f["tiles"]:  # one more tile for each finished, while any are left
                    tiles, last = self.dealer.finished(n)
                    if tiles or last:
                        await link.send(tiles_message(self.dealer, tiles, last))
                if self.watch is not None:
                    self.watch.tiles(n, len(f["tiles"]))
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
                    raise NodeLost(
                        n,
                        f"{self.name(n)}: no message for {self.silence:g} s "
                        "(stopped, hung or cut off)",
                    )
            if not all(self.ready.values()):
                self.last_work = now
            elif now - self.last_work > self.stall:
                waiting = [n for n in self.last_heard if n not in self.stats]
                raise MeshError(
                    f"no node has traced anything for {self.stall:g} s and nodes "
                    f"{waiting} have not finished (alive but stuck)"
                )


def primary_rays(image: ImageSpec, camera) -> int | None:
    """Primary rays of a sized image (None through a camera: rays lost in it are never
    traced, so there is no known total)."""
    if camera is not None:
        return None
    gw, gh = image.sample_grid()
    return gw * gh * (1 if image.corners() else image.spp)


def _summary(stats, plan: MeshPlan, keep, deposits, setup, wall) -> dict:
    nodes = [stats[n] for n in range(plan.nodes)]
    totals: dict[str, int] = {}
    for s in nodes:
        for k, v in s["rays"].items():
            totals[k] = totals.get(k, 0) + v
    busy = [s["busy_cpu_seconds"] for s in nodes]
    own = keep.sum(axis=1)
    return {
        "mesh": plan.to_wire(),
        "rays": totals,
        "deposits_received": deposits,
        "rays_passed": sum(s["rays_sent"] for s in nodes),
        "setup_seconds": setup,  # planned, configured, every engine built and link up
        "wall_seconds": wall,
        "busiest_node_cpu_seconds": max(busy),
        # with routing rays and deposits around the kernels: what a node's batches cost
        "busiest_node_batch_cpu_seconds": max(s.get("batch_cpu_seconds", 0.0) for s in nodes),
        # sum of node tracing CPU / (nodes x busiest): 1 when every node works as long
        "parallel_efficiency": sum(busy) / (len(busy) * max(busy)) if max(busy) > 0 else 1.0,
        "imbalance": (max(busy) - min(busy)) / max(busy) if max(busy) > 0 else 0.0,
        "objects_per_node": own.tolist(),
        # with the neighbours' copies (MeshPlan.copies)
        "objects_held_per_node": [int(own[plan.held(n)].sum()) for n in range(plan.nodes)],
        # the share of the scene's objects the node holding most holds, each counted once:
        # what the object-space mesh saves against image space (where it is 1)
        "objects_held_max_share": max(
            float(keep[plan.held(n)].any(axis=0).mean()) for n in range(plan.nodes)
        )
        if keep.shape[1]
        else 1.0,
        "nodes": nodes,
    }
