"""The host's side of a mesh render: each try of the frame, and the re-plan after a lost
node (DESIGN.md 5). The links to the nodes are `host.run.connections`', the render loop
`host.run.collector`'s and the statistics `host.run.summary`'s.

The host talks to every node directly for control; rays and pixel packets use the torus. A
node whose link breaks or that falls silent is lost: under `on_node_loss="replan"` (the
default) the host gives the render up on every node (ABORT, answered by ABORTED), plans it
again on the nodes that answered and renders the frame on them: from the start, or under
dynamic image space only the tiles no node had traced whole (`host.run.kept`); the image and
ray counts are the single node's, whatever was lost. A node that reports an error (with every
node still there), or a mesh whose nodes all live but none works, fails the render, named.
"""

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from host.planning.plan import Planned, choose_mode, plan_render, smallest_memory
from host.planning.request import Request
from host.run.collector import Collector, tiles_message
from host.run.connections import Nodes, close_all, configure, connect_all, give_up
from host.run.errors import NODE_LOSS, MeshError, NodeLost
from host.run.framebuffer import Framebuffer
from host.run.kept import Kept, keeps_tiles, kept_after, recovery, with_kept_tiles
from host.run.summary import common, summarise
from meshnode.mesh.dealer import TileDealer, deal_order
from meshnode.transport.link import Link, LinkClosed
from protocols.render import ImageSpec, MeshPlan


async def render_on_mesh(
    request: Request,
    nodes: Nodes,
    *,
    progress=None,
    notice=None,
    watch=None,
    ready=None,
    silence: float = 15.0,
    stall: float = 180.0,
    on_node_loss: str = "replan",
) -> tuple[np.ndarray, dict]:
    """Render `request` on the running `nodes` (address i is node i); returns (image,
    statistics). `progress(n)` is called as nodes report n more primary rays traced (negative
    when a re-plan starts the frame again); `notice(text)` hears of the plan chosen and of
    every lost node; `watch`: a `host.live.monitor.Monitor` told of pixels and of every
    node's PROGRESS; `ready()` once every node has built its engine (compiled its kernels on
    a first run) and linked; `silence`: seconds without a message from a node (they send one
    a second) before it is taken for lost; `stall`: seconds in which no node traces anything
    once all are built (all alive, none working: a stuck kernel or a protocol fault);
    `on_node_loss`: "replan" (finish the frame on the nodes left) or "fail". The request's
    `auto` choices are made here, once the nodes have reported their memory
    (`host.planning.plan.choose_mode`)."""
    plan, addresses = request.plan, nodes.addresses
    if len(addresses) != plan.nodes:
        raise ValueError(
            f"a {plan.rows}x{plan.cols} mesh needs {plan.nodes} node addresses, "
            f"got {len(addresses)}"
        )
    if on_node_loss not in NODE_LOSS:
        raise ValueError(f"on_node_loss = {on_node_loss!r}: want one of {NODE_LOSS}")
    start = time.perf_counter()
    alive = list(range(len(addresses)))  # the original index of each node still rendering
    links, memories = await connect_all(nodes)
    connect = time.perf_counter() - start
    auto = request.auto
    memory = smallest_memory(memories, auto.node_memory)
    why = f"MeshPlan.mode = {plan.mode}"
    if auto.mode is not None:
        plan, why = choose_mode(plan, request.scene, memories, auto.mode, auto.node_memory)
    if auto.node_memory is not None and plan.mode == "object" and not plan.node_bytes:
        plan = replace(plan, node_bytes=auto.node_memory)  # the engines' (host.planning.budget)
    if notice is not None:
        notice(f"plan: {plan.mode} space on {plan.rows}x{plan.cols} ({why})")
    lost: list[dict] = []
    first_loss = None
    kept = None  # what lost tries leave that the next keeps (`host.run.kept`)
    try:
        while True:
            names = [f"node {n} ({addresses[n]})" for n in alive]
            attempt = Try(kept)
            try:
                fb, summary = await _attempt(
                    attempt,
                    request.on(plan),
                    memory,
                    [links[n] for n in alive],
                    [addresses[n] for n in alive],
                    names,
                    Observers(progress, watch, ready),
                    (silence, stall),
                )
                break
            except MeshError as e:
                if on_node_loss == "fail":
                    raise
                t_loss = time.perf_counter()
                gone = await give_up([links[n] for n in alive], e, silence)
                if not gone or len(gone) == len(alive):
                    raise
                kept = attempt.left()
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
        await close_all([links[n] for n in alive])
    end = time.perf_counter()
    setup = summary["setup_seconds"]
    summary |= common(
        request.scene.source,
        request.sized,
        request.engine,
        summary["rays"],
        summary["compile_seconds"],
        setup,
        max(end - start - setup, 0.0),
    )
    summary["addresses"] = [addresses[n] for n in alive]
    summary["lost_nodes"] = lost
    summary["recovery_seconds"] = end - first_loss if first_loss is not None else 0.0
    summary["recovery"] = recovery(kept, bool(lost))
    summary["mode"] = {"choice": plan.mode, "why": why, "node_memory_bytes": memories}
    summary["connect_seconds"] = connect
    return fb.image(), summary


