"""The host's side of a mesh render: partition, configuration, object download, pixel
collection and statistics, over one link per node (DESIGN.md 5).

The host talks to every node directly for control; rays and pixel packets use the torus. A
node that fails, or whose link breaks, stops the render with an error naming it.
"""

import asyncio
import time
from dataclasses import asdict, replace

import numpy as np

from host.balance import balanced_cuts
from host.framebuffer import Framebuffer
from host.partition import holders, node_boxes, rectangles, scene_box, subset
from meshnode.link import Link, LinkClosed
from protocols.errors import ProtocolError
from protocols.handshake import check_hello, hello
from protocols.messages import Kind, make
from protocols.scene import SceneData
from protocols.topology import Torus

OBJECT_BATCH = 20000  # records per OBJECTS message


class MeshError(RuntimeError):
    """The render failed on the mesh; the message names the node."""


def _settings(scene, rs, width, height, rects, los, his) -> dict:
    return {
        "view": asdict(scene.view), "background": list(scene.background),
        "width": width, "height": height, "corners": rs.spd, "spp": 1 if rs.spd else rs.spp,
        "seed": rs.seed, "depth": rs.depth, "density": rs.density, "storage": rs.storage,
        "rects": [list(r) for r in rects], "los": los.tolist(), "his": his.tolist(),
    }  # fmt: skip


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


