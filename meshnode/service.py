"""`meshnode serve`: the node's asyncio service (DESIGN.md 5).

Accepts the host and its torus neighbours on one port. For each render: the host sends CONFIG
and the node's objects; the node builds its NodeCore, links to its neighbours and joins the
state packet's ring. Kernels run on a thread (they release the GIL) so links keep flowing.
Every send goes through a per-link outbox served by its own task, so a reader never blocks on
a full link; new primary rays are generated only while incoming rays are done and outboxes are
below their high-water mark, which bounds the rays in flight (and so the memory); readers stop
reading above a high-water mark of queued incoming rays and resume below a low one.
"""

import asyncio
import logging
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from meshnode.link import Link, LinkClosed
from meshnode.node import NodeCore
from meshnode.termination import Packet, State, Termination
from protocols.camera import CameraRays
from protocols.dtypes import DEPOSIT
from protocols.handshake import check_hello, hello
from protocols.messages import OBJECT_TABLES, Kind, make
from protocols.scene import SceneData, View
from protocols.topology import Router, Torus

log = logging.getLogger("meshnode")
OUTBOX_HIGH = 8 * 1024 * 1024  # bytes queued on all links before primaries pause
DEPOSIT_BATCH = 32768  # deposits per pixel packet
RAY_BATCH = 4096  # primary rays per traced batch
HEARTBEAT = 1.0  # seconds between a node's signs of life to the host
INCOMING_HIGH = 1_000_000  # queued incoming rays at which readers stop (~100 MB); resume at 1/4


class Outbox:
    """Messages waiting for one link, sent in order by one task; `sent` is set after every
    send, so a work loop paused on full outboxes wakes when they drain."""

    def __init__(self, link: Link, on_error, sent: asyncio.Event | None = None):
        self.link, self.queue, self.bytes = link, deque(), 0
        self.ready = asyncio.Event()
        self.sent = sent
        self.task = asyncio.create_task(self._run(on_error))

    def post(self, message: dict, size: int = 0, delay: float = 0.0) -> None:
        self.queue.append((message, size, delay))
        self.bytes += size
        self.ready.set()

    async def _run(self, on_error):
        try:
            while True:
                await self.ready.wait()
                self.ready.clear()
                while self.queue:
                    message, size, delay = self.queue.popleft()
                    if delay:
                        await asyncio.sleep(delay)  # an injected slow link (tests)
                    await self.link.send(message)
                    self.bytes -= size
                    if size and self.sent is not None:
                        self.sent.set()
        except LinkClosed as e:
            on_error(e)


class Primaries:
    """Batches of primary rays made one at a time (memory stays bounded at any number of
    rays per pixel), with a look ahead so the work loop can ask whether any are left."""

    def __init__(self, batches):
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


