"""The exit pupil of a camera: where in the plane of its film-most element light from a film
point can pass to the scene (pbrt's idea for its realistic camera: bound it by sampling that
plane from film points at several distances from the axis).

Camera rays aimed at the whole film-most element are mostly wasted when a smaller stop or a
vignetting element lies beyond it (a lens table cannot list its stop first): through a
wide-angle lens only 6% left. The pupil is found once per camera and focus, as one ellipse per
band of film distance (for film points on the +x axis; a lens round about its axis turns it
with the point), and travels in the CameraSpec; `lenscamera.aim_points` samples within it.

The bound is conservative up to the sampling: every aim point found to pass is kept with the
cell around it, in two searches (a coarse grid over 1.5 times the element, then a fine one
over what passed, grown while anything passes at its border). A sliver of pupil narrower
than a coarse cell can be missed, as in pbrt.
"""

import numpy as np

from meshnode.engine.optics import through
from protocols.dtypes import ELLIPSE, ELLIPSOID

BANDS = 32  # bands of film distance from the centre to the film's corner
FILM_POINTS = 3  # film distances tried per band: its edges and its middle
COARSE = 32  # aim points per side of the first search
FINE = 48  # ... and of the second, over the cells the first found passing
AREA_GRID = 200  # per side, for the area passing from the film's centre
REACH = 1.5  # the first search spans this many times the element's semi-aperture
ROUND_POINTS = 64  # points on the element's rim checked against a band's ellipse


def is_round(elements: np.ndarray) -> bool:
    """Every rim, opening and surface round about the axis: the pupil of a film point then
    turns with the point, so one ellipse per distance describes the whole film."""
    e = elements
    rims = (e["shape"] == ELLIPSE) & (e["ax"] == e["ay"])
    caps = (e["kind"] != ELLIPSOID) | (e["cap_x"] == e["cap_y"])
    return bool(np.all(rims & caps))


def passing(elements: np.ndarray, film_z: float, radii, xs, ys) -> np.ndarray:
    """Which aim points (xs, ys) in the film-most element's plane pass from at least one of
    the film points (r, 0, film_z), r in `radii`: rays that leave the lens."""
    first_z = float(elements["z"].min())
    r = np.repeat(np.asarray(radii, float), len(xs))
    x, y = np.tile(xs, len(radii)), np.tile(ys, len(radii))
    o = np.stack([r, np.zeros_like(r), np.full_like(r, film_z)], axis=1)
    d = np.stack([x - r, y, np.full_like(r, first_z - film_z)], axis=1)
    d /= np.linalg.norm(d, axis=1)[:, None]
    alive = np.ones(len(o), dtype=np.bool_)
    through(o, d, elements, False, alive)
    return alive.reshape(len(radii), len(xs)).any(axis=0)