async def render_on_mesh(scene: SceneData, rs, addresses: list[str], rows: int, cols: int,
                         overlap: float = 1.0, cluster: str = "meshtrace",
                         progress=None, link_delay=None, silence: float = 15.0,
                         stall: float = 180.0,
                         incoming_high: int | None = None) -> tuple[np.ndarray, dict]:  # fmt: skip
    """Render on running nodes (address i is node i); returns (image, statistics).
    `progress(n)` is called as nodes report n more primary rays traced;
    `link_delay` = (src, dst, seconds, count) holds back ray messages on one link (tests);
    `silence`: seconds without a message from a node (they send one a second) before the
    render is given up naming it; `stall`: seconds in which no node traces anything (all
    alive, none working, the render unfinished: a stuck kernel or a protocol fault);
    `incoming_high`: queued incoming rays at which a node stops reading (tests use tiny ones)."""
    torus = Torus(rows, cols)
    if len(addresses) != torus.size:
        raise ValueError(f"a {rows}x{cols} mesh needs {torus.size} node addresses")
    width, height = rs.size(scene)
    gw, gh = (width + 1, height + 1) if rs.spd and rs.camera is None else (width, height)
    start = time.perf_counter()
    spec = camera_info = None
    if rs.camera is not None:
        # Autofocus probes the scene here, before any node is configured.
        spec, camera_info = rs.camera_rays(scene, lambda: _probe_engine(scene, rs))
    xs = ys = None
    balance: dict = {"cuts": rs.balance}
    if rs.balance == "cost" and torus.size > 1:
        t0 = time.perf_counter()
        centre = None if spec is None else replace(spec, generation=1, rays=1, special=False,
                                                   film_area="centre", sampling="uniform")
        xs, ys, report = balanced_cuts(scene, gw, gh, rows, cols, overlap, rs.depth, centre)
        balance.update(report, seconds=time.perf_counter() - t0)
    elif rs.balance not in ("even", "cost"):
        raise ValueError(f"balance must be 'even' or 'cost', not {rs.balance!r}")
    box = scene_box(scene)
    los, his = node_boxes(scene, box, width, height, rows, cols, overlap, xs, ys)
    keep = holders(scene, los, his)
    rects = rectangles(gw, gh, rows, cols, xs, ys)
    settings = _settings(scene, rs, width, height, rects, los, his)
    if spec is not None:
        settings["camera"] = spec.to_wire()
    settings["link_delay"] = list(link_delay) if link_delay else None
    settings["incoming_high"] = incoming_high
    links = []
    neighbours = {str(n): a for n, a in enumerate(addresses)}
    try:
        for n, address in enumerate(addresses):
            link = await Link.connect(address, f"node {n} ({address})")
            links.append(link)
            await link.send(hello(cluster, "host"))
            check_hello(await link.recv_raw(), cluster)
        for n, link in enumerate(links):
            await link.send(make(Kind.CONFIG, rows=rows, cols=cols, node=n,
                                 neighbours=neighbours, box=[*los[n], *his[n]],
                                 scene_box=[*box[0], *box[1]], settings=settings))  # fmt: skip
            await _download(link, subset(scene, keep[n]))
    except (LinkClosed, ProtocolError) as e:
        for link in links:
            await link.close()
        raise MeshError(f"setting up the mesh: {e}") from e
    setup = time.perf_counter() - start
    camera = rs.camera is not None  # camera pixels: one sample each, no SPD corners
    fb = Framebuffer(width, height, rs.spd and not camera, 1 if camera else rs.spp)
    stats: dict[int, dict] = {}
    deposits = 0

    last_heard = dict.fromkeys(range(torus.size), time.monotonic())
    work = dict.fromkeys(range(torus.size), 0)
    last_work = [time.monotonic()]

    async def collect(n: int, link: Link):
        nonlocal deposits
        while n not in stats:
            try:
                kind, f = await link.recv()
            except LinkClosed as e:
                raise MeshError(f"node {n} ({addresses[n]}): {e.reason}") from e
            last_heard[n] = time.monotonic()
            if kind is Kind.PIXELS:
                d = f["deposits"]
                fb.add(d["pixel"], d["rgb"])
                deposits += len(d)
                last_work[0] = last_heard[n]
            elif kind is Kind.PROGRESS:
                if f["work"] > work[n]:
                    work[n], last_work[0] = f["work"], last_heard[n]
                if progress and f["rays"]:
                    progress(f["rays"])
            elif kind is Kind.STATS:
                stats[n] = f["stats"]
            elif kind is Kind.ERROR:
                raise MeshError(f"node {n} ({addresses[n]}) failed: {f['reason']}")

    async def watchdog():
        """A node that stops talking (stopped, hung, cut off) fails the render, named; so
        does a mesh whose nodes all talk but none works."""
        while True:
            await asyncio.sleep(min(1.0, silence / 4))
            now = time.monotonic()
            for n in range(torus.size):
                if n not in stats and now - last_heard[n] > silence:
                    raise MeshError(f"node {n} ({addresses[n]}): no message for {silence:g} s "
                                    "(stopped, hung or cut off)")  # fmt: skip
            if now - last_work[0] > stall:
                waiting = [n for n in range(torus.size) if n not in stats]
                raise MeshError(f"no node has traced anything for {stall:g} s and nodes "
                                f"{waiting} have not finished (alive but stuck)")  # fmt: skip

    tasks = [asyncio.ensure_future(collect(n, link)) for n, link in enumerate(links)]
    guard = asyncio.ensure_future(watchdog())
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
        for link in links:
            try:
                await link.send(make(Kind.SHUTDOWN))
            except LinkClosed:
                pass
            await link.close()
    wall = time.perf_counter() - start
    summary = _summary(stats, torus, keep, deposits, setup, wall)
    summary["balance"] = balance
    if camera_info is not None:
        summary["camera"] = camera_info
        if "refined_pixels" in summary["rays"]:
            camera_info["refined_pixels"] = summary["rays"].pop("refined_pixels")
    return fb.image(), summary


def _probe_engine(scene: SceneData, rs):
    from host.autofocus import probe_engine

    width, height = rs.size(scene)
    return probe_engine(scene, width, height, density=rs.density, storage=rs.storage,
                        max_depth=1)  # fmt: skip


def _summary(stats, torus, keep, deposits, setup, wall) -> dict:
    nodes = [stats[n] for n in range(torus.size)]
    totals: dict[str, int] = {}
    for s in nodes:
        for k, v in s["rays"].items():
            totals[k] = totals.get(k, 0) + v
    busy = [s["busy_cpu_seconds"] for s in nodes]
    return {
        "mesh": {"rows": torus.rows, "cols": torus.cols},
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
