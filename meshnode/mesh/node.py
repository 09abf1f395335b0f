"""What one mesh node does with rays, without any sockets: the service and the simulated mesh
both wrap this.

A node holds the objects touching its box and every node's box (in image space: the whole
scene, and every box is the scene's). It makes the primary rays of its rectangles (one in
object space, its tiles in image space) for each state of the render that has them, traces
batches and says where each batch's deposits and leaving rays go; under adaptive sampling its
books (`books.NodeBooks`) keep its own pixels until the frame is flushed.
"""

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from meshnode.engine.camera import eye_rays
from meshnode.engine.deposits import cell_sums, lit
from meshnode.engine.lenscamera import camera_batches, camera_rays, rect_pixels
from meshnode.engine.raycheck import first_untraceable
from meshnode.engine.sky import cells_of, counted, node_sky, sky_batch
from meshnode.engine.structure_cost import eye_ray_count
from meshnode.mesh.adaptive import RAYS_PER_BATCH, RectIndex
from meshnode.mesh.books import NodeBooks
from meshnode.mesh.claimfeed import ClaimFeed
from meshnode.mesh.claims import (
    claim_cells,
    claimed_bands,
    node_claims,
    node_eye_map,
    routing_map,
)
from meshnode.mesh.engines import EngineCache
from meshnode.mesh.feeds import ChunkFeed, Primaries, TileFeed, stealable_last
from meshnode.mesh.spiral import spiral_chunks
from protocols.dtypes import DEPOSIT, RAY
from protocols.errors import BadFrame
from protocols.partition import Partition
from protocols.records import joined
from protocols.render import EVERYWHERE, RenderSpec
from protocols.scene import SceneData, View
from protocols.state import State

HOST = -1  # deposits for the host (object space: through node 0)
EYE_BATCH = 4096  # pinhole eye rays per batch: small enough to interleave with passed rays
IMAGE_BATCH = 65536  # ... in image space, where none are passed: a tile's rows at once
# ... in object space under copies, where few are passed and a batch splits into a kernel
# call per engine held: tetra 2x2 simulated in one process (256x256 at 62 spp, four turns
# each), the nodes' summed tracing CPU best / median: 4096 0.824 / 0.868 s, 16384 0.653 /
# 0.782 s, 65536 0.713 / 0.764 s (`python -m bench.batch_cpu --only tetra --mesh 2x2
# --size 256 --spp 62 --copies-eye-batch N` measures it: its "batches s" column, one turn
# each on a loaded machine, 1.42 / 1.22 / 1.38 s for 4096 / 16384 / 65536)
COPIES_EYE_BATCH = 16384


@dataclass
class Batch:
    """The outcome of tracing one batch on one node."""

    deposits: dict[int, np.ndarray]  # node (HOST: the host) -> DEPOSIT records it takes
    # cell -> RAY records its engine takes on, held elsewhere (`NodeCore.takers` says where),
    # in parts as traced: they leave in frames from where they lie (`protocols.records.Parts`)
    outgoing: dict[int, list[np.ndarray]]
    counts: dict[str, int] = field(default_factory=dict)
    # node -> RAY records its engine, held here (this node's own or a copy), takes on later
    held: dict[int, np.ndarray] = field(default_factory=dict)


def per_cell(deposits: np.ndarray, ids_per_cell: int) -> np.ndarray:
    """A batch's deposits summed per framebuffer cell, under the cell's first id
    (`deposits.cell_sums`: in the order they came, as the host adds them, so the image is
    the same to the bit); the deposits themselves where no cell has two."""
    if len(deposits) < 2:
        return deposits
    out = np.empty(len(deposits), DEPOSIT)
    n = cell_sums(deposits, ids_per_cell, out)
    return deposits if n == len(deposits) else out[:n]