def _grid(x0: float, x1: float, y1: float, n: int):
    """Cell centres of an n x n grid over [x0, x1] x [-y1, y1], and the cells' half sizes."""
    hx, hy = (x1 - x0) / (2 * n), y1 / n
    xs = x0 + hx * (2 * np.arange(n) + 1)
    ys = -y1 + hy * (2 * np.arange(n) + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return gx.ravel(), gy.ravel(), hx, hy


def band_ellipse(elements: np.ndarray, film_z: float, radii) -> tuple[float, float, float]:
    """(centre x, semi-axis x, semi-axis y) of an ellipse holding every cell of the aim plane
    found passing from film points at `radii`; zeros when none passes."""
    reach = REACH * float(elements["ax"][int(np.argmin(elements["z"]))])
    xs, ys, hx, hy = _grid(-reach, reach, reach, COARSE)
    ok = passing(elements, film_z, radii, xs, ys)
    if not ok.any():
        return 0.0, 0.0, 0.0
    # The fine search spans one coarse cell beyond every coarse point that passed (a cell
    # whose centre is blocked may still pass in part), grown while passing points touch it.
    x0, x1 = xs[ok].min() - 2 * hx, xs[ok].max() + 2 * hx
    y1 = np.abs(ys[ok]).max() + 2 * hy
    for _ in range(4):
        fx, fy, fhx, fhy = _grid(x0, x1, y1, FINE)
        fine = passing(elements, film_z, radii, fx, fy)
        edge = (fx - fhx <= x0) | (fx + fhx >= x1) | (np.abs(fy) + fhy >= y1)
        if not np.any(fine & edge):
            break
        x0, x1, y1 = x0 - 2 * hx, x1 + 2 * hx, y1 + 2 * hy
    xs, ys, hx, hy, ok = fx, fy, fhx, fhy, fine
    if not ok.any():
        return 0.0, 0.0, 0.0
    # Corners of every passing cell: an ellipse holding them holds the cells (convexity).
    cx = np.concatenate([xs[ok] - hx, xs[ok] + hx, xs[ok] - hx, xs[ok] + hx])
    cy = np.concatenate([ys[ok] - hy, ys[ok] - hy, ys[ok] + hy, ys[ok] + hy])
    centre = 0.5 * (cx.min() + cx.max())
    w, h = 0.5 * (cx.max() - cx.min()), float(np.abs(cy).max())
    scale = float(np.sqrt(((cx - centre) / w) ** 2 + (cy / h) ** 2).max())
    return float(centre), scale * w, scale * h


def centre_area(elements: np.ndarray, film_z: float) -> float:
    """Area of the film-most element's plane through which light from the film's centre
    leaves the lens: counted on a fine grid over 1.5 times the element; exactly the
    element's ellipse when all of it and nothing beyond passes (a stop listed first)."""
    first = elements[int(np.argmin(elements["z"]))]
    ax, ay = float(first["ax"]), float(first["ay"])
    xs, ys, hx, hy = _grid(-REACH * ax, REACH * ax, REACH * ay, AREA_GRID)
    ok = passing(elements, film_z, [0.0], xs, ys)
    inside = (xs / ax) ** 2 + (ys / ay) ** 2 <= 1.0
    if np.all(ok == inside):
        return float(np.pi * ax * ay)
    return float(ok.sum()) * 4 * hx * hy


def covers_element(table: np.ndarray, elements: np.ndarray) -> bool:
    """Does every band's ellipse hold the whole film-most element? Then the pupil saves
    nothing, and rays are aimed at the element as they always were."""
    rim = float(elements["ax"][int(np.argmin(elements["z"]))])
    t = np.linspace(0.0, 2 * np.pi, ROUND_POINTS, endpoint=False)
    x, y = rim * np.cos(t), rim * np.sin(t)
    for centre, a, b in table:
        if a <= 0 or b <= 0 or np.any(((x - centre) / a) ** 2 + (y / b) ** 2 > 1.0):
            return False
    return True


def exit_pupil(elements: np.ndarray, film_z: float, film_radius: float):
    """(bands as a flat tuple of (centre x, a, b), film distance they span, area passing from
    the film's centre) for a camera focused with its film at `film_z`. No bands when the lens
    is not round about its axis, or the pupil is the whole film-most element everywhere (rays
    are then aimed at the element); area 0 when nothing passes from the centre."""
    area = centre_area(elements, film_z)
    if not is_round(elements) or film_radius <= 0 or area <= 0:
        return (), 0.0, area
    radius = 1.02 * film_radius  # film-area samples reach a little beyond the corner
    edges = np.linspace(0.0, radius, BANDS + 1)
    table = np.array(
        [
            band_ellipse(elements, film_z, np.linspace(lo, hi, FILM_POINTS))
            for lo, hi in zip(edges[:-1], edges[1:], strict=True)
        ]
    )
    if covers_element(table, elements):
        return (), 0.0, area
    return tuple(float(v) for v in table.ravel()), radius, area
