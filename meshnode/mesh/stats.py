"""One node's statistics for one render: rays by kind, rays per link, busy and idle time.

Busy time is wall time with at least one batch on a tracing thread; CPU time is the tracing
threads' own, so a node sharing its core with others is not charged for their work.
"""

import resource
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from protocols.dtypes import LINK_TRAFFIC

RAY_KINDS = ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")
# What each counted event costs, in units of half a (binary) hierarchy step: fitted
# (non-negative least squares, one scale per scene) on each node's kernel CPU in simulated 2x2
# and 3x3 meshes of six SPD scenes, one process, one thread. Within a scene the CPU per unit
# spread 13% with tests + steps + segments + 8 per segment sent on; 5.5% with these. A step
# of the occupancy map costs four of a hierarchy's (a latency-bound chain of arithmetic and a
# table look-up per step; fitted before its divisions became multiplies, 10-15% less a walk
# since), a segment five (box spans, the ray's record, the stack), a test about half a step.
# Kept although the kernels changed since (a 4-wide hierarchy visit costs about 1.9 binary
# ones; a map walk about 60 ns to start and 9 ns a step since it takes the ray's octant):
# refitted to those (visit 4, walk 10, step 2), the pre-pass planned worse meshes, measured
# 3x3 under a quarter share in turns: teapot 2.13 against 3.42 and 3.29, balls 1.84 against
# 1.98 and 1.92, rings 2.83 against 2.69 and 2.66 (frame CPU speedup). Work units count only
# the kernels; a heavy map step also charges the passes whose routing and sending the
# kernels' units leave out. `occupancy_walks` is counted, not weighed. Charging the passes
# and the eye rays' routing at what they cost a node's process (fitted on 36 nodes' frame CPU
# less kernel CPU: 23 units a ray sent, 16 received, 23 an eye ray routed) planned worse
# too, measured 3x3 under a quarter share in turns (frame CPU speedup, one run each): teapot
# 2.87 against 4.12, balls 1.99 against 2.28 (fewer passes, 0.32 against 0.45, but kernels
# 2.79 against 3.98), tetra 2.75 against 2.94: the coarse pre-pass's passes do not scale
# as the render's do.
UNIT_WEIGHTS = {
    "intersection_tests": 1,
    "voxel_steps": 2,
    "occupancy_steps": 8,
    "ray_segments": 10,
    "rays_forwarded": 8,
}


def work_units(counts: dict) -> int:
    """A node's work in the engine's own units, the same on any machine at any load: its
    counted events weighted by what each costs (UNIT_WEIGHTS)."""
    return sum(w * counts.get(k, 0) for k, w in UNIT_WEIGHTS.items())


class NodeStats:
    def __init__(self, node: int):
        self.node = node
        self.counts: dict[str, int] = defaultdict(int)
        self.rays_in: dict[int, int] = defaultdict(int)  # neighbour -> rays received from it
        self.rays_out: dict[int, int] = defaultdict(int)  # next hop -> rays sent to it
        self.pixel_packets = 0
        self.ray_sets = 0  # RAYS_SET frames sent: several RAYS over one link in one frame
        self.relayed = 0  # rays received for another node and sent on toward it
        self.inline = 0  # passed batches traced on the event loop's thread (few rays)
        self.inline_cpu = 0.0  # ... their batches' CPU
        self.batches = 0
        self.cpu = 0.0  # in the engine's kernels: what one node's tracing CPU compares with
        self.batch_cpu = 0.0  # ... and routing rays and deposits around them (`NodeCore.trace`)
        self.busy = 0.0
        self.busy_since = 0.0
        self.busy_ended = 0.0
        self.started = time.perf_counter()

    def traced(self, counts: dict, primaries: int) -> None:
        """A batch finished: its counters, and the primary rays it started here."""
        self.batches += 1
        self.cpu += counts.pop("cpu_seconds")
        self.batch_cpu += counts.pop("batch_cpu_seconds", 0.0)
        add_counts(self.counts, counts, primaries)

    def turn_busy(self) -> None:
        self.busy_since = time.perf_counter()

    def turn_idle(self) -> None:
        self.busy_ended = time.perf_counter()
        self.busy += self.busy_ended - self.busy_since

    def live(self, links: dict[int, dict]) -> dict:
        """The PROGRESS message's live-view fields: busy and elapsed milliseconds (a busy
        span still open counts), rays of every kind traced here, each link's traffic."""
        now = time.perf_counter()
        busy = self.busy + (now - self.busy_since if self.busy_since > self.busy_ended else 0.0)
        traffic = np.zeros(len(links), LINK_TRAFFIC)
        for i, (m, s) in enumerate(sorted(links.items())):
            traffic[i] = (m, self.rays_out[m], s["bytes_out"])
        traced = sum(self.counts.get(k, 0) for k in RAY_KINDS)
        return {
            "busy_ms": int(busy * 1000),
            "elapsed_ms": int((now - self.started) * 1000),
            "traced": traced,
            "links": traffic,
        }

    def report(self, engine_stats: dict | None, links: dict[int, dict]) -> dict:
        """The STATS message's body; `links`: each neighbour link's byte counters."""
        elapsed = time.perf_counter() - self.started
        per_link = {
            str(m): dict(s, rays_sent=self.rays_out[m], rays_received=self.rays_in[m])
            for m, s in links.items()
        }
        return {
            "node": self.node,
            "objects": engine_stats["objects"] if engine_stats else 0,
            "engine": engine_stats or {},
            "rays": dict(self.counts),
            "rays_sent": sum(self.rays_out.values()),
            "rays_received": sum(self.rays_in.values()),
            "pixel_packets": self.pixel_packets,
            "batches": self.batches,
            "busy_seconds": self.busy,
            "busy_cpu_seconds": self.cpu,
            "batch_cpu_seconds": self.batch_cpu,
            "idle_seconds": max(elapsed - self.busy, 0.0),
            "links": per_link,
            "peak_rss_bytes": peak_rss(),
        }


def add_counts(into: dict, counts: dict, primaries: int) -> None:
    """Add one batch's counters (CPU seconds taken out) to a node's, with `primaries` new eye
    rays: eye rays are counted where they are made, not again where they are passed on."""
    for k, v in counts.items():
        if k not in ("eye_rays", "cpu_seconds", "batch_cpu_seconds"):
            into[k] += v
    into["eye_rays"] += primaries


def available_memory() -> int:
    """Bytes this node can give a render (0 when unknown): the system's MemAvailable, or
    what the container's cgroup limit leaves when that is less (a Kubernetes pod)."""
    free = 0
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                free = int(line.split()[1]) * 1024
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text())
            free = min(free, max(int(limit) - used, 0)) if free else max(int(limit) - used, 0)
    except (OSError, ValueError):
        pass
    return free


def peak_rss() -> int:
    """This process's peak resident memory in bytes (Linux reports KiB, macOS bytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)
