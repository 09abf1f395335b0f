"""Bokeh measured on rendered images, checked against thin-lens optics (DESIGN.md 7), not
against the code: the circle of confusion of an out-of-focus point is
C = f^2 (So/Soa - 1) / (N (So - f)), and a regular hexagonal diaphragm gives a hexagonal spot.

The object is a small sphere on the optical axis in a scene without lights: every hit deposits
the same ambient colour, so the sphere is a uniformly bright disc on a black background (a
small glowing source). Its defocused image is its sharp image - the disc projected through the
lens centre onto the film - convolved with the spot a point makes, which is the diaphragm's
opening scaled by k = |Si(So) - Si(Soa)| / Si(Soa) (Si the thin lens' image distance; the spot
is inverted for a point beyond the focus, upright for a nearer one). The camera is a thin lens
with a diaphragm of the same size in its plane, and its front vertex is the view's eye, so
distances along the axis from the eye are distances from the lens. Pixels are read at their
centres (film area "centre"): a pixel is the spot's value at one film point, estimated from
jittered rays over the lens.
"""

import math

import numpy as np
import pytest

from host.camera.lens import Camera
from host.planning.request import Request
from host.run.oneprocess import render
from protocols import dtypes
from protocols.scene import View
from tests.conftest import make_scene, records
from tests.test_optics import stack

F = 0.05  # focal length (m)


def image_distance(s: float) -> float:
    """Thin lens: 1/So + 1/Si = 1/f."""
    return 1.0 / (1.0 / F - 1.0 / s)


def circle_of_confusion(so: float, soa: float, n: float) -> float:
    """Diameter on the film of the spot of a point at Soa, the lens focused at So, f/N."""
    return F * F * abs(so / soa - 1.0) / (n * (so - F))


def lens(stop_radius: float, film: float, sides: int = 0, rotation: float = 0.0) -> Camera:
    """The thin lens with a diaphragm in its plane: an ellipse (disc) of radius `stop_radius`,
    or a regular `sides`-gon of that circumradius with a corner at `rotation` (radians, from
    the camera's x (right) toward y (up)). The lens rim, where rays are aimed (generation
    area 2), is the disc around the diaphragm."""
    elements = stack(
        {"kind": dtypes.THIN_LENS, "z": 0.0, "focal": F, "ax": stop_radius, "ay": stop_radius},
        {
            "kind": dtypes.DIAPHRAGM,
            "z": 0.0,
            "ax": stop_radius,
            "ay": stop_radius,
            "shape": dtypes.POLYGON_RIM if sides else dtypes.ELLIPSE,
            "sides": sides,
            "rotation": rotation,
        },
    )
    return Camera(elements, film, film, None, 2.0)


def glowing_sphere(distance: float, radius: float):
    """A white sphere on the axis `distance` from the eye; no lights, black background."""
    view = View(eye=(0.0, 0.0, 0.0), at=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0), angle=45.0)
    return make_scene(spheres=[((0.0, 0.0, distance), radius, 0)], view=view)


def shoot(scene, camera: Camera, size: int, focus: float, rays: int = 256, **kw) -> np.ndarray:
    """The rendered image's brightness (mean of the channels; the sphere is white)."""
    kw.setdefault("seed", 7)
    settings = records(
        width=size,
        height=size,
        camera=camera,
        generation=2,
        spp=rays,
        sampling="jittered",
        adaptation="all",
        distance=focus,
        **kw,
    )
    image, _ = render(Request(scene, *settings))
    return image.mean(axis=2)


def moments(img: np.ndarray):
    """Total, centroid (column, row) and the per-axis variances, in pixels."""
    rows, cols = np.mgrid[: img.shape[0], : img.shape[1]]
    total = img.sum()
    cx, cy = (img * cols).sum() / total, (img * rows).sum() / total
    vx = (img * (cols - cx) ** 2).sum() / total
    vy = (img * (rows - cy) ** 2).sum() / total
    return total, cx, cy, vx, vy


# -- 1. The circle of confusion ------------------------------------------------------------------

COC_PITCH = 20e-6  # film pixel (m): 64 pixels make a 1.28 mm film
COC_SIZE = 64


