"""`meshnode serve`: the node's asyncio server (DESIGN.md 5), its links and its lifecycle.

Accepts the host and its torus neighbours on one port; every link opens with HELLO. A host
link carries CONFIG and the node's objects, which start a Session (one render at a time: a
second host is refused while one renders); neighbour links are handed to the session that
waits for them. `shutdown()` closes every link and awaits every task the service started.
"""

import asyncio
import contextlib
import gc
import logging
from concurrent.futures import ThreadPoolExecutor

from meshnode.engine.heap import give_back
from meshnode.mesh.engines import EngineCache
from meshnode.mesh.scheduler import INCOMING_HIGH
from meshnode.mesh.stats import available_memory
from meshnode.service.admission import (
    ADMIT_SECONDS,
    AUTHENTICATED,
    PER_ADDRESS,
    Admission,
    RefusalLog,
)
from meshnode.service.config import KEEP_ENGINES, OBJECT_SHARE
from meshnode.service.session import Config, Session
from meshnode.transport.link import (
    HANDSHAKE_FRAME,
    HANDSHAKE_SECONDS,
    Link,
    LinkClosed,
    answer,
    dial,
)
from meshnode.transport.tls import NO_TLS, TlsFiles
from protocols.errors import BadFrame, ProtocolError, Saturated, describe
from protocols.messages import Kind, make

log = logging.getLogger("meshnode")
# A host that renders again at once can reach a node still closing the last render's session
# (its tasks cancelled and awaited, its links dropped): it waits this long for that, not
# refused as "rendering for another host" (a bench's back-to-back renders lost node 0 so and
# re-planned on the other 8 of a 3x3).
CLOSING_WAIT = 10.0
UNCONFIGURED = -1  # the node a listener says it is before its CONFIG has come


def memory_back() -> None:
    """After a render: what it allocated and left in reference cycles is collected, and the
    heap's freed memory goes back to the system (`meshnode.engine.heap.give_back`); a node
    keeps only its engine cache for the next render (issue 41: 1,668 MB stayed after an
    authenticated render that peaked at 1,996 MB)."""
    gc.collect()
    give_back()


