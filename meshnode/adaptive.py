"""Adaptive sampling's bookkeeping for the pixels one node owns (DESIGN.md 7).

Pass 1 traces two rays per pixel, at opposite corners of the sampled area; a pixel gets its
other rays in pass 2 only if those two colours differ by more than the threshold. A ray's
colour is known only when all its descendants have ended, possibly on other nodes, so under
adaptive sampling every deposit travels to the node owning its pixel, and the two passes are
two states of the ring's state machine. The owner alone knows how many rays each of its pixels
got (and how many left the camera), so it divides and sends finished pixels to the host.
"""

import numpy as np

from meshnode.engine.lenscamera import camera_rays, first_pass
from protocols.camera import CameraRays

RAYS_PER_BATCH = 16384  # camera rays made at a time: memory stays bounded at any spp


def owner_of(pixels: np.ndarray, width: int, rects) -> np.ndarray:
    """Index of the rectangle (x0, x1, y0, y1) holding each pixel (-1: none)."""
    x, y = pixels % width, pixels // width
    owner = np.full(len(pixels), -1, np.int64)
    for n, (x0, x1, y0, y1) in enumerate(rects):  # one mask per node, not per pixel
        owner[(x >= x0) & (x < x1) & (y >= y0) & (y < y1)] = n
    return owner


class AdaptiveFilm:
    """Colour sums, ray counts and the pass-1 corner colours of a node's own pixels."""

    def __init__(self, spec: CameraRays, pixels: np.ndarray):
        self.spec = spec
        self.n = spec.per_pixel
        self.first = first_pass(spec)
        self.pixels = np.asarray(pixels, np.int64)
        self.order = np.argsort(self.pixels, kind="stable")
        p = len(self.pixels)
        self.sums = np.zeros((p, 3))
        self.corner = np.zeros((p, 2, 3))
        self.corner_alive = np.zeros((p, 2), np.bool_)
        self.rays = np.zeros(p, np.int64)  # divisor: rays generated (or that left, "left")
        self.refined = np.zeros(p, np.bool_)

    def _local(self, pixels: np.ndarray) -> np.ndarray:
        at = np.searchsorted(self.pixels, pixels, sorter=self.order)
        i = self.order[np.minimum(at, len(self.pixels) - 1)]
        if np.any(self.pixels[i] != pixels):
            raise ValueError("a deposit for a pixel this node does not own")
        return i

    def _chunks(self, idx: np.ndarray, per_pixel: int):
        step = max(1, RAYS_PER_BATCH // max(per_pixel, 1))
        return (idx[i : i + step] for i in range(0, len(idx), step))

    def pass1(self, view, width, height):
        """Batches of the two corner rays of every owned pixel."""
        for idx in self._chunks(np.arange(len(self.pixels)), 2):
            rays, alive = camera_rays(self.spec, view, width, height, self.pixels[idx], self.first)
            self.corner_alive[idx] = alive
            self._count(idx, alive)
            yield rays

    def pass2(self, view, width, height):
        """Batches of the remaining rays of the pixels whose corner colours differ (decided
        when the first batch is asked for: every pass-1 deposit must be in by then)."""
        a, b = self.corner[:, 0], self.corner[:, 1]
        differ = np.max(np.abs(a - b), axis=1) > self.spec.threshold
        if self.spec.adaptation == "left":  # a lost corner says nothing about the colour
            differ |= ~self.corner_alive.all(axis=1)
        rest = np.setdiff1d(np.arange(self.n), self.first)
        self.refined = differ if len(rest) else np.zeros_like(differ)
        for idx in self._chunks(np.flatnonzero(self.refined), len(rest)):
            rays, alive = camera_rays(self.spec, view, width, height, self.pixels[idx], rest)
            self._count(idx, alive)
            yield rays

    def _count(self, idx: np.ndarray, alive: np.ndarray) -> None:
        if self.spec.adaptation == "left":
            self.rays[idx] += alive.sum(axis=1)
        else:
            self.rays[idx] += alive.shape[1]

    def add(self, sample_ids: np.ndarray, rgb: np.ndarray) -> None:
        """Deposits of traced rays (ids pixel * N + k), summed; corner samples also apart."""
        if len(sample_ids) == 0:
            return
        i = self._local(sample_ids // self.n)
        k = sample_ids % self.n
        for c in range(3):
            self.sums[:, c] += np.bincount(i, weights=rgb[:, c], minlength=len(self.pixels))
        for j, corner in enumerate(self.first):
            m = k == corner
            if m.any():
                for c in range(3):
                    self.corner[:, j, c] += np.bincount(i[m], weights=rgb[m, c],
                                                        minlength=len(self.pixels))  # fmt: skip

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel ids and their colours: each pixel's sum over the rays it got."""
        return self.pixels, self.sums / np.maximum(self.rays, 1)[:, None]
