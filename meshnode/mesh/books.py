"""A node's books of the pixels it owns under adaptive sampling (DESIGN.md 7), for NodeCore.

One film per own rectangle (`adaptive.AdaptiveFilm`; under dynamic tiles one per tile dealt
here), where each deposit goes (its pixel's owner, and for pass 1 the owners of the pixels
whose halo holds it), deposits held for dynamic tiles whose node is not known yet, and the
chunks of both passes when neighbours steal (the owner keeps a stolen chunk's books).
"""

import numpy as np

from meshnode.engine.lenscamera import camera_rays, rect_pixels
from meshnode.mesh.adaptive import (
    RAYS_PER_BATCH,
    AdaptiveFilm,
    RectIndex,
    deposit_routes,
    pass_samples,
    split,
)
from meshnode.mesh.feeds import ChunkFeed, Primaries, TileFeed
from meshnode.mesh.spiral import spiral_chunks
from protocols.dtypes import DEPOSIT
from protocols.partition import Partition
from protocols.records import taken
from protocols.render import RenderSpec
from protocols.scene import View
from protocols.state import State

# Stolen or stealable chunks (adaptive sampling's refined runs, a few hundred rays each) start
# this many rays' worth at a time: one kernel call and one deposit message per run cost
# dynamic tiles on balls 2x2 20% more CPU than static; 16384 left a 3x3's pass 2 too coarse
# to steal evenly (bench.mesh --camera, balls 3x3 dynamic: work 6.81 against 7.74 at 4096).
CHUNK_RAYS = 4096


