"""The node service in this process, on loopback: its lifecycle and what it tells a host
that it cannot serve. No subprocesses; every wait is bounded."""

import asyncio

import numpy as np
import pytest

from host.planning.request import Request
from host.run.connections import Nodes
from meshnode.service.server import NodeService
from meshnode.transport.link import Link, LinkClosed, dial
from protocols.messages import Kind, make
from protocols.partition import Partition
from protocols.render import ImageSpec, MeshPlan, RenderSpec
from protocols.scene import SceneHeader, View

VIEW = View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0)


def config(node=0, plan=None, **render_wire):
    plan = plan or MeshPlan()
    spec = RenderSpec(ImageSpec(width=4, height=4), plan=plan)
    n = plan.nodes
    part = Partition.make(
        [(0, 4, 0, 4)] * n, np.zeros((n, 3)), np.ones((n, 3)), (np.zeros(3), np.ones(3))
    )
    render = spec.to_wire()
    for record, changes in render_wire.items():
        render[record].update(changes)
    return make(
        Kind.CONFIG,
        node=node,
        neighbours={str(m): "127.0.0.1:9" for m in range(n)},
        render=render,
        partition=part.to_wire(),
        scene=SceneHeader(VIEW).to_wire(),
        render_id=b"r" * 16,
    )


async def host_link(
    port: int, secret: bytes | None = None, role: str = "host", node: int = -1
) -> Link:
    link, _ = await dial(f"127.0.0.1:{port}", "node under test", "meshtrace", secret, role, node)
    return link


async def send_objects(link: Link, scene, node: int = 0, **tables) -> None:
    """Every object table of `scene` (or of `tables`, by name, instead) as OBJECTS for
    `node`, the last one marked last: what a host downloads."""
    from protocols.messages import OBJECT_TABLES

    for name in OBJECT_TABLES:
        data = tables[name] if name in tables else getattr(scene, name)
        data = data.reshape(-1) if name == "vertices" else data
        await link.send(
            make(
                Kind.OBJECTS,
                node=node,
                table=name,
                records=np.ascontiguousarray(data),
                last=name == "lights",
            )
        )


async def started(secret: bytes | None = None) -> NodeService:
    service = NodeService("127.0.0.1", 0, secret=secret)
    await service.start()
    return service


async def test_a_bad_config_is_answered_with_the_field_it_names():
    service = await started()
    try:
        link = await host_link(service.port)
        await link.send(config(image={"depth": 0}))
        kind, f = await asyncio.wait_for(link.recv(), 10)
        assert kind is Kind.ERROR and "ImageSpec.depth = 0" in f["reason"]
        link = await host_link(service.port)
        await link.send(config(node=7))
        kind, f = await asyncio.wait_for(link.recv(), 10)
        assert kind is Kind.ERROR and "CONFIG.node = 7" in f["reason"]
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_second_host_is_refused_while_one_renders():
    service = await started()
    try:
        first = await host_link(service.port)
        await first.send(config())  # a session starts; no objects yet
        await _heartbeat(first)
        second = await host_link(service.port)
        kind, f = await asyncio.wait_for(second.recv(), 10)
        assert kind is Kind.ERROR and "another host" in f["reason"]
        assert service.session is not None  # the first render goes on
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_host_that_comes_while_the_last_render_closes_waits_instead_of_refused():
    # The first host leaves; its session is still closing (held open here by a gate) when
    # the next host comes, as a host rendering again at once does: the node waits for the
    # close and takes the new render.
    service = await started()
    try:
        first = await host_link(service.port)
        await first.send(config())
        await _heartbeat(first)
        session, closing, gate = service.session, asyncio.Event(), asyncio.Event()
        close = session.close

        async def slow_close():
            closing.set()
            await gate.wait()
            await close()

        session.close = slow_close
        await first.send(make(Kind.SHUTDOWN))
        await asyncio.wait_for(closing.wait(), 10)
        second = await host_link(service.port)
        await second.send(config())
        gate.set()
        kind, f = await asyncio.wait_for(second.recv(), 10)
        assert kind is Kind.PROGRESS  # the new session's heartbeat, no ERROR
        assert service.session is not None and service.session is not session
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_shutdown_closes_every_link_and_awaits_every_task():
    service = await started()
    link = await host_link(service.port)
    await link.send(config())
    await _heartbeat(link)
    session = service.session
    tasks = set(session.tasks) | set(service.tasks)
    assert tasks
    await asyncio.wait_for(service.shutdown(), 10)
    assert all(t.done() for t in tasks)
    assert not service.server.is_serving()
    with pytest.raises(LinkClosed):  # the host sees its link closed, not a hang
        await asyncio.wait_for(link.recv(), 10)


async def _heartbeat(link: Link) -> None:
    """The session's first sign of life: a PROGRESS that says it is not ready yet."""
    kind, f = await asyncio.wait_for(link.recv(), 10)
    assert kind is Kind.PROGRESS and not f["ready"]


