"""Primary rays from a simulated camera (DESIGN.md 7): film points, generation-area points on
the first element (within its exit pupil when the spec has one: `aim_points`), the element
stack, and the camera-to-scene transform from the NFF view.

Vectorised over every (pixel, sample) pair asked for (no loop per pixel); the element tracing
is the `optics.through` kernel. Rays lost in the camera (rims, diaphragms, total reflection)
are dropped; their share of the pixel is black under adaptation "all" (vignetting) and
redistributed over the survivors under "left".

A pixel's rays are the image's rays per pixel (ImageSpec.spp, `spp` here), of which the
sampling's generation type traces N (`CameraSampling.per_pixel`: all of them, a fixed
pattern's points, or one). Sample k of a pixel is a point of a stratified set: with
N = m*m rays, stratum (k % m, k // m) of an m x m grid (otherwise N-rooks: column k, a
shuffled row), taken at its centre (uniform) or at a hashed random point inside it
(jittered). Sample 0 and sample N-1 sit in opposite
corner strata: adaptive sampling traces those two first. Every number comes from a
counter-based hash of (seed, pixel, sample), so any node makes the same ray for a sample.
"""

import math

import numpy as np

from meshnode.engine.camera import set_primary, uniforms, view_basis
from meshnode.engine.jit import kernel
from meshnode.engine.optics import through
from protocols.camera import CameraSampling, CameraSpec, Generation
from protocols.dtypes import RAY

_C = 0.6
JITTER = 0.1
# Fixed patterns in the unit disc: five points, nine points (row-major). Jittered by up to
# JITTER per axis, a corner stays inside the disc (radius (0.6 + 0.1) sqrt 2 = 0.99), and off
# the rim where round-off would decide whether it passes.
FIVE = np.array([(0, 0), (-_C, -_C), (_C, -_C), (-_C, _C), (_C, _C)])
NINE = np.array([(x, y) for y in (-_C, 0, _C) for x in (-_C, 0, _C)])


def first_pass(spec: CameraSpec, spp: int) -> np.ndarray:
    """The two samples at opposite corners that adaptive sampling traces first, at `spp`
    rays per pixel."""
    if spec.sampling.kind.points == 5:
        return np.array([1, 4])
    return np.array([0, spec.per_pixel(spp) - 1])


def _hash_uniform(seed: int, ids: np.ndarray, dim: int) -> np.ndarray:
    """`camera.uniform` of (seed, id, dim) for an array of ids, shaped like it."""
    flat = np.ascontiguousarray(ids, dtype=np.uint64).ravel()
    out = np.empty(len(flat))
    uniforms(seed, flat, dim, out)
    return out.reshape(np.shape(ids))


def _coprime_step(n: int) -> int:
    """A step near n / golden ratio coprime with n: k -> k*step mod n shuffles strata evenly."""
    step = max(1, int(round(n * 0.6180339887)))
    while math.gcd(step, n) != 1:
        step += 1
    return step


