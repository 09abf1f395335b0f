"""What the live view knows of a render: the framebuffer as it fills in, every node's state and
traffic, progress and ETA, and at the end the final image and statistics.

The render calls in from its own thread (the single-node loop, or the mesh client's event
loop); the web server reads from another. One lock guards the state, and the framebuffer is
copied at most `interval` seconds apart (a memcpy in the render's thread; the PNG is made in
the server's), so the render never waits on a page. On big images copies are further apart:
copying and encoding a frame may take at most a fifth of the time between frames (BUDGET),
and frames are at most LONGEST apart.
Frames before the end are previews, JPEG of an sRGB read from a table (a 1024x1024 frame
in about 25 ms, where the exact PNG took 200 ms and, under load, set the next copy ten
seconds off); the final frame is the exact PNG the render wrote. Frames are encoded in
`frames`; node panels and the final figures are made in `figures`.

Progress counts primary rays (or one process's batches) from the first traced one; rates
and the ETA are over the last WINDOW seconds, not since the start: the showcase traces its
sky, half its primary rays, in a seventh of the time.
"""

import math
import threading
import time
from collections import deque

import numpy as np

from host.live.figures import final_figures, final_nodes, node_panel, rays_traced
from host.live.frames import encode_jpeg, encode_png, preview_srgb8
from host.run.framebuffer import Framebuffer, to_srgb8
from protocols.messages import SETUP_STEPS
from protocols.state import State

STATES = [s.name.lower() for s in State]  # a node's state by its number in PROGRESS
BUDGET = 0.2  # share of the time between frames spent copying and encoding one
LONGEST = 2.0  # seconds between frames at most (a cost measured under load runs long)
WINDOW = 5.0  # seconds the recent rates (and so the ETA) are measured over


