"""The live view's web server: the page, and a WebSocket that pushes the render to it.

aiohttp serves both (one well-kept library for HTTP and WebSocket, asyncio like the rest of
the host). It runs on its own thread and event loop, so single-node renders (a thread pool in
the main thread) and mesh renders (the mesh client's event loop) are watched the same way, and
a slow page never holds up the render. Each page gets a status message (JSON text) whenever the
monitor changes, at most every `interval` seconds, and a frame (binary: version as 4 bytes
little-endian, then a JPEG preview, or the final image's PNG) whenever there is a newer one.
"""

import asyncio
import ipaddress
import json
import struct
import threading
from importlib import resources

from aiohttp import WSCloseCode, WSMsgType, web

from host.live.monitor import Monitor

LOOPBACK = "127.0.0.1"
LOCAL_NAMES = {"localhost", "127.0.0.1", "::1"}


class LiveError(OSError):
    """The live view cannot be served (bad address, port taken); the message says which."""


def parse_address(text: str) -> tuple[str, int]:
    """`[HOST:]PORT` (an IPv6 host in brackets) to (host, port); loopback unless a host is
    given."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]") if sep else LOOPBACK
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535 or (sep and not host):
        raise ValueError(f"--serve {text!r}: expected [HOST:]PORT with PORT 0..65535")
    return host, number


class _Client:
    """One page's socket and what it has been sent."""

    def __init__(self, ws: web.WebSocketResponse):
        self.ws, self.wake, self.final_sent = ws, asyncio.Event(), False


