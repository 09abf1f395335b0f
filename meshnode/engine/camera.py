"""Primary rays of a pinhole eye for a rectangle of the sample grid.

Two sample grids: SPD corners ((W+1) x (H+1) rays at pixel corners, averaged four to a pixel)
and pixel samples (W x H x spp, centred or jittered). Jitter comes from a counter-based hash of
(seed, sample, dimension), so any node can generate any sample and get the same ray.
"""

import functools
import math

import numpy as np

from meshnode.engine.jit import inline, kernel
from protocols.dtypes import EYE, RAY
from protocols.render import ImageSpec
from protocols.scene import View


def view_basis(view: View, width: int, height: int):
    """Eye, forward, right, up vectors and the image-plane step per pixel at unit distance.

    The angle spans the centres of the outermost pixel columns (rows if the image is taller);
    up is projected onto the image plane. Remembered per view and size (a render asks once
    per band: 50 us of small-array NumPy each time, 4% of tetra's render); copies returned."""
    try:
        eye, fwd, right, up, step = _view_basis(view, width, height)
    except TypeError:  # a View built with unhashable fields (arrays)
        eye, fwd, right, up, step = _view_basis.__wrapped__(view, width, height)
    return eye.copy(), fwd.copy(), right.copy(), up.copy(), step


@functools.lru_cache(maxsize=16)
def _view_basis(view: View, width: int, height: int):
    eye = np.asarray(view.eye, float)
    fwd = np.asarray(view.at, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(view.up, float))
    if np.linalg.norm(right) < 1e-12:
        raise ValueError("view: up is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    step = 2.0 * math.tan(math.radians(view.angle) / 2.0) / max(max(width, height) - 1, 1)
    return eye, fwd, right, up, step


@kernel
def _mix(x):
    """splitmix64 finaliser: a well-spread 64-bit hash."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@kernel
def uniform(seed, sample, dim):
    """Deterministic uniform in [0, 1) for (seed, sample, dimension)."""
    h = _mix(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(sample))
    h = _mix(h + np.uint64(dim) * np.uint64(0xD1B54A32D192ED03))
    return (h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@kernel
def uniforms(seed, ids, dim, out):
    """`uniform` for every id of a flat array (the camera's sampling draws them in bulk)."""
    for i in range(ids.shape[0]):
        out[i] = uniform(seed, ids[i], dim)


NO_KEEP = np.zeros((0, 0), np.uint8)  # `fill_eye_rays`: every cell of the rectangle


@inline
def set_primary(r, ox, oy, oz, dx, dy, dz, t_min, w, pixel):
    """Fill one primary (eye or camera) RAY record: unit weight scale `w`, no origin object."""
    r.o[0], r.o[1], r.o[2] = ox, oy, oz
    r.d[0], r.d[1], r.d[2] = dx, dy, dz
    r.t_min = t_min
    r.t_max = math.inf
    r.w[0], r.w[1], r.w[2] = w, w, w
    r.pixel = pixel
    r.origin = -1
    r.depth = 1
    r.kind = EYE
    r.light = 0


@kernel
def fill_eye_rays(
    out, eye, fwd, right, up, step, width, height, corners, spp, seed, x0, x1, y0, y1, hither, keep
):
    """Write the eye rays of sample-grid columns [x0, x1) and rows [y0, y1) into `out`: every
    cell's, or where `keep` (rows by columns of the rectangle) has some only those cells'.

    corners=True: sample (i, j) sits on a pixel corner, id j*(W+1)+i. Otherwise sample k of
    pixel (i, j) has id (j*W+i)*spp+k, at the pixel centre (spp 1) or jittered (stratified
    when spp is a square)."""
    n = 0
    grid_w = width + 1 if corners else width
    strata = int(math.sqrt(spp) + 0.5)
    stratified = strata * strata == spp
    every = keep.shape[0] == 0
    for j in range(y0, y1):
        for i in range(x0, x1):
            if not every and keep[j - y0, i - x0] == 0:
                continue
            for k in range(spp):
                sid = j * grid_w + i if corners else (j * width + i) * spp + k
                if corners:
                    fx = float(i)
                    fy = float(j)
                elif spp == 1:
                    fx = i + 0.5
                    fy = j + 0.5
                elif stratified:
                    fx = i + (k % strata + uniform(seed, sid, 0)) / strata
                    fy = j + (k // strata + uniform(seed, sid, 1)) / strata
                else:
                    fx = i + uniform(seed, sid, 0)
                    fy = j + uniform(seed, sid, 1)
                px = (fx - 0.5 * width) * step
                py = (0.5 * height - fy) * step
                dx = fwd[0] + px * right[0] + py * up[0]
                dy = fwd[1] + px * right[1] + py * up[1]
                dz = fwd[2] + px * right[2] + py * up[2]
                ln = math.sqrt(dx * dx + dy * dy + dz * dz)
                # hither is measured along the view axis
                set_primary(
                    out[n], eye[0], eye[1], eye[2], dx / ln, dy / ln, dz / ln, hither * ln, 1.0, sid
                )
                n += 1
    return n


def eye_rays(
    view: View,
    image: ImageSpec,
    rows: tuple[int, int] | None = None,
    cols: tuple[int, int] | None = None,
    keep: np.ndarray | None = None,
):
    """Eye rays (RAY records) of a rectangle of the image's sample grid (all of it by
    default): pixel corners under the SPD rules, else `spp` samples per pixel; with `keep`
    (a flag per sample-grid cell of the rectangle, rows by columns) only the flagged cells'."""
    width, height = image.size
    eye, fwd, right, up, step = view_basis(view, width, height)
    gw, gh = image.sample_grid()
    corners = image.corners()
    spp = 1 if corners else image.spp
    x0, x1 = cols or (0, gw)
    y0, y1 = rows or (0, gh)
    cells = (x1 - x0) * (y1 - y0)
    if keep is None:
        keep = NO_KEEP
    else:
        keep = np.ascontiguousarray(keep, np.uint8)
        if keep.shape != (y1 - y0, x1 - x0):
            raise ValueError(f"eye_rays: keep is {keep.shape}, the rectangle {(y1 - y0, x1 - x0)}")
        cells = int(np.count_nonzero(keep))
    # Not zeroed: the kernel writes every field of every record (RAY has no padding bytes).
    out = np.empty(cells * spp, RAY)
    fill_eye_rays(
        out,
        eye,
        fwd,
        right,
        up,
        step,
        width,
        height,
        corners,
        spp,
        image.seed,
        x0,
        x1,
        y0,
        y1,
        float(view.hither),
        keep,
    )
    return out
