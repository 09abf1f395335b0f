"""The link's send path (meshnode.transport.link) over a fake stream: any failure there, not
only a closed connection, reaches whoever owns the outbox by name, and a session fails its
render with it instead of waiting for rays that were never sent."""

import asyncio
from types import SimpleNamespace

import numpy as np
import pytest

from meshnode.service.config import Config
from meshnode.service.session import Session
from meshnode.transport.link import Link, LinkClosed, Outbox, SendFailed
from protocols.dtypes import RAY
from protocols.errors import FrameTooLarge
from protocols.messages import Kind, make
from protocols.render import MeshPlan
from tests.test_node_service import config


class FakeWriter:
    """A stream writer that keeps what is written; `broken` makes every write fail as a
    reset connection does."""

    def __init__(self, broken: bool = False):
        self.frames, self.broken = [], broken
        self.transport = SimpleNamespace(get_write_buffer_size=lambda: 0)

    def writelines(self, data: list) -> None:
        """One vectored write, kept as the bytes it wrote."""
        if self.broken:
            raise ConnectionResetError("reset by peer")
        self.frames.append(b"".join(data))

    async def drain(self) -> None:
        return None

    def close(self) -> None:
        return None

    async def wait_closed(self) -> None:
        return None


def fake_link(peer: str, max_frame: int = 1 << 20, broken: bool = False) -> Link:
    return Link(asyncio.StreamReader(), FakeWriter(broken), peer, max_frame)


async def first_error(outbox_messages, link: Link) -> BaseException:
    """Post `outbox_messages` on an outbox over `link`; the error its task reports."""
    got = asyncio.get_running_loop().create_future()
    outbox = Outbox(link, lambda e: got.done() or got.set_result(e))
    for m in outbox_messages:
        outbox.post(m)
    error = await asyncio.wait_for(got, 5)
    await asyncio.wait_for(outbox.task, 5)  # the task ends: it never sends past a loss
    return error


async def test_a_frame_over_the_limit_fails_by_peer_and_kind():
    link = fake_link("node 3 (10.0.0.3:7700)", max_frame=4096)
    rays = np.zeros(1000, RAY)  # about 100 kB: far over the 4 kB frame
    ok = make(Kind.SHUTDOWN)
    error = await first_error([ok, make(Kind.RAYS, rays=rays, dest=3, cell=3), ok], link)
    assert isinstance(error, SendFailed) and isinstance(error.__cause__, FrameTooLarge)
    assert "could not send RAYS to node 3 (10.0.0.3:7700)" in str(error)
    assert "exceeds the 4096 limit" in str(error)
    assert len(link.writer.frames) == 1  # the first message went; nothing after the loss


async def test_a_message_that_does_not_encode_fails_by_name():
    link = fake_link("the host")
    error = await first_error([{"k": int(Kind.ERROR), "reason": {1, 2}}], link)  # a set
    assert isinstance(error, SendFailed) and isinstance(error.__cause__, TypeError)
    assert str(error).startswith("could not send ERROR to the host: TypeError")
    assert link.writer.frames == []


async def test_a_reset_connection_is_still_a_link_closed():
    error = await first_error([make(Kind.SHUTDOWN)], fake_link("node 1", broken=True))
    assert isinstance(error, LinkClosed) and error.peer == "node 1"
    assert "reset by peer" in str(error)


async def test_a_send_error_fails_the_sessions_render_and_tells_the_host():
    service = SimpleNamespace(
        threads=1, incoming_high=1 << 16, engines=None, pool=None, object_share=0.5
    )
    host = fake_link("the host")
    session = Session(service, host, Config(config(node=0, plan=MeshPlan(1, 2))))
    try:
        session.attach(1, fake_link("node 1 (127.0.0.1:9)", max_frame=4096))
        session.post_data(1, Kind.RAYS, np.zeros(1000, RAY))
        await asyncio.wait_for(session.wake.wait(), 5)
        assert isinstance(session.error, SendFailed)
        assert "could not send RAYS to node 1 (127.0.0.1:9)" in str(session.error)
        await asyncio.wait_for(_until(lambda: host.writer.frames), 5)
        sent = b"".join(host.writer.frames)
        assert b"node 0: SendFailed: could not send RAYS to node 1" in sent
    finally:
        for task in list(session.tasks):
            task.cancel()
        for outbox in [session.host_out, *session.outboxes.values()]:
            outbox.task.cancel()
        await asyncio.gather(*session.tasks, return_exceptions=True)


async def _until(ready, tries: int = 500) -> None:
    """Yield to the loop until `ready()` holds (bounded in count; the caller bounds time)."""
    for _ in range(tries):
        if ready():
            return
        await asyncio.sleep(0)
    pytest.fail("the host was told nothing")


class FakeTransport:
    """What `Receiver` calls on a transport: pausing and resuming reading, counted."""

    def __init__(self):
        self.paused = 0
        self.resumed = 0

    def pause_reading(self):
        self.paused += 1

    def resume_reading(self):
        self.resumed += 1