class Monitor:
    """The observed render. Render side: `start`, `pixels`, `local`, `node`, `finish`,
    `fail`; server side: `status`, `frame`, `listen`."""

    def __init__(self, interval: float = 0.25, clock=time.monotonic):
        self.interval, self.clock = interval, clock  # clock: seconds (tests set their own)
        self.lock = threading.Lock()
        self.listeners: list = []
        self.phase = "preparing"  # preparing -> building (a mesh) -> tracing -> done | failed
        self.error = ""
        self.width = self.height = 0
        self.rows = self.cols = 1
        self.unit = "rays"
        self.total: int | None = None
        self.done = 0
        self.began = self.clock()
        self.started: float | None = None  # when the render on the nodes began (`start`)
        self.first_work: float | None = None  # when tracing began: compile time is not rate
        self.ended: float | None = None
        self.nodes: list[dict] = []
        self.since: list[float] = []  # when each node's setup step began (monitor's clock)
        self.primary = Recent()  # primary units done, over the last WINDOW seconds
        self.traced = Recent()  # rays of every kind traced, all nodes
        self.node_rates: list[Recent] = []
        self.figures: dict | None = None  # the final figures, from the statistics
        self.fb: Framebuffer | None = None
        self.snapshot: Framebuffer | None = None
        self.next_copy = -math.inf  # the first pixels are copied at once
        self.dirty = False  # deposits came since the last copy
        self.cost = 0.0  # seconds the last frame took to copy and encode
        self.version = 0  # of the frame
        self.frame_done = 0  # progress's `done` when that frame's pixels were copied
        self.final: np.ndarray | None = None  # 8-bit sRGB, the PNG the render writes
        self.stats: dict | None = None
        self.encoded: dict[bool, tuple[int, bytes]] = {}  # png? -> (version, bytes)

    # ------------------------------------------------------------------ render side
    def start(
        self,
        fb: Framebuffer,
        rows: int,
        cols: int,
        objects: list[int],
        total: int | None,
        unit: str = "rays",
    ) -> None:
        """The render begins on `rows` x `cols` nodes holding `objects` each (a mesh's nodes
        build their engines first; one process calls this as it starts tracing); `total`
        units of progress (None: not known ahead, as with camera rays lost in the lens). A
        re-planned frame (a node lost) calls it again: the count starts over."""
        one = rows * cols == 1 and unit == "batches"
        now = self.clock()
        with self.lock:
            self.fb, self.rows, self.cols = fb, rows, cols
            self.width, self.height = fb.width, fb.height
            self.total, self.unit, self.done = total, unit, 0
            self.phase = "tracing" if one else "building"
            self.started = now if self.started is None else self.started
            self.nodes = [node_panel(n, cols, objects[n], one) for n in range(rows * cols)]
            self.since = [now] * len(self.nodes)
            self.primary, self.traced = Recent(), Recent()
            self.node_rates = [Recent() for _ in self.nodes]
            self.snapshot, self.next_copy, self.dirty = None, -math.inf, False
        self._changed()

    def pixels(self, arrived: bool = True) -> None:
        """Deposits were added to the framebuffer (`arrived`; False: a heartbeat's refresh):
        copy it if it changed and the last copy is old enough. Only changes are copied, so
        the first deposits after the build go out at once (a copy of the empty frame on a
        heartbeat had put them off by up to a second)."""
        now = self.clock()
        if arrived and self.fb is not None:
            self.dirty = True
            if self.first_work is None:
                with self.lock:  # object space: deposits may come before the first PROGRESS
                    self._began(now)
        if self.fb is None or not self.dirty or now < self.next_copy:
            return
        self.dirty = False
        copy = Framebuffer(self.fb.width, self.fb.height, self.fb.corners, self.fb.spp)
        copy.sums = self.fb.sums.copy()
        copied = self.clock() - now
        gap = min(max(self.interval, (copied + self.cost) / BUDGET), LONGEST)
        with self.lock:
            self.snapshot, self.next_copy = copy, now + gap
            self.version += 1
            self.frame_done = self.done
        self._changed()

    def local(self, done: int, totals: dict, cpu: float, threads: int) -> None:
        """Single-node progress: `done` jobs traced (their deposits added), the ray counters
        and tracing CPU seconds so far on `threads` threads (busy share: CPU over wall time
        of all threads)."""
        now = self.clock()
        with self.lock:
            self._work(done - self.done, now)
            node = self.nodes[0]
            wall = max(now - self.started, 1e-9)
            busy = min(cpu / (wall * threads), 1.0)
            node.update(state="trace", ready=True, busy=busy)
            self._counted(now, 0, rays_traced(totals))
        self.pixels()  # the job's deposits are in the framebuffer
        self._changed()

    def node(self, n: int, f: dict) -> None:
        """A PROGRESS from node `n` (fields parsed by protocols.messages, checked here against
        the mesh: a state or peer outside it is shown as unknown, never trusted)."""
        now = self.clock()
        with self.lock:
            if not 0 <= n < len(self.nodes):
                return
            self._work(f["rays"], now)
            state = STATES[f["state"]] if f["state"] < len(STATES) else "unknown"
            setup = SETUP_STEPS[f["setup"]] if f["setup"] < len(SETUP_STEPS) else "unknown"
            if setup != self.nodes[n]["setup"]:
                self.since[n] = now
            links = [
                {"peer": int(p), "rays": int(r), "bytes": int(b)}
                for p, r, b in f["links"].tolist()
                if 0 <= p < len(self.nodes)
            ]
            busy = f["busy_ms"] / f["elapsed_ms"] if f["elapsed_ms"] else 0.0
            self.nodes[n].update(
                state=state,
                ready=f["ready"],
                setup=setup,
                objects=f["objects"],
                busy=min(busy, 1.0),
                links=links,
            )
            self._counted(now, n, f["traced"])
            if self.phase == "building" and all(node["ready"] for node in self.nodes):
                self.phase = "tracing"
        self.pixels(arrived=False)
        self._changed()

    def tiles(self, n: int, count: int) -> None:
        """Node `n` started the last rays of `count` more dynamic image-space tiles."""
        with self.lock:
            if 0 <= n < len(self.nodes):
                self.nodes[n]["tiles"] += count
        self._changed()

    def finish(self, image: np.ndarray, stats: dict) -> None:
        """The render is done: its image and statistics, and every node's final figures."""
        final = to_srgb8(image)
        with self.lock:
            self.final, self.stats = final, stats
            self.width, self.height = image.shape[1], image.shape[0]
            self.phase, self.ended = "done", self.clock()
            self.version += 1
            self.frame_done = self.done
            self.figures = final_figures(stats)
            self.nodes = final_nodes(stats, self.nodes, self.cols)
        self._changed()

    def fail(self, message: str) -> None:
        with self.lock:
            self.phase, self.error, self.ended = (
                "failed",
                message or "render failed",
                self.clock(),
            )
        self._changed()

    # ------------------------------------------------------------------ server side
    def listen(self, callback) -> None:
        """`callback()` runs (in the render's thread) whenever something changed."""
        with self.lock:
            self.listeners.append(callback)

    def status(self) -> dict:
        """Everything but the pixels, as JSON-ready values."""
        with self.lock:
            now = self.ended if self.ended is not None else self.clock()
            return {
                "phase": self.phase,
                "error": self.error,
                "width": self.width,
                "height": self.height,
                "rows": self.rows,
                "cols": self.cols,
                "frame": self.version,
                "frame_done": self.frame_done,
                "final": self.final is not None,
                "progress": self._progress(now),
                "nodes": [self._shown(n, node, now) for n, node in enumerate(self.nodes)],
                "stats": strict(self.stats) if self.stats is not None else None,
            }

    def frame(self, png: bool = False) -> tuple[int, bytes] | None:
        """(version, image bytes) of the newest frame: the final image's PNG once there is
        one, before it a JPEG preview (`png`: a PNG preview, for /frame.png)."""
        with self.lock:
            version, final, snap = self.version, self.final, self.snapshot
            cached = self.encoded.get(png or final is not None)
        if cached is not None and cached[0] == version:
            return cached
        began = time.thread_time()  # this thread's work: waits for the GIL are not cost
        if final is not None:
            png, data = True, encode_png(final)
        elif snap is not None:
            rgb = preview_srgb8(snap)
            data = encode_png(rgb) if png else encode_jpeg(rgb)
        else:
            return None
        with self.lock:
            if not png:
                self.cost = time.thread_time() - began
            if self.version == version:
                self.encoded[png] = (version, data)
        return version, data

    # ------------------------------------------------------------------ inside
    def _changed(self) -> None:
        for callback in list(self.listeners):
            callback()

    def _work(self, amount: int, now: float) -> None:
        """`amount` more units done (none: a heartbeat): the count and its recent rate."""
        if amount > 0:
            self._began(now)
            self.done += amount
            self.primary.add(now, self.done)

    def _began(self, now: float) -> None:
        """Work was done: tracing has begun (rates count from here, not from the build)."""
        if self.first_work is None:
            self.first_work = now
            self.primary.add(now, self.done)  # the rate's first anchor
        if self.phase == "building":
            self.phase = "tracing"

    def _counted(self, now: float, n: int, traced: int) -> None:
        """Node `n` has traced `traced` rays in all: its recent rate, and the mesh's."""
        self.nodes[n]["traced"] = traced
        self.node_rates[n].add(now, traced)
        self.traced.add(now, sum(node["traced"] for node in self.nodes))

    def _progress(self, now: float) -> dict:
        """Done and total units, the recent rates and the ETA they give, elapsed seconds
        since the render began; once done, the statistics' figures (`final_figures`)."""
        fraction = min(self.done / self.total, 1.0) if self.total else None
        traced = sum(node["traced"] for node in self.nodes)
        rate = self.primary.rate(now, self.done)
        tracing = self.first_work is not None and now - self.first_work >= 1.0
        eta = None
        if self.phase == "tracing" and self.total and rate > 0 and tracing:
            eta = max(self.total - self.done, 0) / rate
        elapsed = now - (self.started or self.began)
        progress = {
            "done": self.done,
            "total": self.total,
            "unit": self.unit,
            "fraction": fraction,
            "rate": rate,
            "eta_seconds": eta,
            "traced": traced,
            "rays_per_second": self.traced.rate(now, traced),
            "elapsed_seconds": elapsed,
            "started": self.started is not None,
        }
        if self.figures is not None:  # done: the figures the command line prints
            progress.update(
                fraction=1.0,
                traced=self.figures["rays"],
                rays_per_second=self.figures["rays_per_second"],
                elapsed_seconds=self.figures["seconds"],
                final=self.figures,
            )
        return progress

    def _shown(self, n: int, node: dict, now: float) -> dict:
        """Node `n` as the page gets it: with its recent rays/s and how long it has been
        at its setup step."""
        shown = dict(node)
        if "rays_per_second" not in node:  # a final node has its own, from the stats
            shown["rays_per_second"] = self.node_rates[n].rate(now, node["traced"])
        shown["setup_seconds"] = now - self.since[n] if n < len(self.since) else 0.0
        return shown


class Recent:
    """A count's rate over about the last `window` seconds: the latest point at or before
    the window's start is kept as the anchor, so a stall brings the rate down as it lasts."""

    def __init__(self, window: float = WINDOW):
        self.window, self.points = window, deque()

    def add(self, t: float, value: int) -> None:
        self.points.append((t, value))
        self._trim(t)

    def rate(self, now: float, value: int) -> float:
        """Per second, from the anchor to (`now`, `value`); 0 before any span."""
        self._trim(now)
        if not self.points:
            return 0.0
        t0, v0 = self.points[0]
        return (value - v0) / (now - t0) if now > t0 else 0.0

    def _trim(self, now: float) -> None:
        while len(self.points) > 1 and self.points[1][0] <= now - self.window:
            self.points.popleft()


def strict(value):
    """`value` with every non-finite float as null: browsers' JSON has no NaN or Infinity."""
    if isinstance(value, dict):
        return {str(k): strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, np.generic):
        return strict(value.item())
    return value
