"""Reading a link's frames straight into their buffers, with back-pressure.

The link's transport hands its bytes to a `Receiver` instead of a stream reader, so a large
frame's payload is received once, into the array it becomes. Kept apart from `link`: this is
the asyncio protocol side (callbacks from the transport), `link` the coroutine side (`send`,
`recv`, the handshake) that sessions and the host call.
"""

import asyncio
from collections import deque

import numpy as np

from protocols.errors import ProtocolError
from protocols.framing import FrameDecoder

READ_HIGH = 8 * 1024 * 1024  # bytes of decoded frames not yet taken before reading pauses
SCRATCH = 256 * 1024  # small frames and prefixes are read into this, then framed


class Receiver(asyncio.BufferedProtocol):
    """Reads a link's bytes straight into the frames they belong to: a large frame's payload
    is received into its own buffer (the one copy on this side: no stream buffer, no bytes
    object per read), small frames through a scratch buffer. Reading pauses while more than
    READ_HIGH bytes of decoded frames wait to be taken, so a consumer that stops taking
    (back-pressure) stops the sender through TCP. Writing's flow control and the close
    stay with the stream protocol it replaces (`writer.drain`, `wait_closed`)."""

    def __init__(
        self, stream: asyncio.BaseProtocol, transport, decoder: FrameDecoder, held, stats: dict
    ):
        self.stream, self.transport, self.decoder = stream, transport, decoder
        self.stats = stats  # the link's: bytes_in counts what arrives, as it arrives
        self.ready: deque = deque()  # messages decoded, not yet taken
        self.error: BaseException | None = None
        self.closed = False
        self.waiter: asyncio.Future | None = None
        self.paused = False
        # a memoryview, never the bytearray: asyncio's TLS reader fills `buf[offset:]`,
        # which of a bytearray is a copy (a frame then decoded from stale bytes)
        self.scratch = memoryview(bytearray(SCRATCH))
        self.direct = False
        if held:  # bytes the stream reader took before the swap: a bad frame among them is
            # the first receive's error, as one read later would be (raised here, it left
            # the connection open and unread, and the node's accept with a traceback)
            try:
                self._take(self.decoder.feed(held))
            except ProtocolError as e:
                self.error = e
                transport.pause_reading()

    def get_buffer(self, sizehint: int):
        target = self.decoder.buffer(SCRATCH)
        self.direct = target is not None
        return target if self.direct else self.scratch

    def buffer_updated(self, nbytes: int) -> None:
        self.stats["bytes_in"] += nbytes
        try:
            if self.direct:
                self._take(self.decoder.wrote(nbytes))
            else:
                self._take(self.decoder.feed(self.scratch[:nbytes]))
        except ProtocolError as e:
            self.error = e
            self.transport.pause_reading()
        self._wake()

    def _take(self, messages: list) -> None:
        self.ready.extend(messages)
        if messages and not self.paused and self._queued_bytes() > READ_HIGH:
            self.paused = True
            self.transport.pause_reading()

    def _queued_bytes(self) -> int:
        return sum(_nbytes(m) for m in self.ready)

    def taken(self) -> None:
        """A message was taken: reading resumes once the rest are under READ_HIGH."""
        if self.paused and self._queued_bytes() <= READ_HIGH // 2 and self.error is None:
            self.paused = False
            self.transport.resume_reading()

    def _wake(self) -> None:
        if self.waiter is not None and not self.waiter.done():
            self.waiter.set_result(None)

    def eof_received(self):
        self.closed = True
        self._wake()
        return False  # close the transport

    def connection_lost(self, exc) -> None:
        self.closed = True
        if exc is not None and self.error is None:
            self.error = exc
        self._wake()
        self.stream.connection_lost(exc)

    def pause_writing(self) -> None:
        self.stream.pause_writing()

    def resume_writing(self) -> None:
        self.stream.resume_writing()


def _nbytes(message: dict) -> int:
    """The bytes of a decoded message's arrays (what it holds of the payload)."""
    return sum(v.nbytes for v in message.values() if isinstance(v, np.ndarray)) + 64
