"""One TCP connection carrying frames: with `receiver`, the only code that touches streams.

`send` writes a frame and waits for the transport to drain above a high-water mark (so a slow
peer slows the sender instead of growing its memory); `recv` returns the next checked
message. A closed or broken connection, or a malformed message, becomes one LinkClosed that
names the peer and chains the cause.
"""

import asyncio
import ssl
import sys
import time
from collections import deque

from meshnode.transport.receiver import Receiver
from protocols.errors import AuthFailed, ProtocolError, describe
from protocols.framing import MAX_FRAME, FrameDecoder, frame_buffers
from protocols.handshake import auth, check_auth, check_hello, hello, nonce
from protocols.messages import Kind, make, parse

WRITE_CHUNK = 256 * 1024  # send() waits while the transport holds more than this: a slow
# peer slows the sender instead of growing its memory; asyncio's transport takes a frame in
# pieces of this size (`_piece_size`)
HANDSHAKE_FRAME = 4096  # largest frame a peer may send before it has proved the secret
HANDSHAKE_SECONDS = 10.0  # a peer that has not finished the handshake by then is dropped
CLOSE_SECONDS = 5.0  # a closing link's queued bytes must be taken by then, or are dropped


class LinkClosed(ConnectionError):
    """The link to `peer` is gone; `reason` says why."""

    def __init__(self, peer: str, reason: str):
        super().__init__(f"link to {peer} closed: {reason}")
        self.peer, self.reason = peer, reason


class SendFailed(RuntimeError):
    """A message could not be sent on a link that is still open (it did not encode, or its
    frame is over the limit); says to whom and which kind of message."""

    def __init__(self, peer: str, message: dict | None, cause: BaseException):
        try:
            kind = Kind(message["k"]).name
        except (TypeError, KeyError, ValueError):
            kind = "a message"
        super().__init__(f"could not send {kind} to {peer}: {describe(cause)}")
        self.peer, self.kind = peer, kind
        self.__cause__ = cause


