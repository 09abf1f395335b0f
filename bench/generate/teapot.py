"""SPD `teapot`: Newell's teapot (with Crow's bottom) tessellated into smooth triangles on a
checkerboard; two lights. The teapot should be rendered double-sided."""

import numpy as np

from bench.generate.records import SpdScene
from bench.generate.teapot_data import PATCHES, POINTS
from protocols.scene import SceneData, View

DEFAULT = 6  # teapot.nff
VIEW = View(eye=(4.86, 7.2, 5.4), at=(0, 0, 0), up=(0, 0, 1), angle=45.0, hither=1.0)
LIGHTS = ((-3.1, 9.8, 12.1), (11.3, 5.1, 8.8))
BEZIER = np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]], float)
# A mesh quad's corners as (s, t) steps, and its two triangles' corners in the SPD's order.
QUAD = np.array([[0, 0], [0, 1], [1, 1], [1, 0]])
HALVES = np.array([[0, 1, 2], [2, 3, 0]])
CUSP = 0.0001  # a point this close to the z axis is a cusp (lid knob, bottom centre)


def checkerboard(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(white squares, grey squares) (k, 4, 3) of the n x n board on [-4, 4]^2, s-major."""
    s, t = (a.reshape(-1) for a in np.indices((n, n)))
    ds, dt = np.array([0, 1, 1, 0]), np.array([0, 0, 1, 1])
    x = 4.0 * (2.0 * (s[:, None] + ds) / n - 1.0)
    y = 4.0 * (2.0 * (t[:, None] + dt) / n - 1.0)
    squares = np.stack([x, y, np.zeros_like(x)], axis=-1)
    odd = (s + t) % 2 == 1
    return squares[odd], squares[~odd]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sum of a[..., i] b[..., i] over the last axis, added left to right as the SPD's C does
    (so the printed digits come out the same, ties included)."""
    out = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        out = out + a[..., i] * b[..., i]
    return out


def _product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 4, 4) matrix products a b, summed in order (`lib_matrix_multiply`)."""
    return _dot(a[..., :, None, :], np.swapaxes(b, -1, -2)[..., None, :, :])


def surface_points(s: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points, unit normals) (32, k, 3) of every patch at parameters (s, t) (k,): the point
    S M G M^T T for the power vectors S = (s^3, s^2, s, 1), T likewise, and the normal the
    cross product of the t and s tangents (zero where they are parallel)."""
    geometry = np.moveaxis(POINTS[PATCHES], -1, 1)  # (32, 3, 4, 4): x, y, z control nets
    mgm = _product(_product(BEZIER, geometry), BEZIER.T)  # (32, 3, 4, 4)
    columns = np.swapaxes(mgm, -1, -2)[:, None]  # (32, 1, 3, 4, 4): mgm's columns

    def powers(u):
        return np.stack([u * u * u, u * u, u, np.ones_like(u)], 1)[:, None, :]  # (k, 1, 4)

    def slopes(u):
        return np.stack([u * u * 3.0, u * 2.0, np.ones_like(u), np.zeros_like(u)], 1)[:, None, :]

    def value(row, col):  # row . mgm . col per patch, point and coordinate: (32, k, 3)
        return _dot(_dot(row[:, :, None, :], columns), col)

    sp, tp, dsp, dtp = powers(s), powers(t), slopes(s), slopes(t)
    pts, sdir, tdir = value(sp, tp), value(dsp, tp), value(sp, dtp)
    normal = np.stack(
        [
            tdir[..., 1] * sdir[..., 2] - tdir[..., 2] * sdir[..., 1],
            tdir[..., 2] * sdir[..., 0] - tdir[..., 0] * sdir[..., 2],
            tdir[..., 0] * sdir[..., 1] - tdir[..., 1] * sdir[..., 0],
        ],
        axis=-1,
    )
    length = np.sqrt(_dot(normal, normal))[..., None]
    return pts, np.where(length > 0, normal / np.where(length > 0, length, 1.0), 0.0)


def teapot_triangles(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(corners, normals) (k, 3, 3) of the tessellated teapot in the SPD's order (patch, s
    step, t step, half), without the triangles with two corners on a cusp; a cusp corner's
    normal is +z at the lid, -z at the bottom."""
    ss, tt = (a.reshape(-1) for a in np.indices((n, n)))
    corner = QUAD[HALVES]  # (2, 3, 2)
    s = (ss[:, None, None] + corner[None, :, :, 0]) / n  # (n*n, 2, 3)
    t = (tt[:, None, None] + corner[None, :, :, 1]) / n
    pts, nrm = surface_points(s.reshape(-1), t.reshape(-1))
    pts, nrm = pts.reshape(-1, 3, 3), nrm.reshape(-1, 3, 3)  # (32 * n*n * 2, 3, 3)
    cusp = (np.abs(pts[..., 0]) <= CUSP) & (np.abs(pts[..., 1]) <= CUSP)
    keep = cusp.sum(axis=1) <= 1
    pole = np.where(pts[..., 2] > 1.5, 1.0, -1.0)
    nrm = np.where(cusp[..., None], pole[..., None] * np.array([0.0, 0.0, 1.0]), nrm)
    return pts[keep], nrm[keep]


def teapot(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `teapot` at size factor n: the white then the grey squares of the checkerboard, each
    colour before its squares (a spare first `f`, as the SPD writes), then the teapot's 64 n^2
    - 8 n (fewer at n = 1) smooth triangles."""
    scene = SpdScene(VIEW, LIGHTS)
    white, grey = checkerboard(n)
    for rgb, squares in (((1.0, 1.0, 1.0), white), ((0.5, 0.5, 0.5), grey)):
        mat = scene.material(rgb, 0.5, 0.5, 30.0, 0.0, 0.0)
        scene.polygons(squares.reshape(-1, 3), np.full(len(squares), 4), mat)
    orange = scene.material((1.0, 0.5, 0.1), 0.75, 0.25, 37.0, 0.0, 0.0)
    pts, nrm = teapot_triangles(n)
    scene.patches(pts.reshape(-1, 3), nrm.reshape(-1, 3), np.full(len(pts), 3), orange)
    return scene.build(f"<generated teapot {n}>", printed)
