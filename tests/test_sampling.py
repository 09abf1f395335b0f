"""Camera sampling: strata get one ray each, the concentric map keeps area, adaptive sampling
traces exactly the rays it says and matches full sampling where it refines, special
jittering has no depth of field, and the camera gives the same image on 1x1, 2x2 and 3x3."""

import asyncio
import math

import numpy as np
import pytest

from host.camera.lens import Camera
from host.planning.request import Request
from host.run.connections import Nodes
from host.run.localmesh import LocalMesh
from host.run.meshclient import render_on_mesh
from host.run.oneprocess import render
from meshnode.engine.lenscamera import first_pass, to_area, unit_points
from protocols import dtypes
from protocols.camera import CameraSampling, CameraSpec
from protocols.render import MeshPlan
from protocols.scene import View
from tests.conftest import make_scene, records
from tests.test_optics import stack


def thin_camera(focus=2.0, rim=0.01):
    lens = stack({"kind": dtypes.THIN_LENS, "z": 0.0, "focal": 0.05, "ax": rim, "ay": rim})
    return Camera(lens, 0.024, 0.018, None, focus)


def dof_scene():
    """Spheres at 1, 2 and 5 m in front of a camera at the origin looking down +z: with the
    lens focused at 2 m the middle one is sharp and the others blurred."""
    view = View(eye=(0, 0, 0), at=(0, 0, 1), up=(0, 1, 0), angle=30.0)
    return make_scene(
        spheres=[
            ((-0.12, 0.0, 1.0), 0.05, 0),
            ((0.0, 0.02, 2.0), 0.12, 0),
            ((0.6, -0.1, 5.0), 0.4, 0),
        ],
        polygons=[([(-9, -0.6, 0.5), (9, -0.6, 0.5), (9, -0.6, 30), (-9, -0.6, 30)], 0)],
        lights=[(1.0, 3.0, -1.0)],
        view=view,
        background=(0.2, 0.3, 0.5),
    )


