"""What one mesh node does with rays, without any sockets: the service and the simulated mesh
both wrap this.

A node holds the objects touching its box and every node's box (in image space: the whole
scene, and every box is the scene's). It makes the primary rays of its rectangles (one in
object space, its tiles in image space) for each state of the ring that has them, traces
batches, says where each batch's deposits and leaving rays go, and under adaptive sampling
keeps the books of its own pixels until the frame is flushed.
"""

import hashlib
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from meshnode.engine import Engine
from meshnode.engine.camera import eye_rays
from meshnode.engine.deposits import cell_sums, lit
from meshnode.engine.lenscamera import camera_batches, camera_rays, rect_pixels
from meshnode.mesh.adaptive import (
    RAYS_PER_BATCH,
    AdaptiveFilm,
    RectIndex,
    deposit_routes,
    pass_samples,
    split,
)
from meshnode.mesh.scheduler import ChunkFeed, Primaries, TileFeed, spiral_order
from protocols.dtypes import DEPOSIT, RAY
from protocols.render import EngineSpec, Partition, RenderSpec
from protocols.scene import SceneData, View
from protocols.state import State
from protocols.topology import Torus

HOST = -1  # deposits for the host (object space: through node 0)
EYE_BATCH = 4096  # pinhole eye rays per batch: small enough to interleave with passed rays
IMAGE_BATCH = 65536  # ... in image space, where none are passed: a tile's rows at once
# ... in object space under copies, where few are passed and a batch splits into a kernel
# call per engine held: tetra 2x2 simulated in one process (256x256 at 62 spp, four turns
# each, /tmp script), the nodes' summed tracing CPU best / median: 4096 0.824 / 0.868 s,
# 16384 0.653 / 0.782 s, 65536 0.713 / 0.764 s
COPIES_EYE_BATCH = 16384
# Stolen or stealable chunks (adaptive sampling's refined runs, a few hundred rays each) start
# this many rays' worth at a time: one kernel call and one deposit message per run cost
# dynamic tiles on balls 2x2 20% more CPU than static; 16384 left a 3x3's pass 2 too coarse
# to steal evenly (bench.mesh --camera, balls 3x3 dynamic: work 6.81 against 7.74 at 4096).
CHUNK_RAYS = 4096


@dataclass
class Batch:
    """The outcome of tracing one batch on one node."""

    deposits: dict[int, np.ndarray]  # node (HOST: the host) -> DEPOSIT records it takes
    outgoing: dict[int, np.ndarray]  # node -> RAY records it takes on
    counts: dict[str, int] = field(default_factory=dict)
    # node -> RAY records its engine, held here (this node's own or a copy), takes on later
    held: dict[int, np.ndarray] = field(default_factory=dict)


class EngineCache:
    """The engines this node built for its last render, kept for the next render of the same
    objects in the same box with the same engine settings (a user re-rendering a scene at
    another size, sampling or camera on a running cluster pays no build). At most `keep`
    engines (one, or one per box held under MeshPlan.copies), least recently used dropped
    first: bounded memory."""

    def __init__(self):
        self.engines: dict[bytes, Engine] = {}  # oldest use first

    def get(
        self, scene: SceneData, keep: int = 1, spec: EngineSpec = EngineSpec(), **placement
    ) -> tuple[Engine, bool]:
        """(engine, whether it was reused) for `scene` built as `spec` says, at `placement`
        (Engine.from_spec's keywords)."""
        key = _engine_key(scene, {"spec": spec, **placement})
        engine = self.engines.pop(key, None)
        reused = engine is not None
        if engine is None:
            while len(self.engines) >= max(1, keep):  # old memory goes before the build
                del self.engines[next(iter(self.engines))]
            engine = Engine.from_spec(scene, spec, **placement)
        self.engines[key] = engine
        return engine, reused


