"""Adaptive sampling's bookkeeping for the pixels one node owns (DESIGN.md 7).

Pass 1 traces two rays per pixel, at opposite corners of the sampled area; a pixel gets its
other rays in pass 2 if either was lost in the camera, if those two colours differ by more than
the threshold, or if their mean differs by more than the threshold from a side neighbour's: two
rays at the rim of the lens can agree while a blurred edge crosses the lens between them, but
then the neighbours' colours change. A ray's colour is known only when all its descendants have
ended, possibly on other nodes, so under adaptive sampling every deposit travels to the node
owning its pixel - and pass-1 deposits also to the owners of its side neighbours, which keep a
one-pixel halo around their rectangle - and the two passes are two states of the mesh's state
machine (ended by termination waves). The owner alone knows how many rays each of its pixels
got (and how many left the camera), so it divides and sends finished pixels to the host.
"""

import numpy as np

from meshnode.engine.lenscamera import camera_rays, first_pass, rect_pixels
from protocols.camera import CameraSpec

RAYS_PER_BATCH = 16384  # camera rays made at a time: memory stays bounded at any spp
SIDES = ((1, 0), (-1, 0), (0, 1), (0, -1))


class RectIndex:
    """Which rectangle holds a pixel, for rectangles on a grid of cuts (a mesh's rectangles,
    image-space tiles): built once per render, then two binary searches and a table lookup
    per pixel, whatever the number of rectangles."""

    def __init__(self, rects, width: int):
        r = np.asarray(rects, np.int64).reshape(-1, 4)
        self.width = width
        self.xs, self.ys = np.unique(r[:, :2]), np.unique(r[:, 2:])
        self.table = np.full((max(len(self.ys) - 1, 0), max(len(self.xs) - 1, 0)), -1, np.int64)
        xa, xb = np.searchsorted(self.xs, r[:, 0]), np.searchsorted(self.xs, r[:, 1])
        ya, yb = np.searchsorted(self.ys, r[:, 2]), np.searchsorted(self.ys, r[:, 3])
        for i in range(len(r)):  # once per rectangle, at set-up
            self.table[ya[i] : yb[i], xa[i] : xb[i]] = i

    def __call__(self, pixels: np.ndarray) -> np.ndarray:
        """Index of the rectangle holding each pixel id (y * width + x); -1: none."""
        x, y = pixels % self.width, pixels // self.width
        i = np.searchsorted(self.xs, x, "right") - 1
        j = np.searchsorted(self.ys, y, "right") - 1
        inside = (i >= 0) & (i < self.table.shape[1]) & (j >= 0) & (j < self.table.shape[0])
        out = np.full(len(pixels), -1, np.int64)
        out[inside] = self.table[j[inside], i[inside]]
        return out


def deposit_routes(sample_ids, n, first, width, height, index: RectIndex):
    """(deposit index, rectangle) pairs, each once: every deposit to its pixel's rectangle,
    pass-1 deposits also to the rectangles of the pixel's side neighbours (their halo);
    rectangle -1: a pixel no rectangle of `index` holds."""
    pixels, k = sample_ids // n, sample_ids % n
    idx = [np.arange(len(pixels))]
    dest = [index(pixels)]
    corner = np.flatnonzero(np.isin(k, first))
    x, y = pixels[corner] % width, pixels[corner] // width
    for dx, dy in SIDES:
        inside = (x + dx >= 0) & (x + dx < width) & (y + dy >= 0) & (y + dy < height)
        at = corner[inside]
        idx.append(at)
        dest.append(index(pixels[at] + dx + dy * width))
    idx, dest = np.concatenate(idx), np.concatenate(dest)
    key = np.unique((dest + 1) * len(pixels) + idx)
    return key % len(pixels), key // len(pixels) - 1