def _deliver(receiver, data: bytes, piece: int) -> int:
    """Feed `data` as a transport does (into whatever buffer the receiver offers, at most
    `piece` bytes a read); the number of reads that went straight into a frame's payload."""
    direct, at = 0, 0
    while at < len(data):
        buf = receiver.get_buffer(-1)
        n = min(len(buf), piece, len(data) - at)
        buf[:n] = data[at : at + n]
        direct += receiver.direct
        receiver.buffer_updated(n)
        at += n
    return direct


def test_large_frames_are_received_in_place_and_reading_pauses_until_taken():
    from meshnode.transport.receiver import READ_HIGH, Receiver
    from protocols.framing import FrameDecoder, encode

    transport = FakeTransport()
    receiver = Receiver(None, transport, FrameDecoder(), b"", {"bytes_in": 0})
    rays = np.zeros(40_000, RAY)  # about 4 MB a frame: most of it read straight into place
    rays["pixel"] = np.arange(len(rays))
    frames = [encode(make(Kind.RAYS, rays=rays, dest=k, cell=k)) for k in range(3)]
    small = encode(make(Kind.SHUTDOWN))
    direct = _deliver(receiver, b"".join([frames[0], small, frames[1], frames[2]]), 65536)
    assert direct > 0.9 * 3 * len(frames[0]) / 65536  # not through the scratch buffer
    assert len(receiver.ready) == 4 and transport.paused == 1  # over READ_HIGH: paused once
    assert 3 * rays.nbytes > READ_HIGH
    got = []
    while receiver.ready:
        got.append(receiver.ready.popleft())
        receiver.taken()
    assert transport.resumed == 1
    assert [m["k"] for m in got] == [Kind.RAYS, Kind.SHUTDOWN, Kind.RAYS, Kind.RAYS]
    for k, m in zip((0, 1, 2), (got[0], got[2], got[3]), strict=True):
        assert m["dest"] == k
        np.testing.assert_array_equal(m["rays"], rays)


async def test_a_bad_frame_read_before_the_link_took_over_is_its_first_error():
    # Bytes the stream reader already held when the link swapped in its receiver are framed
    # first; a bad frame among them raised out of the link's construction (a node's accept
    # then left the connection open and unread). It is now the first receive's error, and
    # the link closes.
    import struct

    got = asyncio.get_running_loop().create_future()

    async def on_connect(reader, writer):
        await reader._wait_for_data("test")  # the bytes are in the reader before the link
        try:
            link = Link(reader, writer, "peer", max_frame=1024)
            await link.recv()
        except Exception as e:  # noqa: BLE001 - what is raised, and where, is the test
            got.set_result(e)
        writer.close()

    server = await asyncio.start_server(on_connect, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(struct.pack("<I", 2**32 - 1))
    await writer.drain()
    error = await asyncio.wait_for(got, 5)
    assert isinstance(error, LinkClosed) and "exceeds the 1024 limit" in str(error)
    assert await asyncio.wait_for(reader.read(), 5) == b""  # closed by the link
    writer.close()
    server.close()
    await server.wait_closed()


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
def test_rays_in_parts_arrive_as_one_array_over_either_loop(loop):
    # A RAYS message whose rays are several arrays (`Parts`, as a node sends the runs it
    # gathered for a neighbour) crosses a real socket as one frame, written whole on uvloop
    # and in WRITE_CHUNK pieces on asyncio's transport: the receiver gets their join, and
    # the bytes counted are the frame's.
    from meshnode.transport.link import WRITE_CHUNK
    from protocols.framing import encode
    from protocols.records import Parts, joined

    rng = np.random.default_rng(3)
    parts = [np.frombuffer(rng.bytes(n * RAY.itemsize), RAY).copy() for n in (7000, 1, 5000)]
    message = make(Kind.RAYS, rays=Parts.of(parts), dest=1, cell=1)
    assert sum(p.nbytes for p in parts) > 4 * WRITE_CHUNK

    async def main():
        got = asyncio.get_running_loop().create_future()

        async def on_connect(reader, writer):
            got.set_result(await Link(reader, writer, "sender").recv())
            writer.close()

        server = await asyncio.start_server(on_connect, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        link = await Link.connect(f"127.0.0.1:{port}", "receiver", wait=5)
        await link.send(message)
        kind, fields = await asyncio.wait_for(got, 10)
        await link.close()
        server.close()
        await server.wait_closed()
        return kind, fields, link.stats["bytes_out"]

    run = asyncio.run if loop == "asyncio" else pytest.importorskip("uvloop").run
    kind, fields, sent = run(main())
    assert kind is Kind.RAYS and fields["rays"].tobytes() == joined(parts).tobytes()
    assert sent == len(encode(make(Kind.RAYS, rays=joined(parts), dest=1, cell=1)))
