"""The camera's optics against optics: the thin-lens law, the lensmaker's equation, focusing
at infinity, diaphragm areas and total internal reflection."""

import math

import numpy as np
import pytest

from host.camera.focus import cardinal, film_for_distance
from meshnode.engine.optics import inside_rim, trace
from protocols import dtypes


def stack(*rows):
    e = np.zeros(len(rows), dtypes.ELEMENT)
    for i, r in enumerate(rows):
        for k, v in r.items():
            e[i][k] = v
    return e


def thin(f, z=0.0, rim=0.0125):
    return stack(
        {"kind": dtypes.THIN_LENS, "z": z, "focal": f, "ax": rim, "ay": rim, "n_after": 1.0}
    )


@pytest.mark.parametrize("f", [0.035, 0.05, 0.2])
@pytest.mark.parametrize("so", [0.5, 2.0, 10.0])
def test_thin_lens_images_so_to_si(f, so):
    si = 1.0 / (1.0 / f - 1.0 / so)  # 1/So + 1/Si = 1/f
    assert film_for_distance(thin(f), so) == pytest.approx(-si, rel=1e-9)


def test_focus_at_infinity_puts_the_film_at_the_focal_plane():
    assert film_for_distance(thin(0.05), math.inf) == pytest.approx(-0.05, rel=1e-9)
    c = cardinal(thin(0.05))
    assert c["effective_focal_length"] == pytest.approx(0.05, rel=1e-9)
    assert c["rear_principal_plane_z"] == pytest.approx(0.0, abs=1e-12)


def test_thin_lens_sends_every_ray_from_a_point_to_its_image():
    f, so = 0.05, 1.0
    si = 1 / (1 / f - 1 / so)
    rng = np.random.default_rng(0)
    ang, rad = rng.uniform(0, 2 * np.pi, 500), 0.012 * np.sqrt(rng.uniform(0, 1, 500))
    pts = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])  # within the 12.5 mm rim
    o = np.tile([0.0, 0.0, so], (500, 1))  # object point on the axis, scene side
    d = np.column_stack([pts, np.full(500, -so)])
    o2, d2, alive = trace(thin(f), o, d, backward=True)
    assert alive.all()
    t = (-si - o2[:, 2]) / d2[:, 2]
    np.testing.assert_allclose(o2[:, 0] + t * d2[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(o2[:, 1] + t * d2[:, 1], 0.0, atol=1e-12)


def test_thick_biconvex_lens_matches_the_lensmaker():
    n, r, thick = 1.5, 0.05, 0.005
    lens = stack(
        {"kind": dtypes.CAP, "z": 0.0, "radius": r, "n_after": n, "ax": 0.02, "ay": 0.02},
        {"kind": dtypes.CAP, "z": thick, "radius": -r, "n_after": 1.0, "ax": 0.02, "ay": 0.02},
    )
    r1, r2 = r, -r
    power = (n - 1) * (1 / r1 - 1 / r2 + (n - 1) * thick / (n * r1 * r2))
    c = cardinal(lens)
    assert c["effective_focal_length"] == pytest.approx(1 / power, rel=1e-6)
    # Back focal distance f (1 - (n-1) d / (n R1)), R1 the first surface light from the scene
    # meets (convex toward it: +r in the light's own sign convention).
    bfd = (1 / power) * (1 - (n - 1) * thick / (n * r))
    assert c["back_focal_distance"] == pytest.approx(bfd, rel=1e-6)
    # Principal planes of a symmetric lens: f (n-1) d / (n R) inside from each vertex, and the
    # front focal distance equals the back one.
    inset = (1 / power) * (n - 1) * thick / (n * r)
    assert c["rear_principal_plane_z"] == pytest.approx(inset, rel=1e-6)
    assert c["front_principal_plane_z"] == pytest.approx(thick - inset, rel=1e-6)
    assert c["front_focal_distance"] == pytest.approx(bfd, rel=1e-6)


def test_hexagonal_diaphragm_passes_the_hexagons_share_of_a_disc():
    r = 0.01
    hexagon = stack(
        {
            "kind": dtypes.DIAPHRAGM,
            "z": 0.0,
            "ax": r,
            "ay": r,
            "shape": dtypes.POLYGON_RIM,
            "sides": 6,
        }
    )
    rng = np.random.default_rng(1)
    ang = rng.uniform(0, 2 * np.pi, 200_000)
    rad = r * np.sqrt(rng.uniform(0, 1, 200_000))
    o = np.column_stack([rad * np.cos(ang), rad * np.sin(ang), np.full(len(ang), -1.0)])
    d = np.tile([0.0, 0.0, 1.0], (len(o), 1))
    _, _, alive = trace(hexagon, o, d)
    expected = (3 * math.sqrt(3) / 2) / math.pi  # hexagon area / circumscribed disc area
    assert alive.mean() == pytest.approx(expected, abs=0.004)
    # Exact shape: corners (rotation 0) on the x axis, flat edges at the apothem.
    apothem = r * math.cos(math.pi / 6)
    assert inside_rim(r * 0.999, 0.0, r, r, dtypes.POLYGON_RIM, 6, 0.0)
    assert not inside_rim(0.0, apothem * 1.001, r, r, dtypes.POLYGON_RIM, 6, 0.0)
    assert inside_rim(0.0, apothem * 0.999, r, r, dtypes.POLYGON_RIM, 6, 0.0)


def test_total_internal_reflection_loses_the_ray():
    # A glass hemisphere, flat side toward the film: a ray parallel to the axis at height x
    # meets the dome at asin(x / R) from its normal; beyond asin(1 / 1.5) it cannot leave.
    r = 0.01
    dome = stack(
        {"kind": dtypes.PLANE, "z": 0.0, "n_after": 1.5, "ax": r, "ay": r},
        {"kind": dtypes.CAP, "z": r, "radius": -r, "n_after": 1.0, "ax": r, "ay": r},
    )
    critical = r / 1.5
    heights = [0.5 * r, 0.99 * critical, 1.01 * critical, 0.9 * r]
    o = [[x, 0.0, -1.0] for x in heights]
    _, d, alive = trace(dome, o, [[0.0, 0.0, 1.0]] * 4)
    assert alive.tolist() == [True, True, False, False]
    # Snell at the dome for the first ray: sin(out) = 1.5 sin(in), measured from the normal.
    x = heights[0]
    incidence = math.asin(x / r)
    out = math.asin(1.5 * math.sin(incidence))
    assert math.atan2(-d[0, 0], d[0, 2]) == pytest.approx(out - incidence, abs=1e-12)


def test_rays_outside_a_rim_are_lost():
    lens = thin(0.05, rim=0.01)
    _, _, alive = trace(lens, [[0.005, 0, -1], [0.011, 0, -1]], [[0, 0, 1], [0, 0, 1]])
    assert alive.tolist() == [True, False]