class Session:
    """One render on this node, from CONFIG to DONE."""

    def __init__(self, service: "NodeService", host: Link, config: dict):
        self.service, self.host = service, host
        self.node = config["node"]
        self.torus = Torus(config["rows"], config["cols"])
        self.router = Router(self.torus, self.node)
        self.config = config
        self.settings = config["settings"]
        self.tables: dict[str, list] = {}
        self.term = Termination(self.node)
        self.state = State.DOWNLOAD
        self.core: NodeCore | None = None
        self.outboxes: dict[int, Outbox] = {}
        self.wake = asyncio.Event()
        self.host_out = Outbox(host, self.fail, self.wake)
        self.incoming: deque = deque()
        self.primaries = Primaries(iter(()))
        self.deposits: list = []
        self.packet: Packet | None = None
        self.error: Exception | None = None
        self.counts: dict[str, int] = {"eye_rays": 0}
        self.rays_in: dict[int, int] = {}
        self.rays_out: dict[int, int] = {}
        self.pixel_packets = 0
        self.busy = 0.0  # wall seconds with at least one batch on a tracing thread
        self.busy_since = 0.0
        self.batches = 0  # batches traced
        self.cpu = 0.0  # CPU seconds of that thread
        self.started = time.perf_counter()
        self.tasks: list[asyncio.Task] = []
        self.tracing: set[asyncio.Task] = set()  # batches on the pool's threads right now
        self.done_passed = False
        self.delayed = 0
        self.incoming_rays = 0
        self.incoming_high = int(self.settings.get("incoming_high") or INCOMING_HIGH)
        self.drained = asyncio.Event()
        self.view: View | None = None
        self.tasks.append(asyncio.create_task(self.heartbeat()))

    async def heartbeat(self) -> None:
        """Tell the host every second that this node lives (a PROGRESS of no rays), so it can
        name a node that stops, hangs or is cut off within seconds."""
        while True:
            await asyncio.sleep(HEARTBEAT)
            self.host_out.post(make(Kind.PROGRESS, node=self.node, rays=0, work=self.batches))

    # ------------------------------------------------------------------ setup
    def add_objects(self, table: str, records: np.ndarray) -> None:
        self.tables.setdefault(table, []).append(np.array(records))

    def scene(self) -> SceneData:
        def table(name):
            parts = self.tables.get(name)
            dtype = OBJECT_TABLES[name]
            return np.concatenate(parts) if parts else np.zeros(0, dtype)

        s = self.settings
        view = View(**{k: tuple(v) if isinstance(v, list) else v for k, v in s["view"].items()})
        return SceneData(
            view=view, background=tuple(s["background"]), lights=table("lights"),
            materials=table("materials"), spheres=table("spheres"),
            triangles=table("triangles"), polygons=table("polygons"),
            vertices=table("vertices").reshape(-1, 3), cones=table("cones"),
        )  # fmt: skip

    async def build(self) -> None:
        """Build the engine off the loop, then link to the neighbours."""
        s = self.settings
        scene = self.scene()
        self.view = scene.view
        los, his = np.array(s["los"]), np.array(s["his"])
        box = (np.array(self.config["scene_box"][:3]), np.array(self.config["scene_box"][3:]))
        self.core = await asyncio.get_running_loop().run_in_executor(
            self.service.pool,
            lambda: NodeCore(self.node, scene, los, his, box, density=s["density"],
                             storage=s["storage"], max_depth=s["depth"]),  # fmt: skip
        )
        await asyncio.get_running_loop().run_in_executor(self.service.pool, self.core.warmup)
        camera = CameraRays.from_wire(s["camera"]) if s.get("camera") else None
        await asyncio.get_running_loop().run_in_executor(
            self.service.pool,
            lambda: self.core.use_camera(camera, s["width"], s["height"], s["rects"]),
        )
        for m in self.torus.links(self.node):
            if self.node < m:  # the lower index dials, the higher accepts
                link = await Link.connect(self.config["neighbours"][str(m)], f"node {m}")
                await link.send(hello(self.service.cluster, "node", self.node))
                check_hello((await link.recv_raw()), self.service.cluster)
                self.attach(m, link)
        await self.service.wait_links(self)
        if self.node == 0:
            self.packet = Packet.start(self.torus.size)
        self.tasks.append(asyncio.create_task(self.work()))
        self.wake.set()

    def attach(self, m: int, link: Link) -> None:
        self.outboxes[m] = Outbox(link, self.fail, self.wake)
        self.tasks.append(asyncio.create_task(self.read(m, link)))

    # ------------------------------------------------------------------ messages
    def fail(self, error: Exception) -> None:
        if self.error is None:
            self.error = error
            log.error("node %d: %s", self.node, error)
            self.host_out.post(make(Kind.ERROR, reason=f"node {self.node}: {error}"))
            self.wake.set()

    def post_data(self, dest: int, kind: Kind, records: np.ndarray) -> None:
        """A RAYS or PIXELS message toward node `dest`, counted as sent."""
        hop = self.router.next_hop(dest)
        if kind is Kind.RAYS:
            message = make(Kind.RAYS, rays=records, dest=dest)
            self.rays_out[hop] = self.rays_out.get(hop, 0) + len(records)
        else:
            message = make(Kind.PIXELS, deposits=records, dest=dest)
        self.term.on_sent()
        self.outboxes[hop].post(message, records.nbytes, self._delay(hop, kind))

    def _delay(self, hop: int, kind: Kind) -> float:
        """Seconds to hold this message back: settings may name one link (src, dst, seconds,
        count) whose first `count` ray messages are delayed, to test termination."""
        spec = self.settings.get("link_delay")
        if not spec or kind is not Kind.RAYS or (self.node, hop) != (spec[0], spec[1]):
            return 0.0
        if self.delayed >= spec[3]:
            return 0.0
        self.delayed += 1
        return float(spec[2])

    def send_pixels(self, deposits: np.ndarray) -> None:
        """Deposits toward node 0, which hands them to the host."""
        self.pixel_packets += 1
        if self.node == 0:
            self.host_out.post(make(Kind.PIXELS, deposits=deposits, dest=-1), deposits.nbytes)
        else:
            self.post_data(0, Kind.PIXELS, deposits)

    def keep_pixels(self, deposits: np.ndarray) -> None:
        """Adaptive sampling: deposits go to the node owning their pixel, which keeps them."""
        for dest, group in self.core.pixel_routes(deposits).items():
            if dest == self.node:
                self.core.film.add(group["pixel"], group["rgb"])
            else:
                self.pixel_packets += 1
                self.post_data(dest, Kind.PIXELS, group)

    async def read(self, m: int, link: Link) -> None:
        try:
            while True:
                kind, f = await link.recv()
                if kind is Kind.RAYS:
                    self.term.on_received()
                    self.rays_in[m] = self.rays_in.get(m, 0) + len(f["rays"])
                    if f["dest"] == self.node:
                        self.incoming.append(np.array(f["rays"]))
                        self.incoming_rays += len(f["rays"])
                        if self.incoming_rays > self.incoming_high:
                            # Stop reading: TCP pushes back on the sender, whose work loop
                            # goes on (its sends are queued), so this cannot deadlock.
                            self.wake.set()
                            self.drained.clear()
                            await self.drained.wait()
                    else:
                        self.post_data(f["dest"], Kind.RAYS, np.array(f["rays"]))
                elif kind is Kind.PIXELS:
                    self.term.on_received()
                    deposits = np.array(f["deposits"])
                    if f["dest"] != self.node:
                        self.post_data(f["dest"], Kind.PIXELS, deposits)
                    elif self.core.film is not None:
                        self.core.film.add(deposits["pixel"], deposits["rgb"])
                    else:
                        self.send_pixels(deposits)
                elif kind is Kind.STATE:
                    if f["dest"] == self.node:
                        sent, received = np.array(f["sent"]), np.array(f["received"])
                        self.packet = Packet(f["state"], f["last_busy"], f["round"], sent, received)
                    else:
                        self.outboxes[self.router.next_hop(f["dest"])].post(make(Kind.STATE, **f))
                else:
                    raise LinkClosed(f"node {m}", f"unexpected {kind.name} from a neighbour")
                self.wake.set()
        except LinkClosed as e:
            if self.state != State.DONE:
                self.fail(e)
        except Exception as e:  # noqa: BLE001 - a bad message must not silently stop reading
            log.exception("node %d: reading from node %d failed", self.node, m)
            self.fail(e)

    # ------------------------------------------------------------------ work
    def enter(self, state: int) -> None:
        """Act on a state the packet brought."""
        self.state = State(state)
        s = self.settings
        if self.state in (State.TRACE, State.REFINE) and self.core.camera is not None:
            second = self.state == State.REFINE
            self.primaries = Primaries(self.core.camera_pass(self.view, s["width"], s["height"],
                                                             second))  # fmt: skip
        elif self.state == State.TRACE:
            rays = self.core.primary(self.view, s["width"], s["height"], s["corners"], s["spp"],
                                     s["seed"], tuple(s["rects"][self.node]))  # fmt: skip
            batches = (rays[i : i + RAY_BATCH] for i in range(0, len(rays), RAY_BATCH))
            self.primaries = Primaries(batches)
        elif self.state == State.FLUSH and self.core.film is not None:
            pixels, rgb = self.core.film.finish()
            for i in range(0, len(pixels), DEPOSIT_BATCH):
                d = np.zeros(len(pixels[i : i + DEPOSIT_BATCH]), DEPOSIT)
                d["pixel"], d["rgb"] = pixels[i : i + DEPOSIT_BATCH], rgb[i : i + DEPOSIT_BATCH]
                self.host_out.post(make(Kind.PIXELS, deposits=d, dest=-1), d.nbytes)
            self.counts["refined_pixels"] = int(self.core.film.refined.sum())
        elif self.state == State.DONE:
            self.host_out.post(make(Kind.STATS, node=self.node, stats=self.statistics()))

    def flush(self) -> None:
        if self.deposits:
            allp = np.concatenate(self.deposits)
            self.deposits = []
            for i in range(0, len(allp), DEPOSIT_BATCH):
                self.send_pixels(allp[i : i + DEPOSIT_BATCH])

    async def trace(self, rays: np.ndarray) -> None:
        batch = await asyncio.get_running_loop().run_in_executor(
            self.service.pool, self.core.trace, rays
        )
        self.batches += 1
        self.term.on_work()
        self.cpu += batch.counts.pop("cpu_seconds")
        for k, v in batch.counts.items():
            self.counts[k] = self.counts.get(k, 0) + v
        if len(batch.deposits) and self.core.film is not None:
            self.keep_pixels(batch.deposits)
        elif len(batch.deposits):
            self.deposits.append(batch.deposits)
            if sum(len(d) for d in self.deposits) >= DEPOSIT_BATCH:
                self.flush()
        for dest, passed in batch.outgoing.items():
            if dest == self.node:
                self.incoming.append(passed)
                self.incoming_rays += len(passed)
            else:
                self.post_data(dest, Kind.RAYS, passed)

    def queued_bytes(self) -> int:
        return sum(o.bytes for o in self.outboxes.values()) + self.host_out.bytes

    async def work(self) -> None:
        """Run the work loop; any failure is reported to the host, never swallowed."""
        try:
            await self._work()
        except Exception as e:  # noqa: BLE001 - whatever broke, the host must hear of it
            log.exception("node %d: work loop failed", self.node)
            self.fail(e)

    async def _work(self) -> None:
        """Incoming rays first, then primaries, one batch per tracing thread at a time; pass
        the packet on whenever idle (nothing queued, nothing being traced)."""
        while self.error is None:
            self.wake.clear()
            if self.packet is not None and self.packet.state > self.state:
                self.enter(self.packet.state)  # the packet brings the next state
            room = len(self.tracing) < self.service.threads
            if self.incoming and room:
                rays = self.incoming.popleft()
                self.incoming_rays -= len(rays)
                if self.incoming_rays <= self.incoming_high // 4:
                    self.drained.set()
                self.start(rays, primary=False)
                continue
            tracing = self.state in (State.TRACE, State.REFINE) and self.primaries
            if tracing and room and self.queued_bytes() < OUTBOX_HIGH:
                rays = self.primaries.pop()
                self.counts["eye_rays"] = self.counts.get("eye_rays", 0) + len(rays)
                self.start(rays, primary=True)
                continue
            if not self.tracing:
                self.flush()
                if self.packet is not None and not tracing and not self.incoming:
                    self.pass_packet()
                    continue
            await self.wake.wait()

    def start(self, rays: np.ndarray, primary: bool) -> None:
        """Trace a batch on a pool thread; the work loop wakes when it is done."""

        async def run():
            try:
                await self.trace(rays)
                if primary:
                    self.host_out.post(make(Kind.PROGRESS, node=self.node, rays=len(rays),
                                            work=self.batches))  # fmt: skip
            except Exception as e:  # noqa: BLE001 - the host must hear of it
                log.exception("node %d: tracing a batch failed", self.node)
                self.fail(e)
            finally:
                self.tracing.discard(task)
                if not self.tracing:
                    self.busy += time.perf_counter() - self.busy_since
                self.wake.set()

        if not self.tracing:  # the first batch in flight: the node turns busy
            self.busy_since = time.perf_counter()
        task = asyncio.create_task(run())
        self.tracing.add(task)

    def pass_packet(self) -> None:
        """Record counters, maybe advance the state, send the packet to the next ring node;
        a DONE packet goes round once and is dropped where it has been before."""
        packet, self.packet = self.packet, None
        if self.state == State.DONE:
            if self.done_passed:
                return
        else:
            before = packet.state
            packet = self.term.pass_on(packet)
            if packet.state != before:
                self.enter(packet.state)
        self.done_passed = self.state == State.DONE
        nxt = self.torus.ring_next(self.node)
        if nxt == self.node:
            self.packet = None if self.done_passed else packet
            self.wake.set()
            return
        message = make(Kind.STATE, state=packet.state, last_busy=packet.last_busy,
                       round=packet.round, sent=packet.sent, received=packet.received,
                       dest=nxt)  # fmt: skip
        self.outboxes[self.router.next_hop(nxt)].post(message)

    def statistics(self) -> dict:
        elapsed = time.perf_counter() - self.started
        links = {}
        for m, o in self.outboxes.items():
            links[str(m)] = dict(o.link.stats, rays_sent=self.rays_out.get(m, 0),
                                 rays_received=self.rays_in.get(m, 0))  # fmt: skip
        return {
            "node": self.node,
            "objects": self.core.engine.stats["objects"] if self.core else 0,
            "engine": self.core.engine.stats if self.core else {},
            "rays": self.counts,
            "rays_sent": sum(self.rays_out.values()),
            "rays_received": sum(self.rays_in.values()),
            "pixel_packets": self.pixel_packets,
            "busy_seconds": self.busy,
            "busy_cpu_seconds": self.cpu,
            "idle_seconds": max(elapsed - self.busy, 0.0),
            "packet_visits": self.term.visits,
            "links": links,
        }

    async def close(self) -> None:
        for t in [*self.tasks, *self.tracing]:
            t.cancel()
        for o in self.outboxes.values():
            o.task.cancel()
            await o.link.close()
        self.host_out.task.cancel()