class Link:
    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        peer: str,
        max_frame: int = MAX_FRAME,
    ):
        self.reader, self.writer, self.peer = reader, writer, peer
        self.max_frame = max_frame
        self._decoder = FrameDecoder(max_frame)
        self._ready: list = []
        self.stats = {"messages_out": 0, "bytes_out": 0, "messages_in": 0, "bytes_in": 0}
        self._receiver = self._receive_directly()

    def _receive_directly(self) -> "Receiver | None":
        """Swap the stream reader for a `Receiver` on this connection's transport (None
        where the transport cannot: a test's fake writer); what the reader already holds is
        framed first."""
        transport = getattr(self.writer, "transport", None)
        if transport is None or not hasattr(transport, "set_protocol"):
            return None
        stream = transport.get_protocol()
        held = bytes(getattr(self.reader, "_buffer", b""))
        if held:
            self.reader._buffer.clear()
        self.stats["bytes_in"] += len(held)
        receiver = Receiver(stream, transport, self._decoder, held, self.stats)
        transport.set_protocol(receiver)
        return receiver

    def allow(self, max_frame: int) -> None:
        """Accept frames up to `max_frame` bytes from now on (after the handshake)."""
        self.max_frame = self._decoder.max_frame = max_frame

    @property
    def tls(self) -> str | None:
        """The TLS version the link runs, or None on plain TCP."""
        ssl_object = self.writer.get_extra_info("ssl_object")
        return ssl_object.version() if ssl_object is not None else None

    @classmethod
    async def connect(
        cls,
        address: str,
        peer: str,
        wait: float = 5.0,
        max_frame: int = MAX_FRAME,
        tls: ssl.SSLContext | None = None,
    ) -> "Link":
        """Connect to HOST:PORT (over TLS with a context: the peer's certificate must name
        HOST), retrying for `wait` seconds while the peer starts (its name may not resolve
        yet, or nothing listens yet), then giving up naming it; a TLS failure is final."""
        host, port = address.rsplit(":", 1)
        host = host.strip("[]")
        tls_options = (
            {"ssl": tls, "server_hostname": host, "ssl_handshake_timeout": HANDSHAKE_SECONDS}
            if tls
            else {}
        )
        deadline = time.monotonic() + wait
        pause = 0.1
        while True:
            try:
                reader, writer = await asyncio.open_connection(host, int(port), **tls_options)
                return cls(reader, writer, peer, max_frame)
            except ssl.SSLError as e:
                raise LinkClosed(peer, f"TLS with {address} failed: {e.reason or e}") from e
            except OSError as e:
                if time.monotonic() + pause > deadline:
                    raise LinkClosed(
                        peer, f"cannot connect to {address} within {wait:.3g} s: {e.strerror or e}"
                    ) from e
                await asyncio.sleep(pause)
                pause = min(2 * pause, 1.0)

    async def send(self, message: dict) -> None:
        """Write one frame from the buffers it is made of (`frame_buffers`: a ray batch's
        records from where they lie), vectored, waiting while the transport holds more than
        WRITE_CHUNK bytes: the copy into the socket is then the one on this side (`_piece_size`)."""
        try:
            sent, size = 0, _piece_size(self.writer.transport)
            for piece in _pieces(frame_buffers(message, self.max_frame), size):
                self.writer.writelines(piece)
                sent += sum(len(b) for b in piece)
                if self.writer.transport.get_write_buffer_size() > WRITE_CHUNK:
                    await self.writer.drain()
            self.stats["messages_out"] += 1
            self.stats["bytes_out"] += sent
        except (ConnectionError, RuntimeError) as e:
            raise LinkClosed(self.peer, f"send failed: {e}") from e

    async def recv(self):
        """(kind, fields) of the next message, checked."""
        message = await self.recv_raw()
        try:
            return parse(message)
        except ProtocolError as e:
            await self.close()
            raise LinkClosed(self.peer, f"bad message: {e}") from e

    async def recv_raw(self) -> dict:
        """The next message as decoded, unchecked (the handshake checks its own)."""
        if self._receiver is not None:
            return await self._recv_direct(self._receiver)
        while not self._ready:
            try:
                data = await self.reader.read(1 << 20)
            except ConnectionError as e:
                raise LinkClosed(self.peer, f"connection lost: {e}") from e
            if not data:
                raise LinkClosed(self.peer, "peer closed the connection")
            self.stats["bytes_in"] += len(data)
            try:
                self._ready.extend(self._decoder.feed(data))
            except ProtocolError as e:
                await self.close()
                raise LinkClosed(self.peer, f"bad message: {e}") from e
        self.stats["messages_in"] += 1
        return self._ready.pop(0)

    async def _recv_direct(self, r: Receiver) -> dict:
        """The next message `Receiver` decoded; a bad frame or a closed connection becomes
        LinkClosed as on the stream path."""
        while not r.ready:
            if r.error is not None:
                error = r.error
                if isinstance(error, ProtocolError):
                    await self.close()
                    raise LinkClosed(self.peer, f"bad message: {error}") from error
                raise LinkClosed(self.peer, f"connection lost: {error}") from error
            if r.closed:
                raise LinkClosed(self.peer, "peer closed the connection")
            r.waiter = asyncio.get_running_loop().create_future()
            await r.waiter
        message = r.ready.popleft()
        self.stats["messages_in"] += 1
        r.taken()
        return message

    async def close(self) -> None:
        """Close, flushing what is queued; a peer that stopped reading (paused, hung) gets
        CLOSE_SECONDS to take it, then the connection is dropped: closing never hangs."""
        if not self.writer.is_closing():
            self.writer.close()
        try:
            await asyncio.wait_for(self.writer.wait_closed(), CLOSE_SECONDS)
        except TimeoutError:
            self.writer.transport.abort()
        except (ConnectionError, RuntimeError):
            pass

    def abort(self) -> None:
        """Drop the connection now, discarding what is queued (a peer given up for lost)."""
        self.writer.transport.abort()


class Outbox:
    """Messages waiting for one link, sent in order by one task, so a reader or the work loop
    never blocks on a full link. `sent` is set after every data send, so a work loop paused
    on full outboxes wakes when they drain; a broken link goes to `on_error` once."""

    def __init__(self, link: Link, on_error, sent: asyncio.Event | None = None):
        self.link, self.queue, self.bytes = link, deque(), 0
        self.ready = asyncio.Event()
        self.sent = sent
        self.task = asyncio.create_task(self._run(on_error))

    def post(self, message: dict, size: int = 0) -> None:
        """Queue `message`; `size` bytes of it count toward the node's output bound."""
        self.queue.append((message, size))
        self.bytes += size
        self.ready.set()

    async def _run(self, on_error):
        """Send in order; the first failure of any kind goes to `on_error` and ends the task
        (a message that could not be sent is lost, so the render it belongs to cannot finish
        whole: it fails by name instead of waiting for rays that never come)."""
        message = None
        try:
            while True:
                await self.ready.wait()
                self.ready.clear()
                while self.queue:
                    message, size = self.queue.popleft()
                    await self.link.send(message)
                    self.bytes -= size
                    if size and self.sent is not None:
                        self.sent.set()
        except LinkClosed as e:
            on_error(e)
        except Exception as e:  # encoding: a frame too large, a field msgpack cannot pack
            on_error(SendFailed(self.link.peer, message, e))