class LiveServer:
    """Serves `monitor` at http://host:port/ from a thread of its own; `start` returns once
    the port is bound (or raises LiveError), `stop` closes every page's socket and the port."""

    def __init__(
        self, monitor: Monitor, host: str = LOOPBACK, port: int = 0, interval: float = 0.25
    ):
        self.monitor, self.host, self.port, self.interval = monitor, host, port, interval
        self.clients: set[_Client] = set()
        self.bound: list[tuple] = []
        self.loop: asyncio.AbstractEventLoop | None = None
        self.ready = threading.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="live-view", daemon=True)
        self.page = resources.files("host.live").joinpath("index.html").read_text("utf-8")

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def start(self) -> "LiveServer":
        self.thread.start()
        if not self.ready.wait(30):
            raise LiveError(f"the live view on {self.host}:{self.port} did not start in 30 s")
        if self.error is not None:
            raise LiveError(
                f"cannot serve the live view on {self.host}:{self.port}: {self.error}"
            ) from self.error
        self.monitor.listen(self._poke)
        return self

    def stop(self, timeout: float = 10.0) -> None:
        """Close the pages' sockets and the port; the thread ends (waited for `timeout`)."""
        if self.loop is not None and self.thread.is_alive():
            try:
                self.loop.call_soon_threadsafe(self._stopping.set)
            except RuntimeError:  # the loop already closed
                pass
        self.thread.join(timeout)

    def __enter__(self) -> "LiveServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def wait_delivered(self, timeout: float) -> bool:
        """Wait until every page connected has been sent the final frame (True), or
        `timeout` seconds (False): `--serve-exit` leaves after the pages have the result."""
        if self.loop is None or not self.thread.is_alive():
            return False
        future = asyncio.run_coroutine_threadsafe(self._delivered(), self.loop)
        try:
            future.result(timeout)
            return True
        except TimeoutError:
            future.cancel()
            return False

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as e:  # noqa: BLE001 - reported to start(), never lost
            self.error = self.error or e
            self.ready.set()

    async def _main(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        self._sent = asyncio.Event()
        app = web.Application()
        app.add_routes(
            [
                web.get("/", self._index),
                web.get("/ws", self._stream),
                web.get("/frame.png", self._frame),
                web.get("/status.json", self._status),
                web.get("/stats.json", self._stats),
            ]
        )
        app.on_shutdown.append(self._close_pages)
        runner = web.AppRunner(app, access_log=None, shutdown_timeout=2.0)
        await runner.setup()
        try:
            await web.TCPSite(runner, self.host, self.port).start()
            self.bound = [a[:2] for a in runner.addresses]  # (address, port) listened on
            self.port = self.bound[0][1]
        except OSError as e:
            self.error = e
            await runner.cleanup()
            self.ready.set()
            return
        self.ready.set()
        try:
            await self._stopping.wait()
        finally:
            await runner.cleanup()

    def _poke(self) -> None:
        """The monitor changed (called from the render's thread): wake every page's sender."""
        loop = self.loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._wake_all)
            except RuntimeError:  # closed between the check and the call
                pass

    def _wake_all(self) -> None:
        for client in self.clients:
            client.wake.set()

    async def _delivered(self) -> None:
        while not all(c.final_sent for c in self.clients):
            self._sent.clear()
            await self._sent.wait()

    async def _close_pages(self, app) -> None:
        for client in list(self.clients):
            await client.ws.close(code=WSCloseCode.GOING_AWAY, message=b"server stopping")

    # ------------------------------------------------------------------ requests
    def _trusted(self, request: web.Request) -> str | None:
        """Why a request is refused, or None. A page on another site must not read the render
        from the user's browser (the Origin must be this server), and a DNS name rebound to
        loopback must not either (bound to loopback, only loopback names are served)."""
        host = request.host
        if _loopback(self.host) and request.url.host not in LOCAL_NAMES:
            return f"host {host!r} is not this loopback server"
        origin = request.headers.get("Origin")
        if origin is not None and origin not in (f"http://{host}", f"https://{host}"):
            return f"origin {origin!r} is not this server"
        return None

    async def _index(self, request: web.Request) -> web.StreamResponse:
        if why := self._trusted(request):
            raise web.HTTPForbidden(text=f"refused: {why}\n")
        return web.Response(text=self.page, content_type="text/html", headers=NO_STORE)

    async def _status(self, request: web.Request) -> web.StreamResponse:
        if why := self._trusted(request):
            raise web.HTTPForbidden(text=f"refused: {why}\n")
        return web.json_response(self.monitor.status(), headers=NO_STORE, dumps=_dumps)

    async def _stats(self, request: web.Request) -> web.StreamResponse:
        if why := self._trusted(request):
            raise web.HTTPForbidden(text=f"refused: {why}\n")
        stats = self.monitor.status()["stats"]
        if stats is None:
            raise web.HTTPNotFound(text="no statistics yet: the render has not finished\n")
        return web.json_response(stats, headers=NO_STORE, dumps=_dumps)

    async def _frame(self, request: web.Request) -> web.StreamResponse:
        if why := self._trusted(request):
            raise web.HTTPForbidden(text=f"refused: {why}\n")
        frame = await asyncio.get_running_loop().run_in_executor(None, self.monitor.frame, True)
        if frame is None:
            raise web.HTTPNotFound(text="no frame yet: no pixels have arrived\n")
        return web.Response(body=frame[1], content_type="image/png", headers=NO_STORE)

    async def _stream(self, request: web.Request) -> web.StreamResponse:
        """Push status and frames to one page until it leaves or the server stops."""
        if why := self._trusted(request):
            raise web.HTTPForbidden(text=f"refused: {why}\n")
        ws = web.WebSocketResponse(heartbeat=30.0)
        await ws.prepare(request)
        client = _Client(ws)
        self.clients.add(client)
        reader = asyncio.ensure_future(_ignore_input(ws))
        loop = asyncio.get_running_loop()
        sent = -1
        try:
            while not reader.done() and not ws.closed:
                client.wake.clear()
                status, frame = self.monitor.status(), None
                if status["frame"] != sent:
                    frame = await loop.run_in_executor(None, self.monitor.frame)
                    if frame is not None and frame[0] != status["frame"]:
                        status = self.monitor.status()  # as new as the frame, not older
                await ws.send_str(_dumps(status))
                if frame is not None and frame[0] != sent:
                    await ws.send_bytes(struct.pack("<I", frame[0]) + frame[1])
                    sent = frame[0]
                if status["final"] and sent >= status["frame"] and not client.final_sent:
                    client.final_sent = True
                    self._sent.set()
                sent_at = loop.time()
                woken = asyncio.ensure_future(client.wake.wait())
                await asyncio.wait([woken, reader], return_when=asyncio.FIRST_COMPLETED)
                woken.cancel()
                # throttle: a few messages a second at most, but a change after a quiet spell
                # (the first pixels after the build) goes out at once
                rest = sent_at + self.interval - loop.time()
                if not reader.done() and rest > 0:
                    await asyncio.wait([reader], timeout=rest)
        except ConnectionError:  # the page went away mid-send
            pass
        finally:
            self.clients.discard(client)
            self._sent.set()
            reader.cancel()
            await asyncio.gather(reader, return_exceptions=True)
            await ws.close()
        return ws


NO_STORE = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff"}


def _dumps(value) -> str:
    return json.dumps(value, allow_nan=False)


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


async def _ignore_input(ws: web.WebSocketResponse) -> None:
    """Read until the page closes (pages send nothing the server acts on)."""
    async for message in ws:
        if message.type == WSMsgType.ERROR:
            return