class NodeService:
    """Listens on one address; serves renders one after another until stopped."""

    def __init__(self, host: str, port: int, cluster: str = "meshtrace", once: bool = False,
                 threads: int = 1):  # fmt: skip
        self.address, self.port, self.cluster, self.once = host, port, cluster, once
        self.threads = max(1, threads)
        self.pool = ThreadPoolExecutor(max_workers=self.threads, thread_name_prefix="trace")
        self.session: Session | None = None
        self.pending: dict[int, Link] = {}
        self.links_ready = asyncio.Event()
        self.stopped = asyncio.Event()

    async def start(self) -> int:
        self.server = await asyncio.start_server(self.accept, self.address, self.port)
        self.port = self.server.sockets[0].getsockname()[1]
        return self.port

    async def wait_links(self, session: Session) -> None:
        """Until every neighbour of the session's node is linked (in either direction)."""
        want = set(session.torus.links(session.node))
        while True:
            for m in list(self.pending):
                if m in want and m not in session.outboxes:
                    session.attach(m, self.pending.pop(m))
            if want <= set(session.outboxes):
                return
            self.links_ready.clear()
            await asyncio.wait_for(self.links_ready.wait(), timeout=30)

    async def accept(self, reader, writer) -> None:
        peer = "{}:{}".format(*writer.get_extra_info("peername")[:2])
        link = Link(reader, writer, peer)
        try:
            fields = check_hello(await link.recv_raw(), self.cluster)
        except Exception as e:  # a bad handshake closes just this link
            log.warning("refused %s: %s", peer, e)
            await link.close()
            return
        me = self.session.node if self.session else -1
        await link.send(hello(self.cluster, "node", me))
        if fields["role"] == "node":
            link.peer = f"node {fields['node']}"
            self.pending[fields["node"]] = link
            self.links_ready.set()
            return
        await self.serve_host(link)

    async def serve_host(self, link: Link) -> None:
        session = None
        try:
            while True:
                kind, f = await link.recv()
                if kind is Kind.CONFIG:
                    session = self.session = Session(self, link, f)
                elif kind is Kind.OBJECTS and session:
                    session.add_objects(f["table"], f["records"])
                    if f["last"]:
                        session.tasks.append(asyncio.create_task(self._build(session)))
                elif kind is Kind.SHUTDOWN:
                    break
                else:
                    raise LinkClosed("host", f"unexpected {kind.name}")
        except LinkClosed as e:
            log.info("host link: %s", e.reason)
        finally:
            if session:
                await session.close()
            self.session = None
            await link.close()
            if self.once:
                self.stopped.set()

    async def _build(self, session: Session) -> None:
        try:
            await session.build()
        except Exception as e:
            session.fail(e)

    async def run(self) -> None:
        async with self.server:
            await self.stopped.wait()
        self.pool.shutdown(wait=False, cancel_futures=True)