@pytest.mark.parametrize(
    "so,soa,n",
    [
        (2.0, 1.0, 2.0),  # nearer than the focus: C = 0.641 mm = 32 px
        (1.0, 2.5, 2.8),  # beyond the focus: C = 0.564 mm = 28 px
        (0.5, 0.35, 4.0),
    ],  # a close-up, nearer: C = 0.595 mm = 30 px
)
def test_circle_of_confusion_matches_the_thin_lens_formula(so, soa, n):
    """Second moments add under convolution, and a uniform disc of diameter C has the variance
    C^2 / 16 along each axis: C = 4 sqrt(var(defocused) - var(sharp)), per axis, with var(sharp)
    from the same sphere rendered in focus and scaled to the film position focused at So."""
    radius = 0.003 * soa  # its sharp image is about 8 px in radius: a quarter of C
    scene = glowing_sphere(soa, radius)
    cam = lens(F / (2 * n), COC_SIZE * COC_PITCH)
    # In focus every ray from a film point meets the same object point, so the image is binary
    # at pixel centres: jagged, its variance 2% off. Averaged over the pixel (film area
    # "rectangle") it is the sharp image convolved with the pixel: + 1/12 px^2 per axis.
    sharp = moments(shoot(scene, cam, COC_SIZE, focus=soa, film_area="rectangle"))
    sharp_var = [sharp[3] - 1 / 12, sharp[4] - 1 / 12]
    blurred = moments(shoot(scene, cam, COC_SIZE, focus=so))

    # The sharp image is a uniform disc, the silhouette magnified by Si/So: rho^2/4 per axis.
    rho = image_distance(soa) * radius / math.sqrt(soa**2 - radius**2) / COC_PITCH
    assert sharp_var == pytest.approx([rho**2 / 4] * 2, rel=0.005)

    # A point on the axis images on the axis, focused or not: the image centre (pixel 31.5).
    centre = (COC_SIZE - 1) / 2
    for m in (sharp, blurred):
        assert m[1] == pytest.approx(centre, abs=0.1) and m[2] == pytest.approx(centre, abs=0.1)

    # Defocus spreads light without losing it: the film at Si(So) sees the sharp image scaled by
    # Si(So)/Si(Soa) through the lens centre, so the total scales by its square (pixel values
    # are radiance times the share of the lens seeing the sphere, summed over the pixels).
    scale = image_distance(so) / image_distance(soa)
    assert blurred[0] == pytest.approx(sharp[0] * scale**2, rel=0.01)

    predicted = circle_of_confusion(so, soa, n)
    for axis in (0, 1):
        measured = 4 * math.sqrt(blurred[3 + axis] - sharp_var[axis] * scale**2) * COC_PITCH
        # Tolerance: over seeds the jittered estimate scatters by about 0.3%; the sphere's depth
        # (its visible surface lies on average r/3 = 0.1% of Soa nearer than its centre) moves
        # C by 0.1% at most.
        assert measured == pytest.approx(predicted, rel=0.01), (axis, measured, predicted)


def test_film_area_antialiasing_keeps_the_blur_round():
    """With a film generation area the blur must stay round: the image of a glowing sphere on the
    axis has the same spread across as up and down (it does at film area "centre", to 0.3%).

    A regression test: film strata once followed the lens strata by a fixed column map
    (k * step mod m^2), which moved the film point against the lens point in x and made the
    blur 2% narrower across than up and down (var x / var y = 0.962 at 256 rays)."""
    scene = glowing_sphere(1.0, 0.003)
    cam = lens(F / 4, COC_SIZE * COC_PITCH)
    _, _, _, vx, vy = moments(shoot(scene, cam, COC_SIZE, focus=2.0, film_area="rectangle"))
    assert vx == pytest.approx(vy, rel=0.01)


# -- 2. The shape of the bokeh -------------------------------------------------------------------

HEX_PITCH = 15e-6
HEX_SIZE = 80
HEX_STOP = 0.0125  # diaphragm circumradius (m): f/2 for the disc
HEX_ROTATION = 15.0  # degrees: a mirrored image would put corners where the edges should be
HEX_SO, HEX_SOA = 2.0, 1.0
HEX_SPHERE = 0.001  # its sharp image is 3.4 px in radius against a 21 px spot
SPOT_SCALE = abs(image_distance(HEX_SO) - image_distance(HEX_SOA)) / image_distance(HEX_SOA)
SPOT_R = HEX_STOP * SPOT_SCALE / HEX_PITCH  # the spot's circumradius in pixels: 21.4
RHO = image_distance(HEX_SO) * HEX_SPHERE / math.sqrt(HEX_SOA**2 - HEX_SPHERE**2) / HEX_PITCH


