"""One TCP connection carrying frames: the only code that touches streams.

`send` writes a frame and waits for the transport to drain above a high-water mark (so a slow
peer slows the sender instead of growing its memory); `recv` returns the next checked
message. A closed or broken connection, or a malformed message, becomes one LinkClosed that
names the peer and chains the cause.
"""

import asyncio
from collections import deque

from protocols.errors import ProtocolError
from protocols.framing import MAX_FRAME, FrameDecoder, encode
from protocols.messages import parse

HIGH_WATER = 4 * 1024 * 1024  # bytes buffered in the transport before send() waits


class LinkClosed(ConnectionError):
    """The link to `peer` is gone; `reason` says why."""

    def __init__(self, peer: str, reason: str):
        super().__init__(f"link to {peer} closed: {reason}")
        self.peer, self.reason = peer, reason


class Link:
    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: str,
                 max_frame: int = MAX_FRAME):  # fmt: skip
        self.reader, self.writer, self.peer = reader, writer, peer
        self.max_frame = max_frame
        self._decoder = FrameDecoder(max_frame)
        self._ready: list = []
        self.stats = {"messages_out": 0, "bytes_out": 0, "messages_in": 0, "bytes_in": 0}

    @classmethod
    async def connect(cls, address: str, peer: str, retries: int = 50) -> "Link":
        """Connect to HOST:PORT, retrying briefly while the peer starts listening."""
        host, port = address.rsplit(":", 1)
        for attempt in range(retries):
            try:
                reader, writer = await asyncio.open_connection(host, int(port))
                return cls(reader, writer, peer)
            except OSError as e:
                if attempt == retries - 1:
                    raise LinkClosed(peer, f"cannot connect to {address}: {e}") from e
                await asyncio.sleep(0.1)
        raise AssertionError("unreachable")

    async def send(self, message: dict) -> None:
        try:
            frame = encode(message, self.max_frame)
            self.writer.write(frame)
            self.stats["messages_out"] += 1
            self.stats["bytes_out"] += len(frame)
            if self.writer.transport.get_write_buffer_size() > HIGH_WATER:
                await self.writer.drain()
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

    async def close(self) -> None:
        if not self.writer.is_closing():
            self.writer.close()
        try:
            await self.writer.wait_closed()
        except (ConnectionError, RuntimeError):
            pass


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

    async def close(self) -> None:
        """Stop sending and close the link; waits for the sending task to end."""
        self.task.cancel()
        await asyncio.gather(self.task, return_exceptions=True)
        await self.link.close()