class NodeBooks:
    """Adaptive sampling's books of node `node`'s pixels for one render; `feed`: the
    TileFeed dynamic tiles arrive in (None: the node owns its rectangles from the start)."""

    def __init__(
        self, node: int, spec: RenderSpec, part: Partition, view: View, feed: TileFeed | None
    ):
        self.node, self.spec, self.part, self.view, self.feed = node, spec, part, view, feed
        self.films: list[AdaptiveFilm] = []
        self.every_rect = RectIndex(part.rects, spec.image.size[0])
        self.film_at = np.full(len(part.rects), -1, np.int64)  # rectangle -> own film
        self.samples = pass_samples(spec.camera, spec.image.spp)  # (pass 1's, pass 2's)
        # rectangle -> node; under dynamic tiles -1 until the host says (`learn_owners`)
        self.rect_owner = (
            np.full(len(part.rects), -1, np.int64)
            if feed is not None
            else np.asarray(part.owner, np.int64)
        )
        self.held_out: list = []  # dynamic tiles: (deposits, idx, rect) traced here ...
        self.held_in: list = []  # ... and received, for tiles of nodes not known yet
        # pass 1 routes a deposit to at most 5 tiles (its pixel's and the 4 sides')
        self.held_bound = 5 * len(self.samples[0]) * int(np.prod(spec.image.size))
        self.held_count = 0
        for t in np.flatnonzero(self.rect_owner == node).tolist():
            self._add_film(t)

    def _add_film(self, tile: int) -> AdaptiveFilm:
        """Books for an own rectangle (or a dealt tile) of the adaptive render."""
        image = self.spec.image
        film = AdaptiveFilm(
            self.spec.camera, image.spp, self.part.rects[tile], *image.size, image.seed
        )
        self.film_at[tile] = len(self.films)
        self.films.append(film)
        return film

    def dealt(self, tile: int) -> bool:
        """Whether `tile` has its books here already (a tile is dealt once)."""
        return bool(self.film_at[tile] >= 0)

    def deal(self, tile: int):
        """Books for a tile the host dealt here, and its pass-1 batches."""
        w, h = self.spec.image.size
        return self._add_film(tile).pass1(self.view, w, h)

    def primaries(self, state: State) -> Primaries:
        """Pass 1 (corner rays) in TRACE, pass 2 (the rest, where the corners differ) in
        REFINE, none in other states; in chunks neighbours may steal when the render
        steals."""
        w, h = self.spec.image.size
        if state not in (State.TRACE, State.REFINE):
            return Primaries()
        if self.spec.steals:
            return self._chunks(state == State.REFINE)
        return Primaries(
            batch
            for f in self.films
            for batch in (f.pass1 if state == State.TRACE else f.pass2)(self.view, w, h)
        )

    def _chunks(self, refine: bool) -> ChunkFeed:
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
        image, (w, h) = self.spec.image, self.spec.image.size
        samples = self.samples[1 if refine else 0]
        pixels = np.concatenate([rect_pixels(c, w) for c in chunks])
        for part in split(pixels, len(samples)):
            yield camera_rays(
                self.spec.camera, image.spp, self.view, w, h, part, samples, image.seed
            )[0]

    def learn_owners(self, owners: np.ndarray) -> None:
        """Every tile's node, from the host's last TILES: checked against the tiles dealt
        here (all came before, on the same link)."""
        n, nodes = len(self.part.rects), self.part.nodes
        if len(owners) != n or (n and (owners.min() < 0 or owners.max() >= nodes)):
            raise ValueError(
                f"TILES.owners must give each of the {n} tiles a node of the "
                f"{nodes}, got {len(owners)} entries"
            )
        if not np.array_equal(owners == self.node, self.film_at >= 0):
            raise ValueError(f"TILES.owners disagrees with the tiles dealt to node {self.node}")
        self.rect_owner = owners.astype(np.int64)

    def routes(self, deposits: np.ndarray) -> dict[int, np.ndarray]:
        """Deposits by the node owning each deposit's pixel (and pass-1 ones to the owners
        of its side neighbours); under dynamic tiles all to this node, whose `keep` routes
        them once the tiles' nodes are known."""
        if self.feed is not None:
            return {self.node: deposits}
        idx, rect = self._routes(deposits)
        return _once_per_node(deposits, idx, self.rect_owner[rect])

    def keep(self, deposits: np.ndarray, traced_here: bool = False) -> dict[int, np.ndarray]:
        """Deposits routed to this node: into the film of each own rectangle that holds
        their pixel, or has it in its halo. Under dynamic tiles a batch traced here comes
        whole (`routes`, on a pool thread, cannot know which tiles are dealt here by the
        time it is kept): what it holds for other tiles goes on to their nodes, returned by
        node, once the host has said which those are (`learn_owners`); a received deposit
        for a tile not known to be this node's waits for that too. Returns deposits to send
        on, by node."""
        idx, rect = self._routes(deposits)
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
        return self.release()

    def _add(self, deposits: np.ndarray, idx: np.ndarray, film: np.ndarray) -> None:
        for i in np.unique(film).tolist():
            mine = idx[film == i]
            self.films[i].add(deposits["pixel"][mine], deposits["rgb"][mine])

    def release(self) -> dict[int, np.ndarray]:
        """Once every tile's node is known: held deposits kept for this node's tiles (tiles
        dealt here after they were traced), the rest of those traced here sent on, each to
        a node once however many of its tiles they touch (a received one for another node's
        tile came to this node for a tile of its own; its tracer sent it there too)."""
        if self.feed is None or self.feed.open or not (self.held_out or self.held_in):
            return {}  # closed with every tile's node learnt (`learn_owners`)
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

    def _routes(self, deposits):
        """(deposit index, rectangle) pairs of `adaptive.deposit_routes` inside the image."""
        camera, image, (w, h) = self.spec.camera, self.spec.image, self.spec.image.size
        idx, rect = deposit_routes(
            deposits["pixel"], camera.per_pixel(image.spp), self.samples[0], w, h, self.every_rect
        )
        return idx[rect >= 0], rect[rect >= 0]

    def finished_pixels(self):
        """Once every deposit is in: DEPOSIT batches of this node's finished pixels for the
        host."""
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
    return _group(taken(deposits, keep % len(deposits)), keep // len(deposits))


def _group(records: np.ndarray, dest: np.ndarray) -> dict[int, np.ndarray]:
    """Records grouped by destination node (one sort, no loop per record)."""
    if len(records) == 0:
        return {}
    order = np.argsort(dest, kind="stable")
    nodes, starts = np.unique(dest[order], return_index=True)
    groups = np.split(taken(records, order), starts[1:])
    pairs = zip(nodes.tolist(), groups, strict=True)
    return {n: np.ascontiguousarray(g) for n, g in pairs}
