"""Primary rays from a simulated camera (DESIGN.md 7): film points, generation-area points on
the first element, the element stack, and the camera-to-scene transform from the NFF view.

Vectorised over every sample of a pixel rectangle (no loop per pixel); the element tracing is
the `optics.through` kernel. Rays lost in the camera (rims, diaphragms, total reflection) are
dropped; their share of the pixel is black under adaptation "all" (vignetting) and
redistributed over the survivors under "left".
"""

import numpy as np

from meshnode.engine.camera import view_basis
from meshnode.engine.optics import through
from protocols.dtypes import EYE, RAY

# Generation area types: 0 pinhole, 1 centre ray through the elements, 2 n random in the
# ellipse, 3 n random in the rectangle, 4 five points, 5 five jittered, 6 nine, 7 nine jittered.
GENERATION_TYPES = range(8)


def _pattern(gen: int, n: int) -> tuple[np.ndarray, bool]:
    """Unit-square offsets (in [-1, 1]^2) of a fixed pattern, and whether to jitter it."""
    if gen in (0, 1):
        return np.zeros((1, 2)), False
    if gen in (4, 5):
        c = 1 / np.sqrt(2)
        return np.array([(0, 0), (-c, -c), (c, -c), (-c, c), (c, c)]), gen == 5
    if gen in (6, 7):
        g = np.array([-1, 0, 1]) / np.sqrt(2)
        return np.array([(x, y) for y in g for x in g]), gen == 7
    return np.zeros((n, 2)), True  # 2, 3: all random


def lens_points(gen: int, n: int, sample_ids: np.ndarray, ax: float, ay: float, seed: int):
    """Targets on the generation area for every (sample, k): shape (samples, k, 2)."""
    pattern, random = _pattern(gen, n)
    k = len(pattern)
    ids = (sample_ids[:, None] * k + np.arange(k)[None, :]).astype(np.uint64)
    if not random:
        pts = np.broadcast_to(pattern, (len(sample_ids), k, 2)).copy()
    else:
        u = _hash_uniform(seed, ids, 2)
        v = _hash_uniform(seed, ids, 3)
        if gen == 3:
            pts = np.stack([2 * u - 1, 2 * v - 1], axis=-1)
        elif gen == 2:
            r, a = np.sqrt(u), 2 * np.pi * v
            pts = np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)
        else:  # jittered patterns: each point moves within a small square around itself
            pts = pattern[None] + 0.25 * np.stack([2 * u - 1, 2 * v - 1], axis=-1)
    return pts * np.array([ax, ay])


def _hash_uniform(seed: int, ids: np.ndarray, dim: int) -> np.ndarray:
    """Vectorised counter-based uniforms (splitmix64), same construction as camera.uniform."""
    def mix(x):
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))

    with np.errstate(over="ignore"):
        h = mix(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + ids.astype(np.uint64))
        h = mix(h + np.uint64(dim) * np.uint64(0xD1B54A32D192ED03))
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def camera_rays(view, width: int, height: int, elements: np.ndarray, film_w: float,
                film_h: float, film_z: float, gen: int = 2, n: int = 16, seed: int = 0,
                adaptation: str = "all", rows=None, cols=None) -> np.ndarray:  # fmt: skip
    """RAY records (pixel = y * width + x, weight = the ray's share of its pixel) for the
    pixels in rows x cols, through the camera; lost rays are not returned."""
    if gen not in GENERATION_TYPES:
        raise ValueError(f"generation area type must be 0..7, not {gen}")
    if adaptation not in ("all", "left"):
        raise ValueError("adaptation must be 'all' or 'left'")
    y0, y1 = rows or (0, height)
    x0, x1 = cols or (0, width)
    jj, ii = np.meshgrid(np.arange(y0, y1), np.arange(x0, x1), indexing="ij")
    pixel = (jj * width + ii).ravel()
    # Film points: the lens inverts the image, so the film is read mirrored in x and y.
    fx = -((ii.ravel() + 0.5) / width - 0.5) * film_w
    fy = ((jj.ravel() + 0.5) / height - 0.5) * film_h
    first = elements[int(np.argmin(elements["z"]))]
    pts = lens_points(gen, n, pixel, float(first["ax"]), float(first["ay"]), seed)
    k = pts.shape[1]
    o = np.empty((len(pixel) * k, 3))
    o[:, 0] = np.repeat(fx, k)
    o[:, 1] = np.repeat(fy, k)
    o[:, 2] = film_z
    d = np.empty_like(o)
    d[:, 0] = pts[:, :, 0].ravel() - o[:, 0]
    d[:, 1] = pts[:, :, 1].ravel() - o[:, 1]
    d[:, 2] = float(first["z"]) - film_z
    d /= np.linalg.norm(d, axis=1)[:, None]
    alive = np.ones(len(o), dtype=np.bool_)
    if gen != 0:  # type 0 is the classic pinhole: straight through the lens centre
        through(o, d, elements, False, alive)
    share = np.full(len(o), 1.0 / k)
    if adaptation == "left":
        survivors = alive.reshape(-1, k).sum(axis=1)
        share = np.repeat(1.0 / np.maximum(survivors, 1), k)
    # Camera frame -> world: z along the view, x right, y up, the front vertex at the eye.
    eye, fwd, right, up, _ = view_basis(view, width, height)
    front = float(elements["z"].max())
    basis = np.stack([right, up, fwd])
    keep = np.flatnonzero(alive)
    rays = np.zeros(len(keep), RAY)
    rays["o"] = eye + (o[keep] - [0.0, 0.0, front]) @ basis
    rays["d"] = d[keep] @ basis
    rays["t_max"] = np.inf
    rays["w"] = share[keep, None]
    rays["pixel"] = np.repeat(pixel, k)[keep]
    rays["origin"] = -1
    rays["depth"] = 1
    rays["kind"] = EYE
    return rays