class NodeService:
    """Listens on one address; serves renders one after another until stopped.

    `threads`: batches traced at once; `incoming_high`: queued incoming rays at which the
    node stops reading from its neighbours; `once`: stop after the first host leaves;
    `secret`: the cluster secret every peer must prove (None: the empty key, loopback use);
    `tls`: certificate, key and CA files for TLS on every link (meshnode.transport.tls);
    `object_share`: the share of its free memory a render's objects may take (at most 4 GiB);
    `keep_engines`: bytes of engines kept between renders for the next of the same scene."""

    def __init__(
        self,
        host: str,
        port: int,
        cluster: str = "meshtrace",
        once: bool = False,
        threads: int = 1,
        incoming_high: int = INCOMING_HIGH,
        secret: bytes | None = None,
        tls: TlsFiles = NO_TLS,
        object_share: float = OBJECT_SHARE,
        keep_engines: int = KEEP_ENGINES,
    ):
        self.address, self.port, self.cluster, self.once = host, port, cluster, once
        self.secret = secret
        self.tls_server, self.tls_client = tls.server(), tls.client()
        self.threads = max(1, threads)
        self.incoming_high = incoming_high
        self.pool = ThreadPoolExecutor(max_workers=self.threads, thread_name_prefix="trace")
        self.session: Session | None = None
        self.leaving: Session | None = None  # the session whose host has gone, closing
        self.free = asyncio.Event()  # no session: a host may start one
        self.free.set()
        # the last render's engines, for the next of that scene, within `keep_engines` bytes
        self.engines = EngineCache(keep_engines)
        self.object_share = object_share
        # neighbour links that came before their session took them: node -> (render id, link)
        self.pending: dict[int, tuple[bytes, Link]] = {}
        self.links_ready = asyncio.Event()
        self.stopped = asyncio.Event()
        self.tasks: set[asyncio.Task] = set()
        self.server: asyncio.Server | None = None
        self.admission = Admission()  # who may be proving the secret, and how many hosts
        self.refusals = RefusalLog(log)

    async def start(self) -> int:
        tls = (
            {"ssl": self.tls_server, "ssl_handshake_timeout": HANDSHAKE_SECONDS}
            if self.tls_server
            else {}
        )
        self.server = await asyncio.start_server(self._accepted, self.address, self.port, **tls)
        self.port = self.server.sockets[0].getsockname()[1]
        return self.port

    async def run(self) -> None:
        """Serve until stopped (`once`: after one render), then shut down."""
        try:
            await self.stopped.wait()
        finally:
            await self.shutdown()

    async def shutdown(self) -> None:
        """Stop listening, end the render in progress, close every link, await every task."""
        self.stopped.set()
        if self.server is not None:
            self.server.close()
        if self.session is not None:
            await self.session.close()
        current = asyncio.current_task()
        tasks = [t for t in self.tasks if t is not current]
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for _, link in self.pending.values():
            await link.close()
        self.pending.clear()
        if self.server is not None:
            await self.server.wait_closed()
        self.pool.shutdown(wait=False, cancel_futures=True)

    async def _accepted(self, reader, writer) -> None:
        """A connection's task, tracked so `shutdown` can cancel and await it."""
        task = asyncio.current_task()
        self.tasks.add(task)
        try:
            await self.accept(reader, writer)
        finally:
            self.tasks.discard(task)

    # ------------------------------------------------------------------ links
    def wrap(self, peer: int, link: Link) -> Link:
        """The link to neighbour `peer` as the session uses it (tests wrap it to inject
        faults, such as a slow link; production uses it as it is)."""
        return link

    async def dial(self, m: int, address: str) -> Link:
        """Connect to neighbour m, both sides proving the cluster secret."""
        link, theirs = await dial(
            address,
            f"node {m} ({address})",
            self.cluster,
            self.secret,
            "node",
            self.session.node,
            self.tls_client,
            self.session.config.render_id,
        )
        # -1: its CONFIG has not come yet (a busy machine, a slow host): it keeps the link
        # for the session that CONFIG starts, checking render and neighbours then
        # (`neighbour`, `wait_links`); failing here failed the render (bench, 3x3 at once)
        if theirs["node"] not in (m, UNCONFIGURED):
            await link.close()
            raise LinkClosed(link.peer, f"it says it is node {theirs['node']}, not node {m}")
        return self.wrap(m, link)

    async def wait_links(self, session: Session) -> None:
        """Until every neighbour of the session's node is linked (in either direction).
        No fixed timeout: neighbours link once their engines are built, which takes as long
        as their share of the scene; the host's watchdog names a node that dies or hangs."""
        want = set(session.config.torus.links(session.node))
        while True:
            for m, (render, link) in list(self.pending.items()):
                if render != session.config.render_id:  # from a given-up render: never ours
                    del self.pending[m]
                    self._spawn(link.close())
                elif m in want and m not in session.outboxes:
                    session.attach(m, self.pending.pop(m)[1])
            if want <= set(session.outboxes):
                return
            self.links_ready.clear()
            await self.links_ready.wait()

    async def accept(self, reader, writer) -> None:
        """A new connection: admitted to the handshake (`meshnode.service.admission`: a
        small pool, a few an address, a short deadline), then a neighbour's link kept for
        its session or a host's served, within the authenticated capacity."""
        address, port = writer.get_extra_info("peername")[:2]
        peer = f"{address}:{port}"
        link = Link(reader, writer, peer, max_frame=HANDSHAKE_FRAME)
        admitted, dropped = self.admission.arrive(link, address)
        for old in dropped:
            old.abort()
            self.refusals.refused(old.peer, "the handshake pool is full: the oldest goes")
        if not admitted:
            link.abort()
            self.refusals.refused(
                peer, f"{PER_ADDRESS} connections from {address} are proving the secret already"
            )
            return
        me = self.session.node if self.session else UNCONFIGURED
        hosts = []  # a host's link admitted into the authenticated capacity

        def admit(fields: dict) -> None:
            if fields["role"] == "host":
                if not self.admission.authenticate():
                    raise Saturated(f"node saturated: {AUTHENTICATED} hosts' links open")
                hosts.append(True)

        try:
            fields = await asyncio.wait_for(
                answer(link, self.cluster, self.secret, me, available_memory(), admit),
                ADMIT_SECONDS,
            )
        except TimeoutError:
            if hosts:
                self.admission.closed()
            link.abort()
            self.refusals.refused(peer, f"no proof of the secret within {ADMIT_SECONDS:g} s")
            return
        except (ProtocolError, LinkClosed) as e:  # a bad handshake closes just this link
            if hosts:  # admitted, then the handshake failed after all
                self.admission.closed()
            self.refusals.refused(peer, describe(e))
            return
        finally:
            self.admission.leave(link)
        if fields["role"] == "node":
            self.neighbour(fields["node"], fields["render"], link)
            return
        try:
            await self.serve_host(link)
        finally:
            self.admission.closed()

    def neighbour(self, m: int, render: bytes, link: Link) -> None:
        """Keep a link a neighbour opened until its session takes it: only the current
        session's neighbours, for its render, one link each (a newer one replaces an older).
        Before the session's CONFIG arrives the render cannot be checked; the session drops
        links of any other render when it takes its own."""
        session = self.session
        why = None
        if session is not None and render != session.config.render_id:
            why = "its link is for another render (one given up, or another host's)"
        elif session is not None and m not in session.config.torus.links(session.node):
            why = f"node {m} is not a neighbour of node {session.node}"
        if why is not None:
            log.warning("refused %s: %s", link.peer, why)
            self._spawn(link.close())
            return
        link.peer = f"node {m} ({link.peer})"
        old = self.pending.pop(m, None)
        if old is not None:
            self._spawn(old[1].close())
        self.pending[m] = (render, self.wrap(m, link))
        self.links_ready.set()

    def _spawn(self, coro) -> None:
        task = asyncio.create_task(coro)
        self.tasks.add(task)
        task.add_done_callback(self.tasks.discard)

    # ------------------------------------------------------------------ the host
    async def serve_host(self, link: Link) -> None:
        """CONFIG, then the objects, then wait for SHUTDOWN; one render at a time. ABORT ends
        the render without ending the link: the host re-plans on the nodes left and sends a
        new CONFIG on the same link (so `once` nodes stay for it)."""
        if self.session is not None and self.session is self.leaving:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.free.wait(), CLOSING_WAIT)
        if self.session is not None:
            await self._refuse(link, "this node is rendering for another host")
            return
        session = None
        try:
            while True:
                kind, f = await link.recv()
                if kind is Kind.CONFIG and session is None:
                    session = self.session = Session(self, link, Config(f))
                    self.free.clear()
                elif kind is Kind.OBJECTS and session is not None:
                    session.objects.add(f["node"], f["table"], f["records"])
                    if f["last"]:
                        session.spawn(session.build())
                elif kind is Kind.TILES and session is not None:
                    session.on_tiles(f)
                elif kind is Kind.ABORT:
                    log.warning("host gave up the render: %s", f["reason"])
                    await self._end(session)
                    session = None
                    await link.send(make(Kind.ABORTED))
                elif kind is Kind.SHUTDOWN:
                    break
                else:
                    raise BadFrame(f"unexpected {kind.name} from the host")
        except LinkClosed as e:
            log.info("host link: %s", e.reason)
        except (ProtocolError, ValueError) as e:  # a bad CONFIG: tell the host what
            await self._refuse(link, describe(e))
        finally:
            self.leaving = session
            await self._end(session)
            self.leaving = session = None  # the render's objects, queues and books go now
            await link.close()
            self.engines.trim()
            memory_back()
            if self.once:
                self.stopped.set()

    async def _end(self, session: Session | None) -> None:
        """Close a render's session and drop neighbour links it never took: a link kept
        past its render would be handed to the next one as if it were its neighbour's."""
        if session is not None:
            await session.close()
        if self.session is session:
            self.session = None
            self.free.set()
        for _, link in self.pending.values():
            self._spawn(link.close())
        self.pending.clear()

    async def _refuse(self, link: Link, reason: str) -> None:
        log.warning("refused host %s: %s", link.peer, reason)
        try:
            await link.send(make(Kind.ERROR, reason=reason))
        except LinkClosed:
            pass
        await link.close()