def _strata(n: int, ks: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Column and row of sample k's stratum, and the grid's columns and rows."""
    m = math.isqrt(n)
    if m * m == n:
        return ks % m, ks // m, m, m
    # N-rooks: rows shuffled, with the first and last sample kept in opposite corners.
    row = ks.copy()
    inner = (ks > 0) & (ks < n - 1)
    if n > 2:
        row[inner] = 1 + ((ks[inner] - 1) * _coprime_step(n - 2)) % (n - 2)
    return ks, row, n, n


def unit_points(sampling: str, n: int, pixels, ks, seed: int, dim: int) -> np.ndarray:
    """Points in [0, 1)^2 for every (pixel, sample k): shape (len(pixels), len(ks), 2);
    `ks` is one list for every pixel or one row per pixel."""
    ks = np.broadcast_to(np.asarray(ks, np.int64), (len(pixels), np.shape(ks)[-1]))
    ids = pixels[:, None].astype(np.uint64) * np.uint64(n) + ks.astype(np.uint64)
    if sampling == "random":
        return np.stack([_hash_uniform(seed, ids, dim), _hash_uniform(seed, ids, dim + 1)], -1)
    col, row, nx, ny = _strata(n, ks)
    if sampling == "uniform":
        u, v = (col + 0.5) / nx, (row + 0.5) / ny
    else:  # jittered (adaptive is jittered strata traced in two passes)
        u = (col + _hash_uniform(seed, ids, dim)) / nx
        v = (row + _hash_uniform(seed, ids, dim + 1)) / ny
    return np.stack([u, v], -1)


def to_area(p: np.ndarray, ellipse: bool) -> np.ndarray:
    """Unit-square points onto [-1, 1]^2 (rectangle) or the unit disc (ellipse) by the
    concentric map, which keeps strata compact so stratification survives."""
    a = 2.0 * p - 1.0
    if not ellipse:
        return a
    flat = np.ascontiguousarray(a.reshape(-1, 2))
    _concentric(flat)
    return flat.reshape(a.shape)


@kernel
def _concentric(a):
    """Shirley-Chiu concentric map of [-1, 1]^2 onto the unit disc, in place."""
    for i in range(a.shape[0]):
        x, y = a[i, 0], a[i, 1]
        if x == 0.0 and y == 0.0:
            continue
        if abs(x) > abs(y):
            r, phi = x, (math.pi / 4) * (y / x)
        else:
            r, phi = y, math.pi / 2 - (math.pi / 4) * (x / y)
        a[i, 0] = r * math.cos(phi)
        a[i, 1] = r * math.sin(phi)


@kernel
def _emit(out, o, d, alive, share, ids, eye, right, up, fwd, front, hither):
    """RAY records of the rays that left the camera, moved from the camera frame (z along the
    view, the front vertex at the eye) to the scene; returns how many. `hither` > 0 (the
    pinhole): rays start that far along the view axis, as the scene's own eye rays do."""
    n = 0
    for i in range(o.shape[0]):
        if not alive[i]:
            continue
        x, y, z = o[i, 0], o[i, 1], o[i, 2] - front
        a, b, c = d[i, 0], d[i, 1], d[i, 2]
        t_min = hither / c if hither > 0.0 else 0.0
        set_primary(
            out[n],
            eye[0] + x * right[0] + y * up[0] + z * fwd[0],
            eye[1] + x * right[1] + y * up[1] + z * fwd[1],
            eye[2] + x * right[2] + y * up[2] + z * fwd[2],
            a * right[0] + b * up[0] + c * fwd[0],
            a * right[1] + b * up[1] + c * fwd[1],
            a * right[2] + b * up[2] + c * fwd[2],
            t_min,
            share[i],
            ids[i],
        )
        n += 1
    return n


def _pattern_points(s: CameraSampling, n: int, pixels, ks, seed: int) -> np.ndarray:
    """Offsets in [-1, 1]^2 of the sampled area (the lens's, or the film's when special), of
    samples `ks` of the `n` a pixel traces."""
    gen = s.kind
    if gen.points:
        pts = np.broadcast_to((FIVE if gen.points == 5 else NINE)[ks], (len(pixels), len(ks), 2))
        if gen.jittered:  # each point moves within a small square around itself
            ids = pixels[:, None].astype(np.uint64) * np.uint64(16) + ks[None, :]
            jit = np.stack([_hash_uniform(seed, ids, 2), _hash_uniform(seed, ids, 3)], -1)
            pts = pts + JITTER * (2 * jit - 1)
        return np.array(pts)
    p = unit_points(_placement(s), n, pixels, ks, seed, 2)
    ellipse = gen != Generation.RECTANGLE if not s.special else s.film_area == "ellipse"
    return to_area(p, ellipse)


def _placement(s: CameraSampling) -> str:
    """How strata points are placed: adaptive sampling places its rays jittered."""
    return "jittered" if s.sampling == "adaptive" else s.sampling


def sample_offsets(s: CameraSampling, n: int, pixels: np.ndarray, ks: np.ndarray, seed: int):
    """(lens offsets, film offsets) for every (pixel, k) of the `n` rays a pixel traces
    (`CameraSampling.per_pixel`): lens in units of the generation area's semi-axes, film in
    pixels from the pixel centre."""
    shape = (len(pixels), len(ks), 2)
    zeros = np.zeros(shape)
    lens_sampled = not s.kind.through_centre or s.special
    pts = _pattern_points(s, n, pixels, ks, seed) if lens_sampled else None
    half = 0.5 * s.film_area_size
    if s.special:
        return zeros, pts * half
    if s.film_area == "centre":
        return (pts if pts is not None else zeros), zeros
    # The film area's own set, its strata shuffled against the lens's by a random
    # permutation per pixel: any film stratum goes with any lens stratum (no correlation).
    # Without lens sampling there is nothing to decorrelate: sample k is stratum k, so
    # adaptive sampling's first two are the film area's opposite corners.
    perm = ks
    if lens_sampled:
        keys = _hash_uniform(
            seed,
            pixels[:, None].astype(np.uint64) * np.uint64(n)
            + np.arange(n, dtype=np.uint64)[None, :],
            6,
        )
        perm = np.argsort(keys, axis=1)[:, ks]
    film = unit_points(_placement(s), n, pixels, perm, seed, 4)
    film = to_area(film, s.film_area == "ellipse")
    return (pts if pts is not None else zeros), film * half


def camera_rays(
    spec: CameraSpec,
    spp: int,
    view,
    width: int,
    height: int,
    pixels: np.ndarray,
    ks: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """RAY records for samples `ks` (all by default) of `pixels` (ids y * width + x) at the
    image's `spp` rays per pixel, drawn with the image's `seed`, and
    which of them left the camera, shape (len(pixels), len(ks)). Lost rays are not returned.

    Weights: 1 / (rays of the pixel) under "all", times the area the ray was drawn from
    (`aim_points`), 1 / (those that left) under "left"; under adaptive sampling a ray weighs
    its area ("all") or 1, `pixel` is the sample id pixel * N + k, and the node owning the
    pixel divides (it alone knows how many rays the pixel got)."""
    pixels = np.asarray(pixels, np.int64)
    n = spec.per_pixel(spp)
    ks = np.arange(n) if ks is None else np.asarray(ks, np.int64)
    lens, film = sample_offsets(spec.sampling, n, pixels, ks, seed)
    k = len(ks)
    first = spec.elements[int(np.argmin(spec.elements["z"]))]
    ix, iy = pixels % width, pixels // width
    # Film points: the lens inverts the image, so the film is read mirrored in x and y.
    fx = -(((ix[:, None] + 0.5 + film[..., 0]) / width) - 0.5) * spec.film_width
    fy = (((iy[:, None] + 0.5 - film[..., 1]) / height) - 0.5) * spec.film_height
    o = np.empty((len(pixels) * k, 3))
    o[:, 0] = fx.ravel()
    o[:, 1] = fy.ravel()
    o[:, 2] = spec.film_z
    ax, ay, area, lost = aim_points(spec, o[:, 0], o[:, 1], lens.reshape(-1, 2))
    d = np.empty_like(o)
    d[:, 0] = ax - o[:, 0]
    d[:, 1] = ay - o[:, 1]
    d[:, 2] = float(first["z"]) - spec.film_z
    d /= np.linalg.norm(d, axis=1)[:, None]
    alive = ~lost
    pinhole = spec.sampling.kind == Generation.PINHOLE
    if pinhole:  # straight through the centre, no refraction: rays start at the pinhole
        o[:, 0], o[:, 1], o[:, 2] = 0.0, 0.0, float(first["z"])
    else:
        through(o, d, spec.elements, False, alive)
    alive2 = alive.reshape(len(pixels), k)
    left = spec.sampling.adaptation == "left"
    if spec.adaptive(spp):
        share = np.ones(len(o)) if left else area
        ids = (pixels[:, None] * n + ks[None, :]).ravel()
    else:
        per = alive2.sum(axis=1) if left else np.full(len(pixels), k)
        share = np.repeat(1.0 / np.maximum(per, 1), k) * (1.0 if left else area)
        ids = np.repeat(pixels, k)
    eye, fwd, right, up, _ = view_basis(view, width, height)
    rays = np.zeros(int(alive.sum()), RAY)
    hither = float(view.hither) if pinhole else 0.0
    _emit(
        rays, o, d, alive, share, ids, eye, right, up, fwd, float(spec.elements["z"].max()), hither
    )
    return rays, alive2


def aim_points(spec: CameraSpec, fx, fy, lens):
    """Where in the first element's plane rays from film points (fx, fy) are aimed, for lens
    offsets `lens` ((n, 2), in units of the sampled area's semi-axes), each ray's weight for
    the area it was drawn from, and which rays cannot pass at all.

    Rays are drawn in the exit pupil when the spec has one (the region of that plane through
    which light from a film point at this distance from the axis reaches the scene, as an
    ellipse per band of distance, for a point on the +x axis; the lens is round about its
    axis, so the region turns with the film point), else in the first element's ellipse or
    rectangle. A ray weighs the area it was drawn from over the area passing from the film's
    centre (`pupil_area`), so the image centre is as bright as the scene whatever the lens and
    its stop (a lens table cannot list its stop first) and however rays are aimed; vignetting
    stays. A band through which nothing passes loses its rays untraced."""
    first = spec.elements[int(np.argmin(spec.elements["z"]))]
    s = spec.sampling
    n = len(fx)
    u, v = lens[:, 0], lens[:, 1]
    table = np.asarray(spec.pupil, float).reshape(-1, 3)
    lens_sampled = not s.kind.through_centre and not s.special
    shape = 4.0 if s.kind == Generation.RECTANGLE else math.pi
    weighed = lens_sampled and spec.pupil_area > 0
    if len(table) == 0 or s.kind == Generation.PINHOLE:
        ax, ay = float(first["ax"]), float(first["ay"])
        area = np.full(n, shape * ax * ay / spec.pupil_area if weighed else 1.0)
        return u * ax, v * ay, area, np.zeros(n, bool)
    r = np.hypot(fx, fy)
    band = np.minimum((r * (len(table) / spec.pupil_radius)).astype(np.int64), len(table) - 1)
    cx, a, b = table[band].T
    cos = np.divide(fx, r, out=np.ones(n), where=r > 0)
    sin = np.divide(fy, r, out=np.zeros(n), where=r > 0)
    px, py = cx + u * a, v * b
    area = shape * a * b / spec.pupil_area if weighed else np.ones(n)
    return cos * px - sin * py, sin * px + cos * py, area, a <= 0.0


def camera_batches(
    spec: CameraSpec,
    spp: int,
    view,
    width: int,
    height: int,
    pixels: np.ndarray,
    seed: int = 0,
    rays_per_batch: int = 16384,
):
    """Camera rays of `pixels` at `spp` rays per pixel in batches of about `rays_per_batch`
    (bounded memory at any number of rays per pixel)."""
    step = max(1, rays_per_batch // spec.per_pixel(spp))
    for i in range(0, len(pixels), step):
        yield camera_rays(spec, spp, view, width, height, pixels[i : i + step], seed=seed)[0]


def rect_pixels(rect, width: int) -> np.ndarray:
    """Pixel ids of the rectangle (x0, x1, y0, y1), row by row."""
    x0, x1, y0, y1 = rect
    jj, ii = np.meshgrid(np.arange(y0, y1), np.arange(x0, x1), indexing="ij")
    return (jj * width + ii).ravel()