def shrink(plan: MeshPlan, nodes: int) -> MeshPlan:
    """The plan on `nodes` nodes: the most nearly square rows x cols that uses them all
    (shared cells were the old mesh's: the pre-pass chooses again on the new one)."""
    rows = max(d for d in range(1, math.isqrt(nodes) + 1) if nodes % d == 0)
    return replace(plan, rows=rows, cols=nodes // rows, shared=())


@dataclass
class Try:
    """One try at the frame: what the last lost try left (`kept`), and this one's plan,
    framebuffer and collector once made, so a lost try leaves what it traced whole."""

    kept: Kept | None
    planned: Planned | None = None
    fb: Framebuffer | None = None
    collector: Collector | None = None

    def left(self) -> Kept | None:
        """What this try, lost, leaves to the next (nothing if it never got to trace)."""
        if self.collector is None:
            return self.kept
        return kept_after(self.kept, self.planned, self.fb, self.collector)


@dataclass(frozen=True)
class Observers:
    """Who hears of a try's progress: `progress(n)` of primary rays, the live view's
    `watch`, and `ready()` once every node traces."""

    progress: object = None
    watch: object = None
    ready: object = None


async def _attempt(
    attempt: Try,
    request: Request,
    memory: int,
    links: list[Link],
    addresses,
    names,
    observers: Observers,
    patience: tuple[float, float],
):
    """One try at the frame of `request` on `links` (node i is links[i] at addresses[i],
    called names[i] in messages): (framebuffer, summary); `memory`: the smallest node's,
    for `plan_render`; `patience`: (silence, stall) seconds for the collector."""
    progress, watch, plan = observers.progress, observers.watch, request.plan
    start, ticks = time.perf_counter(), time.monotonic()
    planned = plan_render(request, memory)
    kept = attempt.kept if attempt.kept is not None and keeps_tiles(planned) else None
    if kept is not None:
        planned = with_kept_tiles(planned, kept)
    await configure(request.scene, planned, links, addresses)
    sent = time.perf_counter() - start
    spec = planned.spec
    width, height = spec.image.size
    fb = Framebuffer(width, height, spec.corners, spec.ids_per_cell)
    sky = planned.sky
    fb.add(sky.records["pixel"], sky.records["rgb"])
    dealer = _dealer(planned, (kept.tiles if kept else frozenset()) | sky.tiles)
    collector = Collector(fb, names, progress, *patience, dealer, watch, observers.ready)
    if kept is not None:
        fb.sums += kept.sums  # the tiles traced whole before: dealt to nobody this time
    if progress and (kept is not None or sky.tiles):
        collector.traced = (kept.counts if kept else {}).get("eye_rays", 0)
        collector.traced += sky.counts.get("eye_rays", 0)
        progress(collector.traced)
    attempt.planned, attempt.fb, attempt.collector = planned, fb, collector
    if watch is not None:
        watch.start(
            fb,
            plan.rows,
            plan.cols,
            planned.holders.sum(axis=1).tolist(),
            primary_rays(spec.image, request.camera),
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
    summary = summarise(
        collector.stats,
        planned.spec.plan,
        planned.holders,
        collector.deposits,
        ready,
    )
    summary["configure_seconds"] = sent - planned.seconds  # CONFIG and objects sent
    if kept is not None:  # the kept tiles' rays, traced by the lost try
        _add_counts(summary, kept.counts)
    _add_counts(summary, sky.counts)  # ... and those of the tiles the sky fills
    summary["sky_tiles"] = sky.stats
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


def _add_counts(summary: dict, counts: dict) -> None:
    """The summary's ray counts with `counts` (of tiles no node traced) added."""
    for k, v in counts.items():
        summary["rays"][k] = summary["rays"].get(k, 0) + v


def _dealer(planned: Planned, kept=frozenset()) -> TileDealer | None:
    """The host's dealer of dynamic tiles for this plan, dealing none of the `kept` ones;
    None where the partition fixes every tile's node."""
    spec, chosen = planned.spec, planned.spec.plan
    if not chosen.dynamic:
        return None
    rects = planned.partition.rects
    return TileDealer(
        [t for t in deal_order(rects, chosen.order) if t not in kept],
        chosen.nodes,
        chosen.buffer,
        spec.adaptive,
        count=len(rects),
    )


def primary_rays(image: ImageSpec, camera) -> int | None:
    """Primary rays of a sized image (None through a camera: rays lost in it are never
    traced, so there is no known total)."""
    if camera is not None:
        return None
    gw, gh = image.sample_grid()
    return gw * gh * (1 if image.corners() else image.spp)
