"""One raw connection to the node under test, below the project's link layer: it sends any
bytes (malformed ones too), decodes frames of any size and turns silence into `Hang`."""

import asyncio
import time

from bench.fuzz.node import CLUSTER, SECRET
from protocols.framing import MAX_FRAME, FrameDecoder, encode
from protocols.handshake import auth, check_auth, check_hello, hello, nonce
from protocols.messages import Kind, make, parse

CASE_TIMEOUT = 15.0  # s: the node drops a stalled handshake after 10 s


class Hang(Exception):
    """A case got neither an answer nor a refusal within its timeout."""


class Conn:
    """One raw connection to the node, with its own frame decoder (any frame size)."""

    def __init__(self, reader, writer):
        self.reader, self.writer = reader, writer
        self.decoder = FrameDecoder(MAX_FRAME)
        self.ready: list[dict] = []
        self.eof = False

    @classmethod
    async def open(cls, port: int) -> "Conn":
        """A connection to the node on loopback, within the case timeout."""
        reader, writer = await asyncio.wait_for(
            asyncio.open_connection("127.0.0.1", port), CASE_TIMEOUT
        )
        return cls(reader, writer)

    def send(self, data: bytes) -> bool:
        """Write unless the node has hung up; False once it has."""
        if self.eof or self.writer.is_closing():
            return False
        try:
            self.writer.write(data)
        except (ConnectionError, RuntimeError):
            self.eof = True
            return False
        return True

    def end(self) -> None:
        """Send our end of file (half-close), so the node must hang up too."""
        try:
            if not self.writer.is_closing():
                self.writer.write_eof()
        except (OSError, RuntimeError):
            pass

    async def recv(self, timeout: float = CASE_TIMEOUT) -> dict | None:
        """The next message, or None once the node has closed the connection."""
        deadline = time.monotonic() + timeout
        while not self.ready:
            if self.eof:
                return None
            left = deadline - time.monotonic()
            if left <= 0:
                raise Hang("no message and no close")
            try:
                data = await asyncio.wait_for(self.reader.read(1 << 20), left)
            except (ConnectionError, OSError):
                data = b""
            except TimeoutError:
                raise Hang("no message and no close") from None
            if not data:
                self.eof = True
                continue
            self.ready.extend(self.decoder.feed(data))
        return self.ready.pop(0)

    async def until_closed(self, timeout: float = CASE_TIMEOUT) -> list[dict]:
        """Every message until the node closes the connection (Hang if it does not)."""
        got = []
        deadline = time.monotonic() + timeout
        while (m := await self.recv(max(0.01, deadline - time.monotonic()))) is not None:
            got.append(m)
        return got

    async def answer(self, timeout: float = CASE_TIMEOUT) -> str:
        """How the node took what we sent: 'refused' (ERROR and/or close) or 'answered'."""
        m = await self.recv(timeout)
        if m is None or m.get("k") == Kind.ERROR:
            return "refused"
        return "answered"

    async def expect(self) -> dict:
        """The next message; ConnectionError if the node hangs up first (a full node)."""
        m = await self.recv()
        if m is None:
            raise ConnectionError("the node closed the connection")
        return m

    async def handshake(
        self, role: str = "host", node: int = -1, secret: bytes = SECRET, render: bytes = b""
    ):
        """The dialler's side of protocols.handshake; returns the node's HELLO fields."""
        mine = parse(hello(CLUSTER, role, node, nonce(), render))[1]
        self.send(encode(make(Kind.HELLO, **mine)))
        theirs = check_hello(await self.expect(), CLUSTER)
        check_auth(await self.expect(), SECRET, "listener", mine, theirs["nonce"])
        self.send(encode(auth(secret, "dialler", mine, theirs["nonce"])))
        welcome = await self.recv()
        if welcome is None or welcome.get("k") != Kind.WELCOME:
            raise ConnectionError(f"handshake refused: {welcome}")
        return theirs

    async def close(self) -> None:
        """Close our side, waiting at most 5 s."""
        self.writer.close()
        try:
            await asyncio.wait_for(self.writer.wait_closed(), 5)
        except (OSError, RuntimeError, TimeoutError):
            pass