def pass_samples(spec: CameraSpec, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """The sample indices of pass 1 (a pixel's two corners) and of pass 2 (the rest), at the
    image's `spp` rays per pixel."""
    first = first_pass(spec, spp)
    return first, np.setdiff1d(np.arange(spec.per_pixel(spp)), first)


def split(idx: np.ndarray, per_pixel: int):
    """`idx` in slices of at most RAYS_PER_BATCH rays at `per_pixel` rays a pixel."""
    step = max(1, RAYS_PER_BATCH // max(per_pixel, 1))
    return (idx[i : i + step] for i in range(0, len(idx), step))


class AdaptiveFilm:
    """Colour sums and ray counts of a node's rectangle of pixels, and the pass-1 corner
    colours over the rectangle and a one-pixel halo around it (their deposits come from the
    nodes owning those pixels)."""

    def __init__(self, spec: CameraSpec, spp: int, rect, width: int, height: int, seed: int = 0):
        self.spec, self.spp, self.width, self.seed = spec, spp, width, seed
        self.n = spec.per_pixel(spp)
        self.first, self.rest = pass_samples(spec, spp)
        x0, x1, y0, y1 = self.rect = tuple(int(v) for v in rect)
        self.pixels = rect_pixels(self.rect, width)
        self.halo = (max(x0 - 1, 0), min(x1 + 1, width), max(y0 - 1, 0), min(y1 + 1, height))
        hx0, hx1, hy0, hy1 = self.halo
        self.corner = np.zeros((hy1 - hy0, hx1 - hx0, 2, 3))
        p = len(self.pixels)
        self.sums = np.zeros((p, 3))
        self.corner_alive = np.zeros((p, 2), np.bool_)
        self.rays = np.zeros(p, np.int64)  # divisor: rays generated (or that left, "left")
        self.refined = np.zeros(p, np.bool_)

    def make(self, idx: np.ndarray, refine: bool, view, width, height) -> np.ndarray:
        """The camera rays of own pixels `idx` (indices into `pixels`) for pass 1 (their two
        corners) or pass 2 (the rest), books kept: which corners the camera let through, and
        each pixel's divisor. A pixel whose rays a neighbour traces (stealing) gets its books
        kept here the same way, the rays dropped: camera rays are a pure function of camera,
        view, pixel, sample and seed, so the thief makes the very same ones."""
        samples = self.rest if refine else self.first
        rays, alive = camera_rays(
            self.spec, self.spp, view, width, height, self.pixels[idx], samples, self.seed
        )
        if not refine:
            self.corner_alive[idx] = alive
        self._count(idx, alive)
        return rays

    def pass1(self, view, width, height):
        """Batches of the two corner rays of every owned pixel."""
        for idx in split(np.arange(len(self.pixels)), 2):
            yield self.make(idx, False, view, width, height)

    def decide(self) -> np.ndarray:
        """Which own pixels get the rest of their rays: corners apart, or the corners' mean
        apart from a side neighbour's (all pass-1 deposits must be in by now)."""
        t = self.spec.sampling.threshold
        c = self.corner
        differ = np.max(np.abs(c[:, :, 0] - c[:, :, 1]), axis=-1) > t
        mean = 0.5 * (c[:, :, 0] + c[:, :, 1])
        hx0, _, hy0, _ = self.halo
        x0, x1, y0, y1 = self.rect
        own = (slice(y0 - hy0, y1 - hy0), slice(x0 - hx0, x1 - hx0))
        refine = differ[own].copy()
        # Neighbours beyond the image edge are NaN, and a comparison with NaN is false.
        pad = np.pad(mean, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)
        oy, ox, h, w = y0 - hy0 + 1, x0 - hx0 + 1, y1 - y0, x1 - x0
        centre = pad[oy : oy + h, ox : ox + w]
        for dx, dy in SIDES:
            side = pad[oy + dy : oy + dy + h, ox + dx : ox + dx + w]
            refine |= np.max(np.abs(centre - side), axis=-1) > t
        # A corner ray lost in the camera (rim, diaphragm) says nothing of the scene's colour.
        return refine.ravel() | ~self.corner_alive.all(axis=1)

    def start_refine(self) -> None:
        """Pick the pixels that get the rest of their rays (`decide`; all pass-1 deposits
        must be in by now)."""
        n = len(self.pixels)
        self.refined = self.decide() if len(self.rest) else np.zeros(n, np.bool_)

    def pass2(self, view, width, height):
        """Batches of the remaining rays of the pixels `decide` picks (decided when the first
        batch is asked for)."""
        self.start_refine()
        for idx in split(np.flatnonzero(self.refined), len(self.rest)):
            yield self.make(idx, True, view, width, height)

    def index_of(self, rect) -> np.ndarray:
        """Indices into `pixels` of the pixels of `rect` (x0, x1, y0, y1), inside the own
        rectangle."""
        x0, x1, y0, y1 = self.rect
        cx0, cx1, cy0, cy1 = rect
        cols = np.arange(cx0, cx1) - x0
        return ((np.arange(cy0, cy1) - y0)[:, None] * (x1 - x0) + cols[None, :]).ravel()

    def refined_runs(self, rect) -> list[tuple[int, int, int, int]]:
        """The refined pixels of `rect` as runs along its rows, each a one-row rectangle
        (x0, x1, y, y + 1): pass 2's work in the form a GIVE carries, so a neighbour can
        trace it without this node's books."""
        cx0, cx1, cy0, cy1 = rect
        mask = self.refined[self.index_of(rect)].reshape(cy1 - cy0, cx1 - cx0)
        edges = np.diff(np.pad(mask, ((0, 0), (1, 1))).astype(np.int8), axis=1)
        row_s, start = np.nonzero(edges == 1)
        _, end = np.nonzero(edges == -1)  # row-major order pairs each start with its end
        return [
            (cx0 + a, cx0 + b, cy0 + r, cy0 + r + 1)
            for r, a, b in zip(row_s.tolist(), start.tolist(), end.tolist(), strict=True)
        ]

    def _count(self, idx: np.ndarray, alive: np.ndarray) -> None:
        if self.spec.sampling.adaptation == "left":
            self.rays[idx] += alive.sum(axis=1)
        else:
            self.rays[idx] += alive.shape[1]

    def add(self, sample_ids: np.ndarray, rgb: np.ndarray) -> None:
        """Deposits of traced rays (ids pixel * N + k): summed over own pixels; pass-1 ones
        also apart, over the rectangle and its halo."""
        if len(sample_ids) == 0:
            return
        pixels, k = sample_ids // self.n, sample_ids % self.n
        x, y = pixels % self.width, pixels // self.width
        x0, x1, y0, y1 = self.rect
        own = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
        hx0, hx1, hy0, hy1 = self.halo
        in_halo = (x >= hx0) & (x < hx1) & (y >= hy0) & (y < hy1)
        if np.any(~in_halo):
            raise ValueError("a deposit for a pixel outside this node's rectangle and halo")
        local = (y[own] - y0) * (x1 - x0) + (x[own] - x0)
        for c in range(3):
            self.sums[:, c] += np.bincount(local, weights=rgb[own, c], minlength=len(self.pixels))
        hw, size = hx1 - hx0, self.corner.shape[0] * self.corner.shape[1]
        flat = self.corner.reshape(size, 2, 3)
        for j, corner in enumerate(self.first):
            m = k == corner
            if m.any():
                cell = (y[m] - hy0) * hw + (x[m] - hx0)
                for c in range(3):
                    flat[:, j, c] += np.bincount(cell, weights=rgb[m, c], minlength=size)

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """Pixel ids and their colours: each pixel's sum over the rays it got."""
        return self.pixels, self.sums / np.maximum(self.rays, 1)[:, None]
