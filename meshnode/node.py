"""What one mesh node does with rays, without any sockets: the service wraps this.

A node holds the objects touching its box and every node's box. It makes the primary rays of
its rectangle, traces batches (incoming rays first), turns colour into deposits for the pixel
packets, and sorts the rays that leave its box by the node that takes them on.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from meshnode.adaptive import AdaptiveFilm, deposit_routes
from meshnode.engine import Engine
from meshnode.engine.camera import eye_rays
from meshnode.engine.lenscamera import camera_batches, camera_rays, rect_pixels
from meshnode.engine.trace import owners
from protocols.camera import CameraRays
from protocols.dtypes import DEPOSIT, RAY
from protocols.scene import SceneData, View


@dataclass
class Batch:
    """The outcome of tracing one batch on one node."""

    deposits: np.ndarray  # DEPOSIT records, one per traced ray that left colour
    outgoing: dict[int, np.ndarray]  # node -> RAY records it takes on
    counts: dict[str, int] = field(default_factory=dict)


class NodeCore:
    """One node's engine and routing. `los`/`his` are every node's box, `node` indexes them."""

    def __init__(self, node: int, scene: SceneData, los, his, scene_box, *, density=1.0,
                 storage="auto", max_depth=5):  # fmt: skip
        self.node = node
        self.los, self.his = np.asarray(los, float), np.asarray(his, float)
        self.engine = Engine(scene, box=(self.los[node], self.his[node]), scene_box=scene_box,
                             density=density, storage=storage, max_depth=max_depth)  # fmt: skip
        self.camera: CameraRays | None = None
        self.film: AdaptiveFilm | None = None

    def warmup(self) -> None:
        """Compile or load every kernel a render will call, before any is timed."""
        self.engine.warmup()
        ray = np.zeros(1, RAY)
        ray["d"] = (0.0, 0.0, 1.0)
        ray["t_max"] = np.inf
        owners(ray, self.los, self.his)

    def primary(self, view, width, height, corners, spp, seed, rect) -> np.ndarray:
        """Eye rays of this node's rectangle (x0, x1, y0, y1) of the sample grid."""
        x0, x1, y0, y1 = rect
        return eye_rays(view, width, height, corners, spp, seed, rows=(y0, y1), cols=(x0, x1))

    def use_camera(self, spec: CameraRays | None, width: int, height: int, rects) -> None:
        """Primary rays from this camera (None: the pinhole); under adaptive sampling this
        node keeps the books of its own pixels and every deposit comes back to its owner."""
        self.camera, self.width, self.height = spec, width, height
        self.rects = [tuple(r) for r in rects]
        self.film = None
        if spec is not None and spec.adaptive:
            self.film = AdaptiveFilm(spec, self.rects[self.node], width, height)
        if spec is not None:  # compile or load the camera kernels now, not mid-render
            camera_rays(spec, View((0, 0, 0), (0, 0, 1), (0, 1, 0), 45.0), 1, 1, np.zeros(1, int))

    def camera_pass(self, view, width, height, second: bool):
        """Batches of camera rays of this node's rectangle: every ray, or adaptive sampling's
        first pass (corner rays) or second (the rest, where the corners differ)."""
        if self.film is not None:
            return (self.film.pass2 if second else self.film.pass1)(view, width, height)
        if second:
            return iter(())
        pixels = rect_pixels(self.rects[self.node], width)
        return camera_batches(self.camera, view, width, height, pixels)

    def pixel_routes(self, deposits: np.ndarray) -> dict[int, np.ndarray]:
        """Deposits by the node they go to: node 0 (then the host), or under adaptive
        sampling the node owning each deposit's pixel (and pass-1 ones to the halos)."""
        if self.film is None or len(deposits) == 0:
            return {0: deposits} if len(deposits) else {}
        f = self.film
        idx, dest = deposit_routes(deposits["pixel"], f.n, f.first, self.width, self.height,
                                   self.rects)  # fmt: skip
        return _group(deposits[idx], dest)

    def trace(self, rays: np.ndarray) -> Batch:
        cpu = time.thread_time()
        rgb, counts, passed = self.engine.trace_node(rays)
        counts["cpu_seconds"] = time.thread_time() - cpu
        lit = np.any(rgb != 0.0, axis=1)
        deposits = np.zeros(int(lit.sum()), DEPOSIT)
        deposits["pixel"] = rays["pixel"][lit]
        deposits["rgb"] = rgb[lit]
        return Batch(deposits, self.route(passed), counts)

    def route(self, rays: np.ndarray) -> dict[int, np.ndarray]:
        """Rays grouped by the node that takes them on."""
        if len(rays) == 0:
            return {}
        dest = owners(rays, self.los, self.his)
        if (dest < 0).any():
            raise RuntimeError(f"node {self.node}: {int((dest < 0).sum())} rays have no owner box")
        return _group(rays, dest)


def _group(records: np.ndarray, dest: np.ndarray) -> dict[int, np.ndarray]:
    """Records grouped by destination node (one sort, no loop per record)."""
    order = np.argsort(dest, kind="stable")
    nodes, starts = np.unique(dest[order], return_index=True)
    groups = np.split(records[order], starts[1:])
    pairs = zip(nodes.tolist(), groups, strict=True)
    return {n: np.ascontiguousarray(g) for n, g in pairs}