def _engine_key(scene: SceneData, options: dict) -> bytes:
    """A digest of everything an engine is built from: objects, background, options."""
    h = hashlib.blake2b(digest_size=32)
    for table in (
        scene.materials,
        scene.lights,
        scene.spheres,
        scene.triangles,
        scene.polygons,
        scene.vertices,
        scene.cones,
    ):
        h.update(len(table).to_bytes(8, "little"))
        h.update(np.ascontiguousarray(table).tobytes())
    h.update(
        repr((tuple(scene.background), sorted((k, repr(v)) for k, v in options.items()))).encode()
    )
    return h.digest()


def spiral_chunks(rect, side: int) -> list[tuple[int, int, int, int]]:
    """`rect` (x0, x1, y0, y1) cut into chunks of `side` pixels, ordered from the centre
    outward: ring by ring (Chebyshev distance of the chunk from the middle one), each ring
    walked round by angle. Traced from the front, stolen from the back (DESIGN.md 6)."""
    x0, x1, y0, y1 = rect
    xs, ys = list(range(x0, x1, side)), list(range(y0, y1, side))
    j, i = np.divmod(np.arange(len(xs) * len(ys)), len(xs))
    return [
        (xs[i[c]], min(xs[i[c]] + side, x1), ys[j[c]], min(ys[j[c]] + side, y1))
        for c in spiral_order(i, j)
    ]


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
        eye_batch: int = EYE_BATCH,
        engines: EngineCache | None = None,
        copies: dict[int, SceneData] | None = None,
    ):
        self.node, self.spec, self.view, self.part = node, spec, scene.view, part
        least = (
            IMAGE_BATCH
            if spec.plan.mode == "image"
            else (COPIES_EYE_BATCH if spec.plan.copies else 0)
        )
        self.eye_batch = max(eye_batch, least)
        self.feed = TileFeed() if spec.plan.dynamic else None
        self.owned = [] if self.feed else part.rects_of(node)
        self.los, self.his = part.boxes
        self.cells = part.cells  # who takes a ray on (the boxes grown by the overlap hold it)
        copies = copies or {}
        engines = engines or EngineCache()
        keep = 1 + len(copies)
        self.engine, self.engine_reused = engines.get(scene, keep, **self._options(node))
        # MeshPlan.copies: neighbour m's engine, built as m builds it (its objects, its box),
        # traces here the segments m would take on, to the same bits. (A simulated mesh sets
        # the very engines its other cores trace with.)
        self.copies = {m: engines.get(c, keep, **self._options(m))[0] for m, c in copies.items()}
        self.films: list[AdaptiveFilm] = []
        self.adaptive = spec.adaptive
        if self.adaptive:
            self.every_rect = RectIndex(part.rects, spec.image.size[0])
            self.film_at = np.full(len(part.rects), -1, np.int64)  # rectangle -> own film
            self.samples = pass_samples(spec.camera)  # (pass 1's, pass 2's sample indices)
            # rectangle -> node; under dynamic tiles -1 until the host says (`add_tiles`)
            self.rect_owner = (
                np.full(len(part.rects), -1, np.int64)
                if self.feed is not None
                else np.asarray(part.owner, np.int64)
            )
            self.held_out: list = []  # dynamic tiles: (deposits, idx, rect) traced here ...
            self.held_in: list = []  # ... and received, for tiles of nodes not known yet
            # pass 1 routes a deposit to at most 5 tiles (its pixel's and the 4 sides')
            self.held_bound = 5 * len(self.samples[0]) * int(np.prod(spec.image.size))
            self.held_count = 0
            for t in np.flatnonzero(self.rect_owner == node).tolist():
                self._add_film(t)

    def _options(self, node: int) -> dict:
        """Node `node`'s engine: the render's EngineSpec whole, at its box."""
        spec, part = self.spec, self.part
        return dict(
            spec=spec.engine,
            box=(self.los[node], self.his[node]),
            scene_box=part.scene_box,
            max_depth=spec.image.depth,
            occupancy=(part.occ_res, part.occ_bits),
        )

    @property
    def keeps_pixels(self) -> bool:
        """Adaptive sampling: this node keeps the books of its own pixels."""
        return self.adaptive

    def _add_film(self, tile: int) -> AdaptiveFilm:
        """Books for an own rectangle (or a dealt tile) of the adaptive render."""
        w, h = self.spec.image.size
        film = AdaptiveFilm(self.spec.camera, self.part.rects[tile], w, h, self.spec.image.seed)
        self.film_at[tile] = len(self.films)
        self.films.append(film)
        return film

    def warmup(self) -> None:
        """Compile or load every kernel a render will call, before any is timed."""
        for engine in (self.engine, *self.copies.values()):
            engine.warmup()
        ray = np.zeros(1, RAY)
        ray["d"] = (0.0, 0.0, 1.0)
        ray["t_max"] = np.inf
        self.engine.routed(ray, self.cells, True, self.node)
        per_cell(lit_deposits(ray, np.ones((1, 3))).repeat(2), 1)
        if self.spec.camera is not None:
            view = View((0, 0, 0), (0, 0, 1), (0, 1, 0), 45.0)
            camera_rays(self.spec.camera, view, 1, 1, np.zeros(1, int))

    def primaries(self, state: State) -> Primaries:
        """Batches of this node's primary rays for a state of the ring: every eye or camera
        ray in TRACE, or adaptive sampling's first pass (corner rays) in TRACE and second (the
        rest, where the corners differ) in REFINE; under dynamic tiles, the feed the host's
        tiles arrive in. Made one batch at a time."""
        w, h = self.spec.image.size
        if state == State.TRACE and self.feed is not None:
            return self.feed
        if self.adaptive:
            if state not in (State.TRACE, State.REFINE):
                return Primaries()
            if self.spec.steals:
                return self._adaptive_chunks(state == State.REFINE)
            return Primaries(
                batch
                for f in self.films
                for batch in (f.pass1 if state == State.TRACE else f.pass2)(self.view, w, h)
            )
        if state != State.TRACE:
            return Primaries()
        if self.spec.plan.steal:
            side = self.spec.plan.tile
            chunks = [c for rect in self.owned for c in spiral_chunks(rect, side)]
            usable = self._usable()
            return ChunkFeed(
                self._stealable_last(chunks, usable),
                lambda chunks: self.rect_batches(chunks[0]),
                usable=usable,
            )
        return Primaries(batch for rect in self.owned for batch in self.rect_batches(rect))

    def _stealable_last(self, chunks: list, usable) -> list:
        """Under MeshPlan.copies, the chunks fewest of this node's links could trace first
        and those most could last (stable, so each kind keeps its spiral order): thieves
        take from the back, and a node left at the end with chunks only one link holds the
        engine for finished last while the others idled (tetra 3x3, simulated at 137 spp:
        the centre node kept 10 of 11 unstarted chunks from its asking links; parallel
        efficiency 0.948 -> 0.972)."""
        if usable is None or not chunks:
            return chunks
        links = set(Torus(self.spec.plan.rows, self.spec.plan.cols).links(self.node))
        reach = sum(usable(m, chunks).astype(np.int64) for m in links - {self.node})
        return [chunks[i] for i in np.argsort(reach, kind="stable").tolist()]

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

    def _adaptive_chunks(self, refine: bool) -> ChunkFeed:
        """Adaptive sampling with stealing: one pass over chunks of the own rectangles in
        spiral order; in pass 2 (REFINE) a chunk's refined pixels, as runs along its rows
        (`AdaptiveFilm.refined_runs`). An own chunk's books are kept once, by this node,
        when it is traced here or given away (`AdaptiveFilm.make`), whichever comes first: a
        stolen chunk may be passed on, or even come back. The node that traces a chunk makes
        its rays; their deposits go to the pixels' owner, as every deposit does. Chunks are
        started as many at a time as make CHUNK_RAYS rays (a refined run makes a few
        hundred), own ones with books still to keep apart from the rest."""
        side = self.spec.plan.tile
        chunks = []
        for film in self.films:
            if refine:
                film.start_refine()
            for c in spiral_chunks(film.rect, side):
                chunks.extend(film.refined_runs(c) if refine else [c])
        counted: set = set()

        def own(chunk) -> AdaptiveFilm | None:
            """The film of an own chunk whose books are still to keep (now taken on)."""
            film = self._film_of(chunk)
            if film is None or chunk in counted:
                return None
            counted.add(chunk)
            return film

        def give(chunk) -> None:
            if (film := own(chunk)) is not None:
                for _ in self._film_batches(film, [chunk], refine):
                    pass  # books kept; the thief makes these same rays

        def batches(group):
            mine: dict[int, tuple[AdaptiveFilm, list]] = {}
            theirs = []
            for chunk in group:  # once per chunk started, a few hundred rays each
                film = own(chunk)
                if film is None:
                    theirs.append(chunk)
                else:
                    mine.setdefault(id(film), (film, []))[1].append(chunk)
            for film, own_chunks in mine.values():
                yield from self._film_batches(film, own_chunks, refine)
            if theirs:
                yield from self._stolen_batches(theirs, refine)

        per_pixel = len(self.samples[1 if refine else 0])

        def rays(chunk) -> int:
            x0, x1, y0, y1 = chunk
            return (x1 - x0) * (y1 - y0) * per_pixel

        return ChunkFeed(chunks, batches, give, rays=rays, budget=CHUNK_RAYS)

    def _film_of(self, chunk) -> AdaptiveFilm | None:
        """The film of the own rectangle holding `chunk`, None for a neighbour's chunk."""
        x0, _, y0, _ = chunk
        t = int(self.every_rect(np.array([y0 * self.spec.image.size[0] + x0]))[0])
        i = int(self.film_at[t]) if t >= 0 else -1
        return self.films[i] if i >= 0 else None

    def _film_batches(self, film: AdaptiveFilm, chunks: list, refine: bool):
        """Own chunks' rays for one adaptive pass, their books kept as they are made."""
        w, h = self.spec.image.size
        idx = np.concatenate([film.index_of(c) for c in chunks])
        for part in split(idx, len(film.rest if refine else film.first)):
            yield film.make(part, refine, self.view, w, h)

    def _stolen_batches(self, chunks: list, refine: bool):
        """The rays of chunks whose books their owner keeps, for one adaptive pass."""
        w, h = self.spec.image.size
        samples = self.samples[1 if refine else 0]
        pixels = np.concatenate([rect_pixels(c, w) for c in chunks])
        for part in split(pixels, len(samples)):
            yield camera_rays(
                self.spec.camera, self.view, w, h, part, samples, self.spec.image.seed
            )[0]

    def rect_batches(self, rect):
        """Every primary ray of one rectangle (no adaptive sampling), batch by batch."""
        image, camera = self.spec.image, self.spec.camera
        if camera is None:
            return self._eye_batches(rect)
        w, h = image.size
        return camera_batches(
            camera, self.view, w, h, rect_pixels(rect, w), image.seed, RAYS_PER_BATCH
        )

    def add_tiles(self, tiles: list[int], last: bool, owners=()) -> dict[int, np.ndarray]:
        """Dynamic image space: tiles the host dealt (indices of the partition's rectangles),
        whether it will deal no more, and then under adaptive sampling every tile's node
        (`owners`). Returns deposits to send on, by node (`keep`)."""
        w, h = self.spec.image.size
        for t in tiles:
            if not 0 <= t < len(self.part.rects) or (self.adaptive and self.film_at[t] >= 0):
                raise ValueError(
                    f"TILES: tile {t} is not one of the {len(self.part.rects)}, "
                    "or was dealt here before"
                )
            if self.adaptive:
                self.feed.add(t, self._add_film(t).pass1(self.view, w, h))
            else:
                self.feed.add(t, self.rect_batches(self.part.rects[t]))
        if last and self.adaptive:
            self._learn_owners(np.asarray(owners))
        if last:
            self.feed.close()
        return self._release() if self.adaptive else {}

    def _learn_owners(self, owners: np.ndarray) -> None:
        """Every tile's node, from the host's last TILES: checked against the tiles dealt
        here (all came before, on the same link)."""
        n = len(self.part.rects)
        if len(owners) != n or (n and (owners.min() < 0 or owners.max() >= len(self.los))):
            raise ValueError(
                f"TILES.owners must give each of the {n} tiles a node of the "
                f"{len(self.los)}, got {len(owners)} entries"
            )
        if not np.array_equal(owners == self.node, self.film_at >= 0):
            raise ValueError(f"TILES.owners disagrees with the tiles dealt to node {self.node}")
        self.rect_owner = owners.astype(np.int64)

    def _eye_batches(self, rect):
        x0, x1, y0, y1 = rect
        rows = max(1, self.eye_batch // max(1, (x1 - x0) * self.spec.image.spp))
        for y in range(y0, y1, rows):
            yield eye_rays(self.view, self.spec.image, rows=(y, min(y + rows, y1)), cols=(x0, x1))

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
        todo = {self.node if taker is None else taker: rays}
        if primary and self.spec.plan.mode == "object" and len(self.los) > 1:
            # from where each ray's work starts (the map's first occupied voxel); a ray that
            # enters no cell ends here. Grouped in this one call: owners() moves t_min in a
            # sliver between boxes, so a second call could give another box.
            out, starts, _ = self.engine.routed(rays, self.cells, True, self.node)
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
        deposits = (
            deposits[0]
            if len(deposits) == 1
            else np.concatenate(deposits)
            if deposits
            else np.zeros(0, DEPOSIT)
        )
        routes = self.pixel_routes(deposits)
        counts["batch_cpu_seconds"] = time.thread_time() - began  # routing and deposits too
        return Batch(routes, _joined(outgoing), dict(counts), _joined(held))

    def pixel_routes(self, deposits: np.ndarray) -> dict[int, np.ndarray]:
        """Deposits by where they go: the host, or under adaptive sampling the node owning
        each deposit's pixel (and pass-1 ones to the owners of its side neighbours)."""
        if len(deposits) == 0:
            return {}
        if not self.adaptive:
            return {HOST: per_cell(deposits, self.spec.ids_per_cell)}
        if self.feed is not None:  # tiles' nodes are learnt as the host deals: `keep` routes
            return {self.node: deposits}
        idx, rect = self._routes(deposits, self.every_rect)
        return _once_per_node(deposits, idx, self.rect_owner[rect])

    def keep(self, deposits: np.ndarray, traced_here: bool = False) -> dict[int, np.ndarray]:
        """Deposits routed to this node under adaptive sampling: into the film of each own
        rectangle that holds their pixel, or has it in its halo. Under dynamic tiles a batch
        traced here comes whole (`pixel_routes`, on a pool thread, cannot know which tiles
        are dealt here by the time it is kept): what it holds for other tiles goes on to
        their nodes, returned by node, once the host has said which those are (`add_tiles`);
        a received deposit for a tile not known to be this node's waits for that too.
        Returns deposits to send on, by node."""
        idx, rect = self._routes(deposits, self.every_rect)
        film = self.film_at[rect]
        mine = film >= 0
        self._add(deposits, idx[mine], film[mine])
        if self.feed is None or mine.all():
            return {}
        held = self.held_out if traced_here else self.held_in
        held.append((deposits, idx[~mine], rect[~mine]))
        self.held_count += int((~mine).sum())
        if self.held_count > self.held_bound:
            raise ValueError(
                f"node {self.node} holds more deposits for tiles of nodes not "
                f"known yet than the image's pass 1 makes ({self.held_bound})"
            )
        return self._release()

    def _add(self, deposits: np.ndarray, idx: np.ndarray, film: np.ndarray) -> None:
        for i in np.unique(film).tolist():
            mine = idx[film == i]
            self.films[i].add(deposits["pixel"][mine], deposits["rgb"][mine])

    def _release(self) -> dict[int, np.ndarray]:
        """Once every tile's node is known: held deposits kept for this node's tiles (tiles
        dealt here after they were traced), the rest of those traced here sent on, each to
        a node once however many of its tiles they touch (a received one for another node's
        tile came to this node for a tile of its own; its tracer sent it there too)."""
        if self.feed is None or self.feed.open or not (self.held_out or self.held_in):
            return {}  # closed with every tile's node learnt (`_learn_owners`)
        out: dict[int, list] = {}
        for deposits, idx, rect in self.held_in + self.held_out:
            film = self.film_at[rect]
            self._add(deposits, idx[film >= 0], film[film >= 0])
        for deposits, idx, rect in self.held_out:
            away = self.film_at[rect] < 0
            for n, d in _once_per_node(deposits, idx[away], self.rect_owner[rect[away]]).items():
                out.setdefault(n, []).append(d)
        self.held_in, self.held_out, self.held_count = [], [], 0
        return {n: np.concatenate(ds) for n, ds in out.items()}

    def _routes(self, deposits, index: RectIndex):
        camera, (w, h) = self.spec.camera, self.spec.image.size
        idx, rect = deposit_routes(
            deposits["pixel"], camera.per_pixel, self.samples[0], w, h, index
        )
        return idx[rect >= 0], rect[rect >= 0]

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
        for film in self.films:
            pixels, rgb = film.finish()
            for i in range(0, len(pixels), RAYS_PER_BATCH):
                d = np.zeros(len(pixels[i : i + RAYS_PER_BATCH]), DEPOSIT)
                d["pixel"], d["rgb"] = pixels[i : i + RAYS_PER_BATCH], rgb[i : i + RAYS_PER_BATCH]
                yield d

    @property
    def refined_pixels(self) -> int:
        return sum(int(f.refined.sum()) for f in self.films)


def _once_per_node(deposits: np.ndarray, idx: np.ndarray, node: np.ndarray) -> dict:
    """Deposits `idx` by node `node` (pairs), each deposit once per node however many of
    that node's tiles it touches."""
    keep = np.unique(node * len(deposits) + idx)
    return _group(deposits[keep % len(deposits)], keep // len(deposits))


def _joined(parts: dict[int, list]) -> dict[int, np.ndarray]:
    """Each node's list of record arrays as one array."""
    return {n: g[0] if len(g) == 1 else np.concatenate(g) for n, g in parts.items()}


def _runs(rays: np.ndarray, starts: np.ndarray, last: int | None = None) -> dict:
    """The non-empty runs of `Engine.routed` (views) by node, in node order with `last` at
    the end: a primary batch's own rays are traced after those it sends on, as before."""
    bounds = starts.tolist()
    nodes = [n for n in range(len(bounds) - 1) if bounds[n + 1] > bounds[n] and n != last]
    if last is not None and bounds[last + 1] > bounds[last]:
        nodes.append(last)
    return {n: rays[bounds[n] : bounds[n + 1]] for n in nodes}


def _group(records: np.ndarray, dest: np.ndarray) -> dict[int, np.ndarray]:
    """Records grouped by destination node (one sort, no loop per record)."""
    if len(records) == 0:
        return {}
    order = np.argsort(dest, kind="stable")
    nodes, starts = np.unique(dest[order], return_index=True)
    groups = np.split(records[order], starts[1:])
    pairs = zip(nodes.tolist(), groups, strict=True)
    return {n: np.ascontiguousarray(g) for n, g in pairs}
