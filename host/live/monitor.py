"""What the live view knows of a render: the framebuffer as it fills in, every node's state and
traffic, progress and ETA, and at the end the final image and statistics.

The render calls in from its own thread (the single-node loop, or the mesh client's event
loop); the web server reads from another. One lock guards the state, and the framebuffer is
copied at most `interval` seconds apart (a memcpy in the render's thread; the PNG is made in
the server's), so the render never waits on a page. On big images copies are further apart:
copying and encoding a frame may take at most a tenth of the time between frames (BUDGET).
"""

import io
import math
import threading
import time

import numpy as np

from host.run.framebuffer import Framebuffer, to_srgb8
from protocols.state import State

STATES = [s.name.lower() for s in State]  # a node's state by its number in PROGRESS
RAY_KINDS = ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")
BUDGET = 0.1  # share of the time between frames spent copying and encoding one


class Monitor:
    """The observed render. Render side: `start`, `pixels`, `local`, `node`, `finish`,
    `fail`; server side: `status`, `frame`, `listen`."""

    def __init__(self, interval: float = 0.25):
        self.interval = interval
        self.lock = threading.Lock()
        self.listeners: list = []
        self.phase = "preparing"  # preparing -> tracing -> done | failed
        self.error = ""
        self.width = self.height = 0
        self.rows = self.cols = 1
        self.unit = "rays"
        self.total: int | None = None
        self.done = 0
        self.began = self.started = time.monotonic()
        self.first_work: float | None = None  # when tracing began: compile time is not rate
        self.ended: float | None = None
        self.nodes: list[dict] = []
        self.fb: Framebuffer | None = None
        self.snapshot: Framebuffer | None = None
        self.next_copy = -math.inf  # the first pixels are copied at once
        self.cost = 0.0  # seconds the last frame took to copy and encode
        self.version = 0  # of the frame
        self.final: np.ndarray | None = None  # 8-bit sRGB, the PNG the render writes
        self.stats: dict | None = None
        self.png: tuple[int, bytes] | None = None

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
        """Tracing is about to begin on `rows` x `cols` nodes holding `objects` each; `total`
        units of progress (None: not known ahead, as with camera rays lost in the lens)."""
        with self.lock:
            self.fb, self.rows, self.cols = fb, rows, cols
            self.width, self.height = fb.width, fb.height
            self.total, self.unit, self.phase = total, unit, "tracing"
            self.started = time.monotonic()
            self.nodes = [_node(n, cols, objects[n]) for n in range(rows * cols)]
        self._changed()

    def pixels(self) -> None:
        """Deposits were added to the framebuffer: copy it if the last copy is old enough."""
        now = time.monotonic()
        if self.fb is None or now < self.next_copy:
            return
        copy = Framebuffer(self.fb.width, self.fb.height, self.fb.corners, self.fb.spp)
        copy.sums = self.fb.sums.copy()
        copied = time.monotonic() - now
        with self.lock:
            self.snapshot = copy
            self.next_copy = now + max(self.interval, (copied + self.cost) / BUDGET)
            self.version += 1
        self._changed()

    def local(self, done: int, totals: dict, cpu: float, threads: int) -> None:
        """Single-node progress: `done` jobs traced, the ray counters and tracing CPU seconds
        so far on `threads` threads (busy share: CPU over wall time of all threads)."""
        with self.lock:
            self._work(done - self.done)
            self.done = done
            node = self.nodes[0]
            wall = max(time.monotonic() - self.started, 1e-9)
            node.update(
                state="trace",
                ready=True,
                traced=_traced(totals),
                busy=min(cpu / (wall * threads), 1.0),
            )
        self.pixels()
        self._changed()

    def node(self, n: int, f: dict) -> None:
        """A PROGRESS from node `n` (fields parsed by protocols.messages, checked here against
        the mesh: a state or peer outside it is shown as unknown, never trusted)."""
        with self.lock:
            if not 0 <= n < len(self.nodes):
                return
            self._work(f["rays"])
            self.done += f["rays"]
            state = STATES[f["state"]] if f["state"] < len(STATES) else "unknown"
            links = [
                {"peer": int(p), "rays": int(r), "bytes": int(b)}
                for p, r, b in f["links"].tolist()
                if 0 <= p < len(self.nodes)
            ]
            busy = f["busy_ms"] / f["elapsed_ms"] if f["elapsed_ms"] else 0.0
            self.nodes[n].update(
                state=state,
                ready=f["ready"],
                traced=f["traced"],
                objects=f["objects"],
                busy=min(busy, 1.0),
                links=links,
            )
        self.pixels()
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
            self.phase, self.ended = "done", time.monotonic()
            self.version += 1
            self._final_nodes(stats)
        self._changed()

    def fail(self, message: str) -> None:
        with self.lock:
            self.phase, self.error, self.ended = (
                "failed",
                message or "render failed",
                time.monotonic(),
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
            now = self.ended or time.monotonic()
            return {
                "phase": self.phase,
                "error": self.error,
                "width": self.width,
                "height": self.height,
                "rows": self.rows,
                "cols": self.cols,
                "frame": self.version,
                "final": self.final is not None,
                "progress": self._progress(now),
                "nodes": [dict(n) for n in self.nodes],
                "stats": strict(self.stats) if self.stats is not None else None,
            }

    def frame(self) -> tuple[int, bytes] | None:
        """(version, PNG) of the newest frame: the final image once there is one."""
        with self.lock:
            version, final, snap, cached = self.version, self.final, self.snapshot, self.png
        if cached is not None and cached[0] == version:
            return cached
        began = time.monotonic()
        if final is not None:
            rgb = final
        elif snap is not None:
            rgb = to_srgb8(snap.image())
        else:
            return None
        png = (version, encode_png(rgb))
        with self.lock:
            self.cost = time.monotonic() - began
            if self.version == version:
                self.png = png
        return png

    # ------------------------------------------------------------------ inside
    def _changed(self) -> None:
        for callback in list(self.listeners):
            callback()

    def _work(self, amount: int) -> None:
        if amount > 0 and self.first_work is None:
            self.first_work = time.monotonic()

    def _progress(self, now: float) -> dict:
        """Done and total units, rate since tracing began, and the ETA it gives."""
        spent = now - self.first_work if self.first_work is not None else 0.0
        rate = self.done / spent if spent > 0 else 0.0
        fraction = min(self.done / self.total, 1.0) if self.total else None
        if self.phase == "done":
            fraction = 1.0
        eta = None
        if self.phase == "tracing" and self.total and rate > 0 and spent >= 1.0:
            eta = max(self.total - self.done, 0) / rate
        return {
            "done": self.done,
            "total": self.total,
            "unit": self.unit,
            "fraction": fraction,
            "rate": rate,
            "eta_seconds": eta,
            "elapsed_seconds": now - self.began,
        }

    def _final_nodes(self, stats: dict) -> None:
        """Node panels from the statistics (the figures the STATS messages carried)."""
        if "nodes" not in stats:  # one process
            node = self.nodes[0] if self.nodes else _node(0, 1, 0)
            threads = stats.get("threads", 1)
            wall = max(stats.get("trace_seconds", 0.0), 1e-9)
            busy = stats.get("trace_cpu_seconds", 0.0) / (wall * threads)
            node.update(
                state="done",
                traced=_traced(stats["rays"]),
                busy=min(busy, 1.0),
                objects=stats["engine"]["objects"],
            )
            self.nodes = [node]
            return
        nodes = []
        tiles = stats.get("tiles_per_node") or [0] * len(stats["nodes"])
        for n, s in enumerate(stats["nodes"]):
            total = s["busy_seconds"] + s["idle_seconds"]
            links = [
                {"peer": int(p), "rays": v["rays_sent"], "bytes": v["bytes_out"]}
                for p, v in sorted(s["links"].items(), key=lambda kv: int(kv[0]))
            ]
            node = _node(n, self.cols, s["objects"])
            node.update(
                state="done",
                ready=True,
                traced=_traced(s["rays"]),
                links=links,
                busy=s["busy_seconds"] / total if total > 0 else 0.0,
                tiles=tiles[n],
            )
            nodes.append(node)
        self.nodes = nodes


def _node(n: int, cols: int, objects: int) -> dict:
    return {
        "node": n,
        "row": n // cols,
        "col": n % cols,
        "state": "download",
        "ready": False,
        "busy": 0.0,
        "traced": 0,
        "objects": objects,
        "links": [],
        "tiles": 0,
    }


def _traced(rays: dict) -> int:
    """Rays of every kind traced (shadow rays included; the counts' other keys are not rays)."""
    return int(sum(rays.get(k, 0) for k in RAY_KINDS))


def encode_png(rgb: np.ndarray) -> bytes:
    """8-bit RGB as PNG bytes, fast compression: frames go out several times a second."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(out, format="PNG", compress_level=1)
    return out.getvalue()


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
