"""One render on one node, from CONFIG to DONE: the application layer of the node service.

The session reads its configuration and objects, builds its NodeCore off the event loop, links
to its neighbours, and then lets the Scheduler decide: it traces the batches it is told to on
the service's thread pool (kernels release the GIL, so links keep flowing), posts rays and
deposits toward the nodes that take them, and passes termination waves on; what neighbours send
is checked first (`inbound`). Every send goes through a per-link Outbox; new primary rays start
only while the outboxes are below a high-water mark, which bounds the rays in flight (and so
the memory).
"""

import asyncio
import logging
import os
import time

import numpy as np

from meshnode.engine.kernelcache import compile_clock
from meshnode.mesh.driver import Driver
from meshnode.mesh.node import NodeCore
from meshnode.mesh.scheduler import Scheduler
from meshnode.mesh.stats import NodeStats
from meshnode.mesh.steps import Trace
from meshnode.service.config import Config, Objects
from meshnode.service.depositpackets import DepositPackets
from meshnode.service.inbound import (
    check_pixels,
    check_rays,
    checked_cell,
    checked_chunks,
    checked_echo,
    checked_parts,
    checked_probe,
)
from meshnode.service.reports import progress_message, stats_message
from meshnode.service.sends import Sends
from meshnode.transport.link import Link, LinkClosed, Outbox
from protocols.errors import BadFrame, ProtocolError, describe
from protocols.messages import Kind, make
from protocols.records import copied
from protocols.state import State, states_of
from protocols.topology import Router

log = logging.getLogger("meshnode")
OUTBOX_HIGH = 8 * 1024 * 1024  # bytes queued on all links before primaries pause
HEARTBEAT = 1.0  # seconds between a node's signs of life to the host
# seconds at least between PROGRESS messages of traced rays: as often as a live view draws
# (host.live's interval). One a batch took 3.6% of a tetra 3x3 node's CPU; one in 50 ms was
# still 60-75 a node and render of 3 s on balls 3x3, a third of the messages it sent.
PROGRESS_EVERY = 0.25
# Held deposits go to the host each time the node idles (True: as before `DepositPackets`;
# `python -m bench.passing` compares both)
IDLE_DEPOSITS = False
# A passed batch of fewer rays is traced on the event loop's thread: a pool thread's hand-off
# and wake-up back cost more than its tracing (0: every batch on the pool)
INLINE_RAYS = 64