def lit_deposits(rays: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """DEPOSIT records of the rays that brought any colour (`deposits.lit`)."""
    out = np.empty(len(rays), DEPOSIT)
    return out[: lit(rays, rgb, out)]


class NodeCore:
    """One node's engine, primary rays and routing, for one render; pinhole eye rays are
    made in batches of about `eye_batch` (whole rows of the node's rectangle); `engines`
    keeps the engine for the next render (None: always build)."""

    def __init__(
        self,
        node: int,
        scene: SceneData,
        spec: RenderSpec,
        part: Partition,
        eye_batch: int | None = None,
        engines: EngineCache | None = None,
        copies: dict[int, SceneData] | None = None,
    ):
        self.node, self.spec, self.view, self.part = node, spec, scene.view, part
        least = (
            IMAGE_BATCH
            if spec.plan.mode == "image"
            else (COPIES_EYE_BATCH if spec.plan.copies else 0)
        )
        self.eye_batch = max(EYE_BATCH if eye_batch is None else eye_batch, least)
        self.feed = TileFeed() if spec.plan.dynamic else None
        self.owned = [] if self.feed else part.rects_of(node)
        self.los, self.his = part.boxes
        self.cells = part.cells  # who takes a ray on (the boxes grown by the overlap hold it)
        self.takers = spec.plan.takers(node)  # the node a cell's rays are handed to
        copies = copies or {}
        engines = engines or EngineCache()
        keep = 1 + len(copies)
        self.engine, self.engine_reused = engines.get(scene, keep, **self._options(node))
        # MeshPlan.copies: neighbour m's engine, built as m builds it (its objects, its box),
        # traces here the segments m would take on, to the same bits. (A simulated mesh sets
        # the very engines its other cores trace with.)
        self.copies = {m: engines.get(c, keep, **self._options(m))[0] for m, c in copies.items()}
        held = (self.engine, *self.copies.values())
        self.engine_bytes = sum(e.stats["engine_bytes"] for e in held)
        if spec.plan.node_bytes and self.engine_bytes > spec.plan.node_bytes:
            raise BadFrame(
                f"node {node}'s engines take {self.engine_bytes} bytes, over the plan's budget "
                f"of {spec.plan.node_bytes} (MeshPlan.node_bytes)"
            )
        self.books = NodeBooks(node, spec, part, self.view, self.feed) if spec.adaptive else None
        self.eye, self.eye_reason = node_eye_map(
            engines, self.engine, spec, part, self.view, self.books
        )
        background, eye = self.engine.shading.background, (self.eye, self.eye_reason)
        self.sky, self.sky_reason = node_sky(spec, part, self.view, *eye, background)
        self.claims, self.claims_reason = node_claims(
            engines, self.engine, spec, part, self.view, self.eye
        )
        self.claim_cells = None  # under stealing, the cell each claimed sample starts in
        if spec.plan.steal and self.claims is not None:
            self.claim_cells = claim_cells(engines, self.engine, spec, part, self.view, self.eye)
        self.eye = routing_map(self.eye, list(spec.plan.held(node)))

    def _options(self, node: int) -> dict:
        """Node `node`'s engine: the render's EngineSpec whole, at its box, told the primary
        rays it is expected to take on (its structure is chosen for them and the rays they
        bring): taken as an even share of the render's, 1/nodes, in object space as in
        image space (a node's own rectangle or tiles; in object space the rays passed on
        from neighbours add to it, and crowded boxes take more than others)."""
        spec, part = self.spec, self.part
        return dict(
            spec=spec.engine,
            box=(self.los[node], self.his[node]),
            scene_box=part.scene_box,
            max_depth=spec.image.depth,
            # image space: one process's engine (a map sent there is the sky's)
            occupancy=EVERYWHERE
            if spec.plan.mode == "image"
            else (part.occ_res, part.occ_bits, part.occ_fine, part.inner),
            eye_rays_expected=eye_ray_count(spec.image, spec.camera is not None) / spec.plan.nodes,
        )

    @property
    def keeps_pixels(self) -> bool:
        """Adaptive sampling: this node keeps the books of its own pixels."""
        return self.books is not None

    def warmup(self) -> None:
        """Compile or load every kernel a render will call, before any is timed."""
        for engine in (self.engine, *self.copies.values()):
            engine.warmup()
        ray = np.zeros(1, RAY)
        ray["d"] = (0.0, 0.0, 1.0)
        ray["t_max"] = np.inf
        self.engine.routed(ray, self.cells, True, self.node)
        first_untraceable(ray)  # a neighbour's RAYS are checked by it (meshnode.service.inbound)
        per_cell(lit_deposits(ray, np.ones((1, 3))).repeat(2), 1)
        if self.spec.camera is not None:
            view = View((0, 0, 0), (0, 0, 1), (0, 1, 0), 45.0)
            camera_rays(self.spec.camera, self.spec.image.spp, view, 1, 1, np.zeros(1, int))

    def primaries(self, state: State) -> Primaries:
        """Batches of this node's primary rays for a state of the render: every eye or camera
        ray in TRACE, or adaptive sampling's two passes (`NodeBooks.primaries`); under
        dynamic tiles, the feed the host's tiles arrive in. Made one batch at a time."""
        if state == State.TRACE and self.feed is not None:
            return self.feed
        if self.books is not None:
            return self.books.primaries(state)
        if state != State.TRACE:
            return Primaries()
        if self.spec.plan.steal and self.claims is not None:  # holders take claimed chunks
            plan, image = self.spec.plan, self.spec.image
            per_cell = 1 if image.corners() else image.spp
            args = (self.claims, self.claim_cells, plan, plan.tile, self._made)
            return ClaimFeed(self.node, *args, per_cell, self.eye_batch)
        if self.spec.plan.steal:
            side = self.spec.plan.tile
            chunks = [c for rect in self.owned for c in spiral_chunks(rect, side)]
            usable = self._usable()
            return ChunkFeed(
                stealable_last(chunks, usable, self.node, self.spec.plan),
                lambda chunks: self.rect_batches(chunks[0]),
                usable=usable,
            )
        if self.claims is not None:
            return Primaries(self._claimed_batches())
        return Primaries(batch for rect in self.owned for batch in self.rect_batches(rect))

    def _usable(self):
        """Under MeshPlan.copies, which chunks a thief can trace itself: those of tiles
        whose eye rays a node it holds the engine of takes on (`Partition.takers`: the node
        most of a tile's eye rays enter). A diagonal neighbour's chunks would only have
        their eye rays made there and sent on. None without copies: any chunk moves."""
        if not self.spec.plan.copies:
            return None
        plan, (gw, _) = self.spec.plan, self.spec.sample_grid
        taker = np.asarray(self.part.takers or self.part.owner, np.int64)
        index = RectIndex(self.part.rects, gw)

        def usable(thief: int, chunks: list) -> np.ndarray:
            c = np.asarray(chunks, np.int64)
            held = np.array(plan.held(thief))
            tile = index(c[:, 2] * gw + c[:, 0])
            return (tile >= 0) & np.isin(taker[tile], held)

        return usable

    def rect_batches(self, rect):
        """Every primary ray of one rectangle (no adaptive sampling), batch by batch."""
        image, camera = self.spec.image, self.spec.camera
        if camera is None:
            return self._eye_batches(rect)
        w, h = image.size
        return camera_batches(
            camera, image.spp, self.view, w, h, rect_pixels(rect, w), image.seed, RAYS_PER_BATCH
        )

    def add_tiles(self, tiles: list[int], last: bool, owners=()) -> dict[int, np.ndarray]:
        """Dynamic image space: tiles the host dealt (indices of the partition's rectangles),
        whether it will deal no more, and then under adaptive sampling every tile's node
        (`owners`). Returns deposits to send on, by node (`NodeBooks.keep`)."""
        books = self.books
        for t in tiles:
            if not 0 <= t < len(self.part.rects) or (books is not None and books.dealt(t)):
                raise ValueError(
                    f"TILES: tile {t} is not one of the {len(self.part.rects)}, "
                    "or was dealt here before"
                )
            rays = books.deal(t) if books is not None else self.rect_batches(self.part.rects[t])
            self.feed.add(t, rays)
        if last and books is not None:
            books.learn_owners(np.asarray(owners))
        if last:
            self.feed.close()
        return books.release() if books is not None else {}

    def _claimed_batches(self):
        """The eye rays of every sample-grid cell this node claims."""
        return self._made(self.claims == self.node, 0, 0)

    def _eye_batches(self, rect):
        x0, x1, y0, y1 = rect
        return self._made(np.ones((y1 - y0, x1 - x0), bool), y0, x0)

    def _made(self, flags: np.ndarray, y: int, x: int):
        """Batches of the eye rays of the flagged cells of a rectangle whose first cell is
        (`y`, `x`), in bands of rows of about `eye_batch` rays; those that meet nothing last,
        as one batch of their deposits (`sky.sky_batch`), made and traced by no one."""
        image, (h, w) = self.spec.image, flags.shape
        nothing = flags & cells_of(self.sky, (y, y + h), (x, x + w))
        made, per_cell = flags & ~nothing, 1 if image.corners() else image.spp
        for y0, y1, x0, x1 in claimed_bands(made, per_cell, self.eye_batch):
            rows, cols = (y + y0, y + y1), (x + x0, x + x1)
            yield eye_rays(self.view, image, rows=rows, cols=cols, keep=made[y0:y1, x0:x1])
        yield sky_batch(self.sky, nothing, y, x)

    def trace(self, rays: np.ndarray, primary: bool = False, taker: int | None = None) -> Batch:
        """Trace a batch here, with the engine of node `taker` (this node's own when None, or
        a copy it holds: MeshPlan.copies); in object space a batch of primary rays first
        sends each ray to the node whose cell holds its start (`Engine.routed`), as every
        passed segment goes: a ray's segments then do not depend on the node that made it (a
        stolen chunk's eye rays were traced from the thief's box where they started in both,
        and round-off at box edges then changed a few trees in millions: 11 rays on a
        mount_s1 2x2 at 10 spp). Rays for a neighbour whose copy this node holds are traced
        here with that copy instead. Segments that leave for an engine held here come back
        in `Batch.held`, to be queued and merged with others for the same engine: traced at
        once, each batch's few dozen per engine cost a kernel call apiece (tetra 3x3
        simulated, 384x384 at 32 spp: 593 engine calls, 310 of them under 8,192 rays; 508
        merged)."""
        began = time.thread_time()
        if rays.dtype == DEPOSIT:  # eye rays that meet nothing: their deposits (`sky`)
            return self._sky_deposits(rays, began)
        todo = {self.node if taker is None else taker: rays}
        if primary and self.spec.plan.mode == "object" and len(self.los) > 1:
            # from where each ray's work starts (the map's first occupied voxel); a ray that
            # enters no cell ends here. Grouped in this one call: owners() moves t_min in a
            # sliver between boxes, so a second call could give another box.
            out, starts, _ = self.engine.routed(rays, self.cells, True, self.node, self.eye)
            todo = _runs(out, starts, last=self.node)
        outgoing = {d: [g] for d, g in todo.items() if d != self.node and d not in self.copies}
        counts: Counter = Counter(rays_forwarded=sum(len(g[0]) for g in outgoing.values()))
        held: dict[int, list] = {}
        deposits, cpu = [], 0.0
        for taker, batch in todo.items():
            if taker in outgoing:
                continue
            engine = self.engine if taker == self.node else self.copies[taker]
            cpu -= time.thread_time()
            rgb, done, passed = engine.trace_node(batch)
            cpu += time.thread_time()
            counts.update(done)
            deposits.append(lit_deposits(batch, rgb))
            for dest, sent in self.route(passed).items():
                into = held if dest == self.node or dest in self.copies else outgoing
                into.setdefault(dest, []).append(sent)
        counts["cpu_seconds"] = cpu
        deposits = joined(deposits) if deposits else np.zeros(0, DEPOSIT)
        routes = self.pixel_routes(deposits)
        counts["batch_cpu_seconds"] = time.thread_time() - began  # routing and deposits too
        return Batch(routes, outgoing, dict(counts), _joined(held))

    def stood_for(self, rays: np.ndarray) -> int:
        """The eye rays a primary batch stands for: its rays, or under a batch of the sky's
        cells (`sky.sky_batch`) their samples."""
        return len(rays) * (self.sky.per_cell if rays.dtype == DEPOSIT else 1)

    def _sky_deposits(self, sky: np.ndarray, began: float) -> Batch:
        """A batch standing for eye rays that meet nothing (`sky.sky_batch`): deposited and
        counted as traced (a black background deposits nothing, as `lit` keeps nothing)."""
        lit = sky if self.sky.rgb.any() else sky[:0]
        counts = counted({"cpu_seconds": 0.0}, self.stood_for(sky))
        routes = self.pixel_routes(lit)
        counts["batch_cpu_seconds"] = time.thread_time() - began
        return Batch(routes, {}, counts, {})

    def pixel_routes(self, deposits: np.ndarray) -> dict[int, np.ndarray]:
        """Deposits by where they go: the host, or under adaptive sampling the node owning
        each deposit's pixel (`NodeBooks.routes`)."""
        if len(deposits) == 0:
            return {}
        if self.books is None:
            return {HOST: per_cell(deposits, self.spec.ids_per_cell)}
        return self.books.routes(deposits)

    def keep(self, deposits: np.ndarray, traced_here: bool = False) -> dict[int, np.ndarray]:
        """Deposits for this node's own pixels into its books (`NodeBooks.keep`); returns
        deposits to send on, by node."""
        return self.books.keep(deposits, traced_here)

    def route(self, rays: np.ndarray) -> dict[int, np.ndarray]:
        """Rays grouped by the node that takes each on from its t_min: the one whose cell
        holds it there (or, from outside the scene, where it enters), not any box that holds
        it: boxes overlap, cells tile the scene (`owners`, which moves t_min to that entry)."""
        if len(rays) == 0:
            return {}
        out, starts, lost = self.engine.routed(rays, self.cells, False)
        if lost:
            raise RuntimeError(f"node {self.node}: {lost} rays have no owner box")
        return _runs(out, starts)

    def finished_pixels(self):
        """Adaptive sampling, once every deposit is in: DEPOSIT batches of this node's
        finished pixels for the host (none otherwise)."""
        return self.books.finished_pixels() if self.books is not None else iter(())

    @property
    def refined_pixels(self) -> int:
        return self.books.refined_pixels if self.books is not None else 0


def _joined(parts: dict[int, list]) -> dict[int, np.ndarray]:
    """Each node's list of record arrays as one array."""
    return {n: joined(g) for n, g in parts.items()}


def _runs(rays: np.ndarray, starts: np.ndarray, last: int | None = None) -> dict:
    """The non-empty runs of `Engine.routed` (views) by node, in node order with `last` at
    the end: a primary batch's own rays are traced after those it sends on, as before."""
    bounds = starts.tolist()
    nodes = [n for n in range(len(bounds) - 1) if bounds[n + 1] > bounds[n] and n != last]
    if last is not None and bounds[last + 1] > bounds[last]:
        nodes.append(last)
    return {n: rays[bounds[n] : bounds[n + 1]] for n in nodes}