async def dial(
    address: str,
    peer: str,
    cluster: str,
    secret: bytes | None,
    role: str,
    node: int = -1,
    tls: ssl.SSLContext | None = None,
    render: bytes = b"",
    wait: float = 5.0,
) -> tuple[Link, dict]:
    """Connect to a node (over TLS with a context; retrying for `wait` seconds) and prove
    the cluster secret both ways (protocols.handshake), a node naming the `render` the link
    is for; returns the link, open for whole frames, and the node's HELLO fields. LinkClosed
    names the peer and why it refused or could not be reached."""
    link = await Link.connect(address, peer, wait, max_frame=HANDSHAKE_FRAME, tls=tls)
    try:
        theirs = await asyncio.wait_for(
            _dialler(link, cluster, secret or b"", role, node, render), HANDSHAKE_SECONDS
        )
    except (ProtocolError, LinkClosed, TimeoutError) as e:
        await link.close()
        reason = e.reason if isinstance(e, LinkClosed) else describe(e)
        if tls is None and isinstance(e, LinkClosed):
            reason += " (a node that listens with TLS closes plain connections: --tls-ca)"
        raise LinkClosed(peer, f"handshake failed: {reason}") from e
    link.allow(MAX_FRAME)
    return link, theirs


async def _dialler(
    link: Link, cluster: str, secret: bytes, role: str, node: int, render: bytes
) -> dict:
    message = hello(cluster, role, node, nonce(), render)
    mine = parse(message)[1]
    await link.send(message)
    theirs = check_hello(await link.recv_raw(), cluster)
    check_auth(await link.recv_raw(), secret, "listener", mine, theirs["nonce"])
    await link.send(auth(secret, "dialler", mine, theirs["nonce"]))
    kind, f = parse(await link.recv_raw())
    if kind is Kind.ERROR:
        raise AuthFailed(f"refused by the node: {f['reason']}")
    if kind is not Kind.WELCOME:
        raise AuthFailed(f"expected WELCOME, got {kind.name}")
    return theirs


async def answer(
    link: Link, cluster: str, secret: bytes | None, node: int, memory: int = 0, admit=None
) -> dict:
    """The listener's side of the handshake, bounded in time and frame size: the dialler's
    HELLO fields once it has proved the secret (and `admit(fields)`, if given, raised no
    Saturated); otherwise it is told why, the link is closed and ProtocolError or
    LinkClosed raised."""
    link.allow(HANDSHAKE_FRAME)
    try:
        return await asyncio.wait_for(
            _listener(link, cluster, secret or b"", node, memory, admit), HANDSHAKE_SECONDS
        )
    except TimeoutError:
        await link.close()
        raise LinkClosed(link.peer, f"no handshake within {HANDSHAKE_SECONDS:g} s") from None
    except LinkClosed:  # the peer left mid-handshake: close our side too
        await link.close()
        raise
    except ProtocolError as e:
        try:
            await link.send(make(Kind.ERROR, reason=describe(e)))
        except LinkClosed:
            pass
        await link.close()
        raise


async def _listener(link: Link, cluster: str, secret: bytes, node: int, memory: int, admit) -> dict:
    dialler = check_hello(await link.recv_raw(), cluster)
    mine = nonce()
    await link.send(hello(cluster, "node", node, mine, memory=memory))
    await link.send(auth(secret, "listener", dialler, mine))
    check_auth(await link.recv_raw(), secret, "dialler", dialler, mine)
    if admit is not None:
        admit(dialler)  # Saturated: the dialler hears why instead of WELCOME
    await link.send(make(Kind.WELCOME))
    link.allow(MAX_FRAME)
    return dialler


def _piece_size(transport) -> int:
    """The bytes of a frame written at once: all of it on uvloop, whose transports keep the
    buffers they could not send yet (no copy, no shift: `python -m bench.link`, the link
    29-39 M rays/s against 24-31 in 256 kB pieces, both ends' CPU 80-91 ns a ray against
    91-106); WRITE_CHUNK on asyncio's, which before Python 3.12 copies and shifts its whole
    buffer on every send (a 6.8 MB frame written whole cost it 5 ms of memmove)."""
    return sys.maxsize if type(transport).__module__.startswith("uvloop") else WRITE_CHUNK


def _pieces(buffers: list, size: int):
    """`buffers` as lists of memoryviews of at most `size` bytes in all, in order (a large
    buffer sliced, never copied)."""
    piece, room = [], size
    for buf in buffers:
        view = memoryview(buf).cast("B")
        while len(view):
            take = view[:room]
            piece.append(take)
            view, room = view[len(take) :], room - len(take)
            if not room:
                yield piece
                piece, room = [], size
    if piece:
        yield piece