class Session(Sends, Driver):
    """One render on this node, driving its Scheduler over the links (`Driver`); `service`
    gives the thread pool, the cluster id, the number of tracing threads and the links
    neighbours opened to this node."""

    def __init__(self, service, host: Link, config: Config):
        self.service, self.host, self.config = service, host, config
        node = config.node
        threads = min(service.threads, config.render.engine.threads or service.threads)
        sched = Scheduler(
            node,
            config.torus.parent(node),
            config.torus.children(node),
            threads,
            service.incoming_high,
            neighbours=config.torus.links(node),
            steal=config.render.steals,
            states=states_of(config.render.adaptive),
        )
        super().__init__(node, sched)
        self.router = Router(config.torus, node)
        self.stats = NodeStats(self.node)
        self.objects = Objects([self.node, *config.copies], service.object_share)
        self.early_tiles: list[dict] = []  # TILES that came before the engine was built
        self.outboxes: dict[int, Outbox] = {}
        self.wake = asyncio.Event()
        self.drained = asyncio.Event()
        self.host_out = Outbox(host, self.fail, self.wake)
        self.packets = DepositPackets(self.to_host)  # deposits for the host
        self.error: Exception | None = None
        self.ready = False  # engine built and every neighbour linked
        self.setup = "objects"  # the setup step PROGRESS reports (SETUP_STEPS)
        self.created = time.perf_counter()
        self.setup_seconds = 0.0
        self.compile_seconds = 0.0  # of the setup, numba compiling (a first run)
        self.frame_cpu_start = time.process_time()  # moved to the frame's start once built
        self.frame_sys_start = os.times().system
        self.frame_loop_start = time.thread_time()
        self.progress_rays, self.progress_due = 0, 0.0  # rays not yet told; when to tell
        self.progress_sent = 0
        self.tasks: set[asyncio.Task] = set()
        self.spawn(self.heartbeat())

    def spawn(self, coro) -> asyncio.Task:
        """A task of this session: tracked, so `close` can cancel and await it."""
        task = asyncio.create_task(coro)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)
        return task

    async def heartbeat(self) -> None:
        """Tell the host every second that this node lives (a PROGRESS of no rays, saying
        whether it is ready), so it can name a node that stops, hangs or is cut off within
        seconds, and tell a node still building from a stuck one."""
        while True:
            await asyncio.sleep(HEARTBEAT)
            self.progress(0)

    def progress(self, rays: int) -> None:
        """Primary rays just traced, to the host with what its live view shows of this node
        (`reports.progress_message`), at most once in PROGRESS_EVERY seconds; rays not yet
        told go with the next. A call of no rays (the heartbeat, ready, the end of the frame)
        tells at once, and does not put the next batch's off."""
        self.progress_rays += rays
        now = time.monotonic()
        if rays:
            if now < self.progress_due:
                return
            self.progress_due = now + PROGRESS_EVERY
        told, self.progress_rays = self.progress_rays, 0
        self.progress_sent += 1
        self.host_out.post(progress_message(self, told))

    # ------------------------------------------------------------------ setup
    async def build(self) -> None:
        """Build the engine off the loop, link to the neighbours, then start working."""
        try:
            loop = asyncio.get_running_loop()
            c = self.config
            self.setup = "engine"
            scene = self.objects.scene(self.node, c.scene)
            copies = {m: self.objects.scene(m, c.scene) for m in c.copies}
            with compile_clock() as clock:  # a first run's compiling, told apart in the stats
                self.core = await loop.run_in_executor(
                    self.service.pool,
                    lambda: NodeCore(
                        self.node,
                        scene,
                        c.render,
                        c.partition,
                        engines=self.service.engines,
                        copies=copies,
                    ),
                )
                variant = self.core.engine.variant()
                self.setup = "load" if self.core.engine.compiled else "compile"
                if self.setup == "compile":  # the live view shows the step meanwhile
                    log.info("node %d: compiling %s, first run only", self.node, variant)
                await loop.run_in_executor(self.service.pool, self.core.warmup)
            self.compile_seconds = clock.seconds
            if clock.seconds:
                log.info("node %d: compiled %s in %.1f s", self.node, variant, clock.seconds)
            for f in self.early_tiles:  # nothing is traced yet, so no deposit is to send
                self.core.add_tiles(f["tiles"], f["last"], f["owners"])
            self.setup = "links"
            for m in c.torus.links(self.node):
                if self.node < m:  # the lower index dials, the higher accepts
                    self.attach(m, await self.service.dial(m, c.neighbours[str(m)]))
            await self.service.wait_links(self)
            self.setup_seconds = time.perf_counter() - self.created
            self.ready, self.setup = True, "ready"
            self.progress(0)
            self.frame_cpu_start = time.process_time()
            self.frame_sys_start = os.times().system
            self.frame_loop_start = time.thread_time()  # this, the event loop's thread
            self.spawn(self.work())
        except Exception as e:  # noqa: BLE001 - whatever broke, the host must hear of it
            self.fail(e)

    def attach(self, m: int, link: Link) -> None:
        self.outboxes[m] = Outbox(link, self.fail, self.wake)
        self.spawn(self.read(m, link))

    # ------------------------------------------------------------------ messages
    def fail(self, error: Exception) -> None:
        """Report the first failure to the host (named, never empty) and stop working."""
        if self.error is None:
            self.error = error
            log.error("node %d: %s", self.node, describe(error))
            self.host_out.post(make(Kind.ERROR, reason=f"node {self.node}: {describe(error)}"))
            self.wake.set()

    async def read(self, m: int, link: Link) -> None:
        try:
            while True:
                kind, f = await link.recv()
                if kind in (Kind.RAYS, Kind.RAYS_SET):
                    on = self.on_rays if kind is Kind.RAYS else self.on_rays_set
                    if on(m, f):
                        # Stop reading: TCP pushes back on the sender, whose work loop goes
                        # on (its sends are queued), so this cannot deadlock.
                        self.drained.clear()
                        self.wake.set()
                        await self.drained.wait()
                elif kind is Kind.PIXELS:
                    self.on_pixels(f)
                elif kind is Kind.STATE:
                    self.sched.probe_in(checked_probe(f, m, self.config.torus.parent(self.node)))
                elif kind is Kind.ECHO:
                    self.sched.echo_in(m, checked_echo(f))
                elif kind is Kind.STEAL:
                    self.sched.steal_request(m)
                elif kind is Kind.GIVE:
                    self.sched.given(m, checked_chunks(f["chunks"], self.config.render))
                else:
                    raise BadFrame(f"unexpected {kind.name} from a neighbour")
                self.wake.set()
        except LinkClosed as e:
            if self.sched.state != State.DONE:
                self.fail(e)
        except ProtocolError as e:  # a bad message: named, no traceback
            self.fail(LinkClosed(f"node {m}", describe(e)))
        except Exception as e:  # noqa: BLE001 - a bad message must not silently stop reading
            log.exception("node %d: reading from node %d failed", self.node, m)
            self.fail(LinkClosed(f"node {m}", describe(e)))

    def on_rays(self, m: int, f: dict) -> bool:
        """Queue rays for this node, or pass them on toward theirs; True when the scheduler
        says to stop reading (the one place that decides: `Scheduler.rays_in`)."""
        check_rays(f, self.config.torus.size)
        self.stats.rays_in[m] += len(f["rays"])
        # the frame's records as they arrived: aligned, writable, this message's own
        # (`protocols.framing`), so taken on without another copy
        if f["dest"] == self.node:
            taker = checked_cell(f, self.node, self.config.render.plan.held(self.node))
            return self.sched.rays_in(f["rays"], taker=taker)
        self.sched.message_in()
        self.pass_on([(f["dest"], f["rays"], f["cell"])])
        return False

    def on_rays_set(self, m: int, f: dict) -> bool:
        """RAYS_SET: several RAYS in one frame (`post_rays_set`), each part queued here or
        passed on toward its node as RAYS are; the frame counted as one message."""
        parts = checked_parts(f, self.config.torus.size)
        rays, held = f["rays"], self.config.render.plan.held(self.node)
        mine = [
            (checked_cell({"cell": c}, self.node, held), rays[lo:hi])
            for d, c, lo, hi in parts
            if d == self.node
        ]  # every part checked before any is taken
        self.stats.rays_in[m] += len(rays)
        self.sched.message_in()
        stop = False
        for taker, part in mine:
            stop = self.sched.rays_in(part, message=False, taker=taker) or stop
        onward = [(d, rays[lo:hi], c) for d, c, lo, hi in parts if d != self.node]
        if onward:
            self.pass_on(onward)
        return stop

    def on_pixels(self, f: dict) -> None:
        check_pixels(f, self.config.torus.size)
        self.sched.message_in()
        deposits = copied(f["deposits"])
        if f["dest"] != self.node:
            self.post_data(f["dest"], Kind.PIXELS, deposits)
        elif self.core.keeps_pixels:
            self.send_pixels(self.core.keep(deposits))
        else:
            self.to_host(deposits)

    def on_tiles(self, f: dict) -> None:
        """Tiles the host dealt (dynamic image space); kept until the engine is built."""
        if not self.config.render.plan.dynamic:
            raise BadFrame("TILES for a render without dynamic tiles")
        if self.core is None:
            self.early_tiles.append(f)
            return
        self.send_pixels(self.core.add_tiles(f["tiles"], f["last"], f["owners"]))
        self.wake.set()

    # ------------------------------------------------------------------ work
    async def work(self) -> None:
        """Do what the scheduler says until the render ends or fails; any failure is
        reported to the host, never swallowed."""
        try:
            while self.error is None:
                self.wake.clear()
                room = self.queued_bytes() < OUTBOX_HIGH
                while (step := self.sched.next(room)) is not None:
                    self.act(step)
                    room = self.queued_bytes() < OUTBOX_HIGH
                if self.sched.may_read:
                    self.drained.set()
                await self.wake.wait()
        except Exception as e:  # noqa: BLE001 - whatever broke, the host must hear of it
            log.exception("node %d: work loop failed", self.node)
            self.fail(e)

    def flush(self) -> None:
        """Idle, or a dynamic tile traced whole: the tiles traced whole go to the host after
        every deposit of theirs on the same link, so the host may keep them if another node
        is lost; otherwise held deposits wait for their packet (`DepositPackets`)."""
        tiles_done = self.traced.done and not self.core.keeps_pixels
        if tiles_done or IDLE_DEPOSITS:
            self.packets.send()
        if tiles_done:
            tiles, counts = self.traced.take()
            self.host_out.post(make(Kind.TILES_TRACED, node=self.node, tiles=tiles, counts=counts))

    def queued_bytes(self) -> int:
        return sum(o.bytes for o in self.outboxes.values()) + self.host_out.bytes

    def start(self, step: Trace) -> None:
        """Trace a batch on a pool thread, the work loop woken when it is done; a passed
        batch of fewer than INLINE_RAYS rays on this thread, at once."""
        if self.sched.in_flight == 1:  # the first batch in flight: the node turns busy
            self.stats.turn_busy()
        if not step.primary and len(step.rays) < INLINE_RAYS:
            self.stats.inline += 1
            try:
                batch, error = self.core.trace(step.rays, False, step.taker), None
                self.stats.inline_cpu += batch.counts.get("batch_cpu_seconds", 0.0)
            except Exception as e:  # noqa: BLE001 - the host must hear of it
                batch, error = None, e
            self.traced_batch(step, batch, error)
        else:
            self.spawn(self.trace(step))

    async def trace(self, step: Trace) -> None:
        loop = asyncio.get_running_loop()
        try:
            batch, error = (
                await loop.run_in_executor(
                    self.service.pool, self.core.trace, step.rays, step.primary, step.taker
                ),
                None,
            )
        except Exception as e:  # noqa: BLE001 - the host must hear of it
            batch, error = None, e
        self.traced_batch(step, batch, error)

    def traced_batch(self, step: Trace, batch, error: Exception | None) -> None:
        """A batch traced (or its failure, `error`): its output delivered, the scheduler
        told, the work loop woken."""
        rays, primary = step.rays, step.primary
        try:
            if error is not None:
                raise error
            self.stats.traced(batch.counts, self.core.stood_for(rays) if primary else 0)
            self.deliver(batch, step)
            if primary:
                self.progress(self.core.stood_for(rays))
        except Exception as e:  # noqa: BLE001 - the host must hear of it
            log.exception("node %d: tracing a batch failed", self.node)
            self.fail(e)
        finally:
            self.sched.batch_done()
            if self.sched.in_flight == 0:
                self.stats.turn_idle()
            self.wake.set()

    def for_host(self, deposits: np.ndarray) -> None:
        """Held for the host's next packet (`DepositPackets`)."""
        self.packets.add(deposits)

    def finished(self, batches) -> None:
        """Adaptive sampling's finished pixels, straight to the host."""
        for d in batches:
            self.host_out.post(make(Kind.PIXELS, deposits=d, dest=-1), d.nbytes)
        self.stats.counts["refined_pixels"] = self.core.refined_pixels

    def report(self) -> None:
        """The deposits and rays not yet told, then the node's STATS to the host
        (`reports.stats_message`)."""
        self.packets.send()
        self.progress(0)
        self.host_out.post(stats_message(self))

    async def close(self) -> None:
        """Cancel and await every task of this render, then drop its neighbour links: the
        render is over (every node sent its STATS) or given up, so nothing queued on them
        matters, and a neighbour that stopped reading must not hold this node up."""
        self.packets.close()
        tasks = list(self.tasks)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for o in self.outboxes.values():
            o.task.cancel()
        await asyncio.gather(*(o.task for o in self.outboxes.values()), return_exceptions=True)
        for o in self.outboxes.values():
            o.link.abort()
        self.host_out.task.cancel()
        await asyncio.gather(self.host_out.task, return_exceptions=True)