@pytest.mark.parametrize(
    "table,change,what",
    [
        ("spheres", {"mat": -(2**31)}, "material index"),
        ("spheres", {"radius": float("nan")}, "must be finite"),
        ("polygons", {"count": 2**31 - 1}, "vertex ranges"),
        ("lights", {"pos": float("nan")}, "must be finite"),
        # the scene readers refuse numbers beyond 1e100; so does a node, whoever sends them
        ("spheres", {"radius": 1e300}, "radius = 1e+300 is beyond +-1e+100"),
        ("triangles", {"v": -1e308}, "v = 1e+308 is beyond"),
    ],
)
async def test_objects_that_would_crash_or_hang_an_engine_are_refused(table, change, what):
    # Found by bench/fuzz_node.py: a bad material index read outside an array in a kernel
    # (a segfault), a NaN kept a ray walking forever, a huge polygon count asked for 16 GiB.
    from meshnode.service.warmup import ALL_KINDS, variant_scene

    scene = variant_scene(ALL_KINDS)
    records = getattr(scene, table).copy()
    for field, value in change.items():
        records[field] = value
    service = await started()
    try:
        link = await host_link(service.port)
        await link.send(config())
        await send_objects(link, scene, **{table: records})
        while True:  # heartbeats, then the error naming the table
            kind, f = await asyncio.wait_for(link.recv(), 10)
            if kind is Kind.ERROR:
                break
        assert f"OBJECTS {table}" in f["reason"] and what in f["reason"]
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


async def test_a_finished_render_leaves_nothing_but_the_engine_cache(monkeypatch):
    # 1,668 MB stayed after an authenticated render that peaked at 1,996 MB (issue 41): the
    # finished session (its objects, queues, books) stayed referenced until the next render,
    # and the heap kept what batches freed. Now the session goes, the heap is trimmed, and
    # only the engine cache is kept for a render of the same scene.
    import gc
    import weakref

    from host.run.meshclient import render_on_mesh
    from meshnode.service import server as server_module
    from meshnode.service.session import Session
    from protocols.render import EngineSpec, ImageSpec, MeshPlan
    from tests.conftest import make_scene

    sessions, trimmed = [], []
    original = Session.__init__

    def remember(self, *a, **k):
        original(self, *a, **k)
        sessions.append(weakref.ref(self))

    monkeypatch.setattr(Session, "__init__", remember)
    monkeypatch.setattr(server_module, "give_back", lambda: trimmed.append(True) or True)
    service = await started()
    try:
        scene = make_scene()
        await render_on_mesh(
            Request(
                scene, ImageSpec(width=16, height=16), EngineSpec(threads=1), plan=MeshPlan(1, 1)
            ),
            Nodes([f"127.0.0.1:{service.port}"]),
        )
        await asyncio.wait_for(service.free.wait(), 10)
        for _ in range(200):  # the host link's task finishes its `finally` (bounded turns)
            if trimmed:
                break
            await asyncio.sleep(0)
        gc.collect()
        assert trimmed and len(sessions) == 1 and sessions[0]() is None
        assert service.leaving is None and service.session is None
        assert len(service.engines.engines) == 1  # kept for the next render of this scene
    finally:
        await asyncio.wait_for(service.shutdown(), 10)


@pytest.mark.parametrize("speaks", [b"HTTP/1.1 400 Bad Request\r\n\r\n", b"\x00\x00\x00\x05hello"])
async def test_a_neighbour_address_that_is_another_service_fails_by_name(speaks):
    # A CONFIG whose neighbour address points at some other service (issue 41 item 8): the
    # node dials it, gets no HELLO but whatever that service says, and the host hears which
    # neighbour and why in one ERROR, at once; nothing hangs.
    from meshnode.service.warmup import ALL_KINDS, variant_scene

    async def other_service(reader, writer):
        writer.write(speaks)
        await writer.drain()
        await reader.read(1 << 16)
        writer.close()

    foreign = await asyncio.start_server(other_service, "127.0.0.1", 0)
    address = f"127.0.0.1:{foreign.sockets[0].getsockname()[1]}"
    scene = variant_scene(ALL_KINDS)
    service = await started()
    try:
        link = await host_link(service.port)
        message = config(plan=MeshPlan(1, 2))
        message["neighbours"] = {"0": f"127.0.0.1:{service.port}", "1": address}
        await link.send(message)
        await send_objects(link, scene)
        for _ in range(100):  # heartbeats, then the error naming the neighbour (bounded)
            kind, f = await asyncio.wait_for(link.recv(), 15)
            if kind is Kind.ERROR:
                break
        assert kind is Kind.ERROR
        assert f"node 1 ({address})" in f["reason"] and "handshake failed" in f["reason"]
    finally:
        await asyncio.wait_for(service.shutdown(), 10)
        foreign.close()
        await foreign.wait_closed()


async def test_a_bad_frame_sent_with_the_hello_is_refused_and_the_connection_closed(caplog):
    # A peer that writes its HELLO and a length prefix past any frame's limit at once: the
    # node read both before its link took over the connection, and a bad frame there raised
    # out of the link's construction, left the connection open and unread (a fuzzer waited
    # out its 15 s timeout) and logged an unhandled exception.
    import struct

    from protocols.framing import encode
    from protocols.handshake import hello

    service = NodeService("127.0.0.1", 0)
    await service.start()
    try:
        for _ in range(5):
            reader, writer = await asyncio.open_connection("127.0.0.1", service.port)
            writer.write(encode(hello("meshtrace", "host")) + struct.pack("<I", 2**32 - 1))
            await writer.drain()
            while await asyncio.wait_for(reader.read(65536), 5):  # the node closes it
                pass
            writer.close()
        link = await host_link(service.port)  # and a real host is served after them
        await link.send(config())
        kind, _ = await asyncio.wait_for(link.recv(), 10)
        assert kind is Kind.PROGRESS
        await link.close()
    finally:
        await asyncio.wait_for(service.shutdown(), 10)
    assert not [r for r in caplog.records if "Unhandled exception" in r.getMessage()]