def spot_inside(shape: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The ideal spot (the diaphragm scaled by SPOT_SCALE) in image pixels, x right, y up.

    Orientation: the film shows the opening upright (near point) or inverted (far point), and
    the image is the film read mirrored in x and y (the lens inverts), so a corner at angle a in
    the camera frame (x right, y up) lands at a or a + 180 degrees in the image: the same
    directions for a hexagon."""
    if shape == "disc":
        return x * x + y * y <= SPOT_R**2
    apothem = SPOT_R * math.cos(math.pi / 6)
    inside = np.ones(np.shape(x), bool)
    for k in range(6):
        a = math.radians(HEX_ROTATION) + (2 * k + 1) * math.pi / 6  # edge k's normal
        inside &= x * math.cos(a) + y * math.sin(a) <= apothem
    return inside


def expected_radius(shape: str, angle: float) -> float:
    """Where the ideal spot blurred by the sphere's sharp image (a uniform disc of radius RHO)
    falls to half its plateau along `angle`: the distance at which half of that disc lies
    inside the spot (bisection). At an edge's midpoint that is the edge itself; a 120 degree
    corner is pulled inward."""
    g = np.linspace(-RHO, RHO, 241)
    kx, ky = np.meshgrid(g, g)
    keep = kx**2 + ky**2 <= RHO**2
    kx, ky = kx[keep], ky[keep]
    lo, hi = 0.0, 1.5 * SPOT_R
    for _ in range(40):
        s = 0.5 * (lo + hi)
        inside = spot_inside(shape, s * math.cos(angle) + kx, s * math.sin(angle) + ky).mean()
        lo, hi = (s, hi) if inside > 0.5 else (lo, s)
    return 0.5 * (lo + hi)


def radius_profile(img, cx, cy, level, angles) -> np.ndarray:
    """Per direction (image x right, y up), the outermost distance from (cx, cy) at which the
    bilinearly interpolated image is still at `level`."""
    steps = np.arange(0.0, 1.6 * SPOT_R, 0.25)
    out = []
    for a in angles:
        x, y = cx + steps * math.cos(a), cy - steps * math.sin(a)
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = x - x0, y - y0
        v = (
            img[y0, x0] * (1 - fx) * (1 - fy)
            + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy
            + img[y0 + 1, x0 + 1] * fx * fy
        )
        j = int(np.flatnonzero(v >= level)[-1])
        out.append(steps[j] + 0.25 * (v[j] - level) / (v[j] - v[j + 1]))
    return np.array(out)


@pytest.fixture(scope="module")
def spots():
    """The defocused sphere through the hexagonal and through the round diaphragm, with its
    centroid, total and plateau (the mean where the whole sharp disc fits inside the spot)."""
    scene = glowing_sphere(HEX_SOA, HEX_SPHERE)
    out = {}
    for shape, sides in (("hexagon", 6), ("disc", 0)):
        cam = lens(HEX_STOP, HEX_SIZE * HEX_PITCH, sides, math.radians(HEX_ROTATION))
        # 1024 rays: the sharp image is small, a pixel sees it through a small part of the
        # lens (at 256 rays the plateau scatters by 18% from pixel to pixel, 7% here).
        img = shoot(scene, cam, HEX_SIZE, focus=HEX_SO, rays=1024)
        total, cx, cy, _, _ = moments(img)
        rows, cols = np.mgrid[:HEX_SIZE, :HEX_SIZE]
        r = np.hypot(cols - cx, rows - cy)
        plateau = img[r < SPOT_R * math.cos(math.pi / 6) - RHO - 2].mean()
        out[shape] = (img, total, cx, cy, plateau)
    return out


def hexagon_area(circumradius: float) -> float:
    return 3 * math.sqrt(3) / 2 * circumradius**2


@pytest.mark.parametrize("shape", ["hexagon", "disc"])
def test_bokeh_has_the_area_of_the_scaled_diaphragm(spots, shape):
    """Total / plateau is the spot's area, whatever blurs it (the plateau is where the spot
    covers the whole sharp image): the hexagon's 3 sqrt(3)/2 R^2 or the disc's pi R^2, R the
    diaphragm's radius scaled by k. Tolerance: over seeds the ratio scatters by 0.4%."""
    _, total, _, _, plateau = spots[shape]
    area = hexagon_area(SPOT_R) if shape == "hexagon" else math.pi * SPOT_R**2
    assert total / plateau == pytest.approx(area, rel=0.015)


