"""Where a node's primary rays come from in a state of the render: batches made one at a time.

`Primaries` is a plain sequence of batches; `ChunkFeed` holds chunks of the node's rectangle,
traced from the front and stolen from the back (DESIGN.md 6); `TileFeed` holds the tiles the
host deals under dynamic image space. The Scheduler pops batches from whichever the node set
up for the state.
"""

from collections import deque

import numpy as np

from protocols.topology import Torus


class Primaries:
    """Batches of primary rays made one at a time (memory stays bounded at any number of
    rays per pixel), with a look ahead so the scheduler can tell whether any are left."""

    label = -1  # the tile of the batch `pop` returned last (TileFeed; -1: none)

    def __init__(self, batches=()):
        self.batches, self.next = iter(batches), None
        self._advance()

    def _advance(self) -> None:
        self.next = next(self.batches, None)
        while self.next is not None and len(self.next) == 0:
            self.next = next(self.batches, None)

    def __bool__(self) -> bool:
        return self.next is not None

    def pop(self) -> np.ndarray:
        rays = self.next
        self._advance()
        return rays

    @property
    def waiting(self) -> bool:
        """More batches may still come (a tile feed the host has not closed)."""
        return False


def stealable_last(chunks: list, usable, node: int, plan) -> list:
    """`chunks` with those fewest of `node`'s torus links could take (`usable(thief,
    chunks)`; None: any chunk moves) first and those most could last (stable, so each kind
    keeps its order): thieves take from the back, and a node left at the end with chunks
    only one link holds the engine for finished last while the others idled (tetra 3x3,
    simulated at 137 spp: the centre node kept 10 of 11 unstarted chunks from its asking
    links; parallel efficiency 0.948 -> 0.972)."""
    if usable is None or not chunks:
        return chunks
    links = set(Torus(plan.rows, plan.cols).links(node)) - {node}
    reach = sum(usable(m, chunks).astype(np.int64) for m in links)
    return [chunks[i] for i in np.argsort(reach, kind="stable").tolist()]


class ChunkFeed(Primaries):
    """Object space with stealing: chunks (x0, x1, y0, y1) of this node's rectangle in spiral
    order, centre first, traced from the front; `take` hands unstarted chunks from the back
    (the outer end of the spiral) to a neighbour that has run out, and `add` takes chunks a
    neighbour gave. `batches(chunks)` makes the primary rays of a list of chunks, one batch
    at a time: one chunk, or with `rays(chunk)` (how many it makes) as many from the front
    as make at most `budget` rays (adaptive sampling's refined runs make a few hundred each,
    and every batch costs a kernel call and its messages). A chunk is started (and can no
    longer be given) once its group's first batch is looked ahead. `usable(thief, chunks)`
    (None: all) says which chunks a thief can trace itself."""

    def __init__(self, chunks, batches, on_give=None, usable=None, rays=None, budget: int = 0):
        self.chunks, self.make, self.on_give = deque(chunks), batches, on_give
        self.usable, self.rays, self.budget = usable, rays, budget
        self.current = iter(())
        super().__init__()

    def _advance(self) -> None:
        while True:
            self.next = next(self.current, None)
            if self.next is not None and len(self.next):
                return
            if self.next is None:
                if not self.chunks:
                    return
                self.current = iter(self.make(self._group()))

    def _group(self) -> list:
        """The next chunks to start: one, or as many as fit the ray budget."""
        group = [self.chunks.popleft()]
        if self.rays is not None:
            n = self.rays(group[0])
            while self.chunks and n + (more := self.rays(self.chunks[0])) <= self.budget:
                group.append(self.chunks.popleft())
                n += more
        return group

    def take(self, thief: int = -1) -> list:
        """Half of the unstarted chunks `thief` can use, from the outer end (none when one
        or none is left: this node will start it sooner than a message could carry it);
        `on_give(chunk)` is told of each (adaptive sampling keeps its books as it gives)."""
        chunks = list(self.chunks)
        if self.usable is None or not chunks:
            ok = np.arange(len(chunks))
        else:
            ok = np.flatnonzero(self.usable(thief, chunks))
        picked = ok[len(ok) - len(ok) // 2 :][::-1].tolist()  # outermost first
        given = [chunks[i] for i in picked]
        if given:
            gone = set(picked)
            self.chunks = deque(c for i, c in enumerate(chunks) if i not in gone)
        if self.on_give is not None:
            for chunk in given:
                self.on_give(chunk)
        return given

    def add(self, chunks, giver: int = -1) -> None:
        """Chunks a neighbour (`giver`) gave, traced after this node's own."""
        self.chunks.extend(tuple(c) for c in chunks)
        if self.next is None:
            self._advance()


class TileFeed(Primaries):
    """Primary batches of tiles the host deals while the frame is traced (dynamic image
    space): tiles are added as they arrive, `finished` lists the tiles whose last batch has
    been handed out (the node reports them, and gets new ones), and until the host closes
    the feed an empty one means "wait", not "done"."""

    def __init__(self):
        self.tiles: deque = deque()  # (tile index, batches)
        self.finished: list[int] = []
        self.open = True
        self.next_tile = -1  # the tile of the batch looked ahead
        super().__init__()

    def pop(self) -> np.ndarray:
        self.label = self.next_tile
        return super().pop()

    def add(self, tile: int, batches) -> None:
        self.tiles.append((tile, iter(batches)))
        if self.next is None:
            self._advance()

    def close(self) -> None:
        self.open = False

    def _advance(self) -> None:
        self.next = None
        while self.next is None and self.tiles:
            tile, batches = self.tiles[0]
            self.next, self.next_tile = next(batches, None), tile
            while self.next is not None and len(self.next) == 0:
                self.next = next(batches, None)
            if self.next is None:
                self.tiles.popleft()
                self.finished.append(tile)

    @property
    def waiting(self) -> bool:
        return self.open