@pytest.mark.parametrize("n", [4, 9, 16, 5, 7])
@pytest.mark.parametrize("sampling", ["uniform", "jittered"])
def test_each_stratum_gets_one_ray(n, sampling):
    pixels = np.arange(50)
    p = unit_points(sampling, n, pixels, np.arange(n), seed=3, dim=2)
    m = math.isqrt(n)
    nx, ny = (m, m) if m * m == n else (n, n)
    cells = np.floor(p[..., 0] * nx).astype(int) + nx * np.floor(p[..., 1] * ny).astype(int)
    for row in cells:  # each pixel: n different cells, one per column (and row)
        assert len(set(row.tolist())) == n
        assert len(set((row % nx).tolist())) == min(n, nx)
        assert len(set((row // nx).tolist())) == min(n, ny)
    # Adaptive's first two samples sit in opposite corner strata.
    a, b = p[:, 0], p[:, -1]
    assert np.all(a < 1.0 / min(nx, ny) + 1e-12) and np.all(b > 1 - 1.0 / min(nx, ny) - 1e-12)


def test_concentric_map_keeps_area():
    # Uniform points on the square land uniformly on the disc: equal-area rings and equal
    # sectors hold equal shares (binomial sd ~0.001 for 200k points), all inside the disc.
    d = to_area(np.random.default_rng(1).random((200_000, 2)), ellipse=True)
    r2 = (d**2).sum(-1)
    assert r2.max() <= 1 + 1e-12
    counts = np.histogram(r2, bins=5, range=(0, 1))[0]
    np.testing.assert_allclose(counts / len(r2), 0.2, atol=0.004)
    ang = np.histogram(np.arctan2(d[:, 1], d[:, 0]), bins=8, range=(-np.pi, np.pi))[0]
    np.testing.assert_allclose(ang / len(r2), 1 / 8, atol=0.004)


def _render(camera=None, **kw):
    rs = records(width=48, height=36, camera=camera or thin_camera(), threads=1, **kw)
    return render(Request(dof_scene(), *rs))


def test_adaptive_traces_corners_then_the_rest_where_they_differ():
    n = 16
    full, full_stats = _render(spp=n, sampling="jittered")
    pixels = 48 * 36
    # Threshold 0: a pixel is refined unless its two corner rays agree exactly; refined
    # pixels get exactly the jittered rays, so they equal the jittered image.
    img, st = _render(spp=n, sampling="adaptive", threshold=0.0)
    refined = st["camera"]["refined_pixels"]
    assert st["rays"]["eye_rays"] == 2 * pixels + (n - 2) * refined  # no lost rays here
    assert 0 < refined < pixels
    diff = np.abs(img - full).max(axis=2)
    assert np.count_nonzero(diff > 1e-12) <= pixels - refined
    # A threshold above any colour difference refines nothing: two rays a pixel.
    img2, st2 = _render(spp=n, sampling="adaptive", threshold=10.0)
    assert st2["rays"]["eye_rays"] == 2 * pixels and st2["camera"]["refined_pixels"] == 0
    # The usual threshold: far fewer rays than full sampling, close to its image.
    img3, st3 = _render(spp=n, sampling="adaptive", threshold=0.05)
    assert st3["rays"]["eye_rays"] < 0.6 * full_stats["rays"]["eye_rays"]
    assert np.sqrt(((img3 - full) ** 2).mean()) < 0.02


def test_first_pass_is_opposite_corners_of_each_pattern():
    spec = CameraSpec(thin_camera().elements, 0.024, 0.018, -0.05, CameraSampling(generation=4))
    assert first_pass(spec, 16).tolist() == [1, 4]  # (-c, -c) and (c, c) of the five points
    spec = CameraSpec(thin_camera().elements, 0.024, 0.018, -0.05, CameraSampling(generation=6))
    assert first_pass(spec, 16).tolist() == [0, 8]


def test_special_jittering_has_no_depth_of_field():
    # Over the film area instead of the lens: every ray passes the lens centre, so the
    # image is the centre-ray image (type 1) over the same film points, whatever the
    # aperture; lens sampling at that aperture blurs visibly (CoC of 5 pixels at 1 m).
    kw = dict(generation=2, spp=16, sampling="uniform", film_area="rectangle")
    wide, _ = _render(thin_camera(rim=0.05), special=True, **kw)
    tiny, _ = _render(thin_camera(rim=0.0001), special=True, **kw)
    np.testing.assert_allclose(wide, tiny, atol=1e-9)
    centre, _ = _render(thin_camera(rim=0.05), **{**kw, "generation": 1})
    np.testing.assert_allclose(wide, centre, atol=1e-9)
    blurred, _ = _render(thin_camera(rim=0.05), **kw)
    assert np.abs(blurred - centre).max() > 0.1


def test_film_area_antialiases_an_edge():
    # Centre rays only (type 1): pixels are 0 or 1 across the sharp sphere's rim; over a film
    # area of one pixel they take values between, and the mean brightness is unchanged.
    sharp, _ = _render(generation=1)
    soft, _ = _render(generation=1, spp=16, film_area="rectangle")
    assert soft.mean() == pytest.approx(sharp.mean(), rel=0.02)
    levels = lambda im: len(np.unique(np.round(im[..., 0], 6)))  # noqa: E731
    assert levels(soft) > levels(sharp)


def _mesh(rows, cols, rs, progress=None):
    with LocalMesh(rows * cols) as addresses:
        coro = render_on_mesh(
            Request(dof_scene(), rs.image, rs.engine, rs.camera, MeshPlan(rows, cols, 1.0)),
            Nodes(addresses),
            progress=progress,
        )
        return asyncio.run(asyncio.wait_for(coro, 180))


@pytest.mark.parametrize(
    "sampling,meshes", [("jittered", [(2, 2)]), ("adaptive", [(2, 2), (3, 3)])]
)
def test_camera_on_the_mesh_gives_the_single_node_image(sampling, meshes):
    rs = records(width=30, height=24, camera=thin_camera(), spp=9, sampling=sampling, threads=1)
    ref, ref_stats = render(Request(dof_scene(), *rs))
    for rows, cols in meshes:
        reports = []
        img, stats = _mesh(rows, cols, rs, reports.append)
        np.testing.assert_allclose(img, ref, rtol=0, atol=1e-9)
        assert stats["rays"]["eye_rays"] == ref_stats["rays"]["eye_rays"] == sum(reports)
        if sampling == "adaptive":
            assert stats["camera"]["refined_pixels"] == ref_stats["camera"]["refined_pixels"]


def test_adaptive_refines_a_pixel_unlike_its_side_neighbours_and_halos_agree():
    # A 5x4 image whose pixel (2, 1) has both corner rays white and every other pixel black:
    # the pixel and its four side neighbours are refined (their corner means differ by 1),
    # nothing else. Split into two rectangles with deposits routed to owners and halos, the
    # two nodes decide exactly as one node does.
    from meshnode.mesh.adaptive import AdaptiveFilm, RectIndex, deposit_routes

    spec = CameraSpec(
        thin_camera().elements, 0.024, 0.018, -0.05, CameraSampling(sampling="adaptive")
    )
    width, height, n = 5, 4, spec.per_pixel(4)
    pixels = np.arange(width * height)
    ids = np.concatenate([pixels * n + k for k in first_pass(spec, 4)])
    rgb = np.zeros((len(ids), 3))
    rgb[ids // n == 1 * width + 2] = 1.0
    whole = AdaptiveFilm(spec, 4, (0, width, 0, height), width, height)
    whole.corner_alive[:] = True  # (no pass 1 here: every corner ray left the camera)
    whole.add(ids, rgb)
    refined = set(np.flatnonzero(whole.decide()).tolist())
    assert refined == {7, 2, 6, 8, 12}  # (2, 1) and (2, 0), (1, 1), (3, 1), (2, 2)

    rects = [(0, 2, 0, height), (2, width, 0, height)]
    films = [AdaptiveFilm(spec, 4, r, width, height) for r in rects]
    for film in films:
        film.corner_alive[:] = True
    idx, dest = deposit_routes(ids, n, first_pass(spec, 4), width, height, RectIndex(rects, width))
    for node, film in enumerate(films):
        mine = idx[dest == node]
        film.add(ids[mine], rgb[mine])
    split = {int(p) for f in films for p in f.pixels[f.decide()]}
    assert split == refined


def test_adaptive_refines_pixels_whose_corner_rays_the_camera_stops():
    # The hexagonal stop (6.25 mm) is smaller than the lens the rays are aimed at (15 mm):
    # the corner rays, near the lens rim, never get out. They say nothing of the scene, so
    # every pixel is refined and the image is the jittered one, not black.
    elements = stack(
        {"kind": dtypes.THIN_LENS, "z": 0.0, "focal": 0.05, "ax": 0.015, "ay": 0.015},
        {
            "kind": dtypes.DIAPHRAGM,
            "z": 0.002,
            "ax": 0.00625,
            "ay": 0.00625,
            "shape": dtypes.POLYGON_RIM,
            "sides": 6,
        },
    )
    cam = Camera(elements, 0.024, 0.018, None, 2.0)
    full, _ = _render(cam, spp=16, sampling="jittered")
    img, st = _render(cam, spp=16, sampling="adaptive")
    assert st["camera"]["refined_pixels"] == 48 * 36
    np.testing.assert_allclose(img, full, atol=1e-12)
    assert full.mean() > 0.05


def test_host_render_warns_when_most_camera_rays_are_stopped(tmp_path, capsys):
    """A hexagonal stop is not round about the axis, so rays are aimed at the lens rim listed
    first (no exit pupil), and most are stopped."""
    from host.cli import main

    scene = tmp_path / "s.nff"
    scene.write_text(
        "v\nfrom 0 0 -3\nat 0 0 0\nup 0 1 0\nangle 40\nhither 0\nresolution 8 8\n"
        "b 0 0 0\nl 0 0 -3\nf 1 1 1 1 0 1 0 1\ns 0 0 0 1\n"
    )
    camera = tmp_path / "c.toml"
    camera.write_text(
        '[[element]]\ntype = "thin_lens"\nz = 0.0\nfocal = 0.05\ndiameter = 0.03\n'
        '[[element]]\ntype = "diaphragm"\nz = 0.002\ndiameter = 0.008\n'
        'shape = "hexagon"\n'
    )
    args = [
        "render",
        str(scene),
        "-o",
        str(tmp_path / "o.png"),
        "--quiet",
        "--mesh",
        "1x1",
        "--camera",
        str(camera),
    ]
    assert main(args) == 0
    assert "of the camera rays leave the camera" in capsys.readouterr().err


@pytest.mark.parametrize("generation", [4, 5, 6, 7])
def test_fixed_patterns_stay_inside_the_generation_area(generation):
    # Aimed at a stop that is the film-most element, every ray of the five- and nine-point
    # patterns leaves the camera, jittered or not (none on the rim, none beyond it).
    from meshnode.engine.lenscamera import camera_rays

    spec = CameraSpec(
        thin_camera().elements, 0.024, 0.018, -0.0513, CameraSampling(generation=generation)
    )
    _, alive = camera_rays(spec, 16, dof_scene().view, 64, 48, np.arange(64 * 48))
    assert alive.all()
    special = CameraSpec(
        thin_camera().elements,
        0.024,
        0.018,
        -0.0513,
        CameraSampling(generation=generation, film_area="rectangle", special=True),
    )
    assert first_pass(special, 16).tolist() == ([1, 4] if generation < 6 else [0, 8])


def test_rect_index_finds_the_rectangle_of_every_pixel():
    # Mesh rectangles with uneven cuts and image tiles with a ragged last row and column:
    # the index agrees with a test of every rectangle, and pixels outside all are -1.
    from meshnode.mesh.adaptive import RectIndex

    width, height = 37, 23
    meshes = [
        [(0, 10, 0, 8), (10, 37, 0, 8), (0, 10, 8, 23), (10, 37, 8, 23)],
        [
            (x, min(x + 8, width), y, min(y + 8, height))
            for y in range(0, height, 8)
            for x in range(0, width, 8)
        ],
        [(0, 37, 0, 5), (0, 37, 9, 23)],
    ]
    pixels = np.arange(width * height)
    x, y = pixels % width, pixels // width
    for rects in meshes:
        want = np.full(len(pixels), -1)
        for i, (x0, x1, y0, y1) in enumerate(rects):
            want[(x >= x0) & (x < x1) & (y >= y0) & (y < y1)] = i
        assert (RectIndex(rects, width)(pixels) == want).all()