def test_hexagonal_bokeh_corners_point_where_the_diaphragms_do(spots):
    """The complex moment Z6 = sum I (x + iy)^6 / sum I about the centroid is unchanged by
    convolution with anything round (its lower moments in x + iy vanish), so it is the scaled
    hexagon's own: arg Z6 = 6 x (corner angle), |Z6| that of a hexagon of circumradius R. A
    disc has none. Tolerances: |Z6| goes as R^6 and weighs the noisy rim most: over seeds it
    scatters by 1.5%; 6% in |Z6| is 1% in R. The corner angle (60 degree periodic) scatters
    by 0.3 degree."""
    t = np.linspace(0.0, 2 * math.pi, 1 << 16, endpoint=False)
    # The hexagon's boundary radius over the angle, a corner at HEX_ROTATION.
    u = (t - math.radians(HEX_ROTATION)) % (math.pi / 3) - math.pi / 6
    boundary = SPOT_R * math.cos(math.pi / 6) / np.cos(u)
    want = (np.exp(6j * t) * boundary**8 / 8).mean() * 2 * math.pi / hexagon_area(SPOT_R)
    z6 = {}
    for shape in ("hexagon", "disc"):
        img, total, cx, cy, _ = spots[shape]
        rows, cols = np.mgrid[:HEX_SIZE, :HEX_SIZE]
        z = (cols - cx) - 1j * (rows - cy)  # image x right, y up
        z6[shape] = (img * z**6).sum() / total
    assert abs(z6["hexagon"]) == pytest.approx(abs(want), rel=0.06)
    corner = math.degrees(np.angle(z6["hexagon"])) / 6
    assert (corner - HEX_ROTATION + 30) % 60 - 30 == pytest.approx(0.0, abs=1.0)
    assert abs(z6["disc"]) < 0.1 * abs(want)


@pytest.mark.parametrize("shape", ["hexagon", "disc"])
def test_bokeh_radius_over_the_angle(spots, shape):
    """Thresholded at half its plateau, the spot reaches the scaled diaphragm's edges: at an
    edge's midpoint the hexagon's apothem R cos 30, at its corners a little less than R (the
    sharp disc rounds them; expected_radius works out how much); the disc R all round. So the
    radius at edge midpoints over that at corners is cos 30 / (1 - rounding) = 0.908 for the
    hexagon, 1 for the disc. Tolerances: one direction's radius scatters by about 0.2 px (the
    jittered estimate at the rim); over seeds the six directions' mean moves by 0.1 px and
    the ratio by 0.004."""
    img, _, cx, cy, plateau = spots[shape]
    corners = np.radians(HEX_ROTATION + 60 * np.arange(6))
    edges = corners + math.radians(30)
    r_corner = radius_profile(img, cx, cy, plateau / 2, corners).mean()
    r_edge = radius_profile(img, cx, cy, plateau / 2, edges).mean()
    want_corner = expected_radius(shape, corners[0])
    want_edge = expected_radius(shape, edges[0])
    if shape == "hexagon":
        assert want_edge == pytest.approx(SPOT_R * math.cos(math.pi / 6), rel=1e-3)
        assert 0.85 * SPOT_R < want_corner < SPOT_R
    assert r_corner == pytest.approx(want_corner, rel=0.015)
    assert r_edge == pytest.approx(want_edge, rel=0.015)
    assert r_edge / r_corner == pytest.approx(want_edge / want_corner, abs=0.015)
    if shape == "hexagon":
        assert r_edge / r_corner < 0.93  # clearly not round
    else:
        assert r_edge / r_corner == pytest.approx(1.0, abs=0.02)

    # Six-fold: over the full turn, the profile's strongest harmonic (besides the mean) is the
    # sixth for the hexagon, its peaks at the corners; the disc's profile is flat.
    angles = np.radians(np.arange(0.0, 360.0, 1.0))
    profile = radius_profile(img, cx, cy, plateau / 2, angles)
    harmonics = np.abs(np.fft.rfft(profile))[1:13] / len(profile)
    if shape == "hexagon":
        assert int(np.argmax(harmonics)) + 1 == 6
        peak = -math.degrees(np.angle(np.fft.rfft(profile)[6])) / 6
        assert (peak - HEX_ROTATION + 30) % 60 - 30 == pytest.approx(0.0, abs=1.5)
        assert harmonics[5] > 4 * np.delete(harmonics, [5, 11]).max()
    else:
        assert harmonics.max() < 0.01 * SPOT_R
