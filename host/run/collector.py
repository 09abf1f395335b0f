"""The render loop on the host: pixels, progress, tiles and statistics from every node as they
come, and the watchdog that names a node that falls silent or a mesh that stops working.
"""

import asyncio
import time

from host.run.errors import MeshError, NodeLost
from host.run.framebuffer import Framebuffer
from meshnode.mesh.dealer import TileDealer
from meshnode.transport.link import Link, LinkClosed
from protocols.messages import Kind, make


def tiles_message(dealer: TileDealer, tiles: list[int], last: bool) -> dict:
    """TILES for a node: under adaptive sampling its last carries every tile's node."""
    return make(Kind.TILES, tiles=tiles, last=last, owners=dealer.owners_with(last))


class Collector:
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
        # dynamic image space: tiles whose every deposit has come, and their ray counts
        self.tiles_traced: list[int] = []
        self.traced_counts: dict[str, int] = {}

    def name(self, n: int) -> str:
        return self.names[n]

    async def run(self, links: list[Link]) -> None:
        """Collect from every node until each has sent its STATS; the first failure (a
        node's or the watchdog's) ends the render and cancels the rest."""
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
        """Node n's messages, each acted on as it comes, until its STATS."""
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
                if self.watch is not None and len(d):  # deposits: tracing has begun
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
            elif kind is Kind.TILES_TRACED and self.dealer is not None:
                self.traced_tiles(n, f)
            elif kind is Kind.STATS:
                self.stats[n] = f["stats"]
            elif kind is Kind.ERROR:
                raise MeshError(f"{self.name(n)} failed: {f['reason']}")

    def traced_tiles(self, n: int, f: dict) -> None:
        """Tiles node n traced whole: each must be one dealt to it, reported once."""
        owner = self.dealer.owner
        if f["node"] != n or any(not t < len(owner) or owner[t] != n for t in f["tiles"]):
            raise MeshError(f"{self.name(n)} reports traced tiles that were not dealt to it")
        self.tiles_traced.extend(f["tiles"])
        for k, v in f["counts"].items():
            self.traced_counts[k] = self.traced_counts.get(k, 0) + v

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
