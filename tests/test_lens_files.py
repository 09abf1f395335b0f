"""Lens files as users bring them (the common prescription format: the shared lens files, else
the same tables in tests/data), the exit pupil, ellipsoidal caps and the pinhole's samplers,
each against a reference of its own: a y-nu paraxial trace written here, the thin lens of the
same f-number, the Cartesian oval, the scene's own pinhole rays and a many-ray image."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from host.camera.lens import Camera, CameraError, describe
from host.camera.lensfile import read_camera, read_toml
from host.camera.setup import CameraSetup, PinholeSetup
from host.cli import main
from host.planning.request import Request
from host.run.oneprocess import render
from meshnode.engine.optics import trace
from protocols import dtypes
from protocols.camera import CameraSampling
from protocols.render import EngineSpec, ImageSpec
from protocols.scene import SceneData, View
from tests.conftest import lens_file
from tests.test_optics import stack

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("dgauss.50mm.dat", "wide.22mm.dat")


def shared_lens(name: str) -> Path:
    """A lens file as users bring it (tests.conftest.lens_file)."""
    return lens_file(name)


def paraxial_efl(path: Path) -> float:
    """Effective focal length (mm) by a y-nu trace of a ray parallel to the axis, straight
    from the table's rows: n'u' = nu - y c (n' - n), then y += t u' (the stop has no power)."""
    rows = []
    for line in path.read_text().splitlines():
        words = line.split("#", 1)[0].split()
        if words:
            rows.append([float(w) for w in words])
    y, nu, n = 1.0, 0.0, 1.0
    for radius, thickness, index, _ in rows:
        n_after = index if index > 0 else 1.0  # 0 (the stop's row) is air
        c = 0.0 if radius == 0 else 1.0 / radius
        nu -= y * c * (n_after - n)
        n = n_after
        y += thickness * nu / n
    return -1.0 / nu  # height 1 over the final slope (in air)


def _uniform_scene(width=36, height=24) -> SceneData:
    """Nothing but a white background: every pixel that light reaches should be 1."""
    return SceneData(
        view=View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0, 0.0, width, height),
        background=(1.0, 1.0, 1.0),
    )


def _thin_lens(efl: float, n: float) -> Camera:
    """An ideal lens of focal length `efl` stopped to f/n by a diaphragm listed first."""
    return Camera(
        stack(
            {"kind": dtypes.DIAPHRAGM, "ax": efl / (2 * n), "ay": efl / (2 * n)},
            {"kind": dtypes.THIN_LENS, "focal": efl, "ax": efl, "ay": efl, "n_after": 1.0},
        ),
        0.036,
        0.024,
    )


def _render(scene, setup, width=36, height=24, seed=0):
    image = ImageSpec(width=width, height=height, spp=16, seed=seed)
    return render(Request(scene, image, EngineSpec(threads=2), setup))


# ---------------------------------------------------------------------------- lens tables


@pytest.mark.parametrize("name", SHIPPED)
def test_host_camera_on_shipped_tables_gives_the_paraxial_focal_length(name, capsys):
    path = shared_lens(name)
    assert main(["camera", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    expected = paraxial_efl(path) / 1000
    assert d["effective_focal_length_m"] == pytest.approx(expected, rel=1e-3)
    # Last thickness 0: the film is placed by focusing at infinity, on the back focal point.
    assert d["focus_distance_m"] == "infinity"
    assert d["film_z_m"] == pytest.approx(d["rear_principal_plane_z_m"] - expected, rel=1e-6)
    # The f-number option scales the stop.
    assert main(["camera", str(path), "--f-number", "8", "--film-size", "24x16"]) == 0
    assert "f/8.00" in capsys.readouterr().out


def test_table_rows_comments_missing_last_thickness_and_air(tmp_path):
    """Comments and blank lines anywhere, 1 and 0 both air, a last row without its
    thickness: the same lens as the plain table."""
    plain = tmp_path / "plain.dat"
    plain.write_text("50 5 1.5 30\n-50 0 1 30\n")
    odd = tmp_path / "odd.dat"
    odd.write_text("# a lens\n\n  50\t5\t1.5\t30   # front\n# between\n\n-50 0 30\n\n# end\n")
    a, b = read_camera(plain), read_camera(odd)
    np.testing.assert_array_equal(a.elements, b.elements)
    assert a.film_z is None and b.film_z is None  # placed by focusing
    assert a.focused_film_z() == pytest.approx(b.focused_film_z())
    fixed = tmp_path / "fixed.dat"
    fixed.write_text("50 5 1.5 30\n0 1 0 20\n-50 40 1 30\n")  # a stop row in air (index 0)
    cam = read_camera(fixed, film_size=(0.024, 0.016))
    assert cam.film_z == pytest.approx(-0.046) and (cam.film_width, cam.film_height) == (
        0.024,
        0.016,
    )


@pytest.mark.parametrize(
    "rows,line,words",
    [
        ("50 5 1.5 30\nfifty 0 1 30\n", 2, "'fifty' is not a number"),
        ("50 5 1.5 30 7\n-50 0 1 30\n", 1, "expected 4 numbers"),
        ("50 1.5 30\n-50 0 1 30\n", 1, "only the last row may leave out its thickness"),
        ("50 5 1.5 -30\n-50 0 1 30\n", 1, "aperture diameter must be positive"),
        ("50 5 0.5 30\n-50 0 1 30\n", 1, "neither air"),
        ("50 5 1.5 30\n-50 nan 1 30\n", 2, "finite"),
        ("50 5 1.5 30\n-50 -1 1 30\n", 2, "thickness must be >= 0"),
        ("10 5 1.5 30\n-50 0 1 30\n", 1, "smaller than half the aperture"),
        ("50 5 1.5 30\n-50 0 1.5 30\n", 2, "must leave the light in air"),
    ],
)
def test_bad_table_rows_name_the_file_and_line(tmp_path, rows, line, words, capsys):
    path = tmp_path / "bad.dat"
    path.write_text("# header\n" + rows)
    with pytest.raises(CameraError, match=f"bad.dat:{line + 1}: .*{words}"):
        read_camera(path)
    assert main(["camera", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"bad.dat:{line + 1}:" in err


# ---------------------------------------------------------------------------- exit pupil


@pytest.mark.parametrize("name", SHIPPED)
def test_most_camera_rays_leave_through_the_exit_pupil_and_the_centre_is_as_bright_as_a_thin_lens(
    name,
):
    cam = read_camera(shared_lens(name))
    d = describe(cam)
    setup = CameraSetup(cam, CameraSampling())
    scene = _uniform_scene()
    img, stats = _render(scene, setup)
    left = stats["rays"]["eye_rays"] / (36 * 24 * 16)
    assert left >= 0.5
    assert stats["camera"]["rays_leaving_lens"] >= 0.5
    # Aimed at the whole rear element instead (the same weights), far fewer leave.
    spec, _ = setup.spec(scene, ImageSpec(width=36, height=24), None)
    assert len(spec.pupil) > 0
    from meshnode.engine.lenscamera import camera_rays

    pixels = np.arange(36 * 24)
    _, alive = camera_rays(spec, 16, scene.view, 36, 24, pixels)
    _, alive_rear = camera_rays(replace(spec, pupil=()), 16, scene.view, 36, 24, pixels)
    assert alive.mean() > 1.5 * alive_rear.mean()
    # As bright at the centre as an ideal lens of the same f-number (colour adaptation all).
    thin, _ = _render(
        scene,
        CameraSetup(_thin_lens(d["effective_focal_length_m"], d["f_number"]), CameraSampling()),
    )
    centre = (slice(11, 13), slice(17, 19))
    np.testing.assert_allclose(thin[centre], 1.0, atol=1e-12)
    assert img[centre].mean() == pytest.approx(thin[centre].mean(), rel=0.05)


def test_drawing_rays_in_the_pupil_changes_no_pixel_beyond_noise():
    """The same image, vignetted corners included, whether rays are drawn in the exit pupil or
    in one disc twice the rear element's size for every film point (which holds every aim
    point that passes: a curved rear surface passes some beyond its rim in the aim plane):
    each ray weighs the area it was drawn from."""
    from meshnode.engine.lenscamera import camera_rays

    cam = read_camera(shared_lens("wide.22mm.dat"))
    scene = _uniform_scene(6, 4)
    setup = CameraSetup(cam, CameraSampling())
    spec, _ = setup.spec(scene, ImageSpec(width=6, height=4, spp=32768), None)
    rear = float(spec.elements["ax"][0])
    disc = replace(spec, pupil=(0.0, 2 * rear, 2 * rear), pupil_radius=1.0)

    def image(s):
        rays, _ = camera_rays(s, 32768, scene.view, 6, 4, np.arange(24), seed=3)
        return np.bincount(rays["pixel"], weights=rays["w"][:, 0], minlength=24)

    pupil, reference = image(spec), image(disc)
    assert pupil.min() < 0.6  # the corners are vignetted ...
    np.testing.assert_allclose(pupil, reference, atol=0.04)  # ... alike both ways


# ---------------------------------------------------------------------------- ellipsoids


def _ellipsoid(a, b, c, n_after=1.0, rim=0.01, z=0.0):
    return {
        "kind": dtypes.ELLIPSOID,
        "z": z,
        "cap_x": a,
        "cap_y": b,
        "radius": c,
        "n_after": n_after,
        "ax": rim,
        "ay": rim,
    }


def test_an_ellipsoid_with_equal_semi_axes_is_the_spherical_cap():
    r, n = 0.05, 1.6
    glass = {"kind": dtypes.PLANE, "z": -0.2, "n_after": n, "ax": 0.05, "ay": 0.05}
    cap = stack(
        glass, {"kind": dtypes.CAP, "z": 0.0, "radius": -r, "n_after": 1.0, "ax": 0.02, "ay": 0.02}
    )
    ell = stack(glass, _ellipsoid(r, r, -r, rim=0.02))
    rng = np.random.default_rng(1)
    o = np.column_stack([rng.uniform(-0.015, 0.015, (200, 2)), np.full(200, 0.1)])
    d = np.column_stack([rng.uniform(-0.05, 0.05, (200, 2)), -np.ones(200)])
    oc, dc, ac = trace(cap, o, d, backward=True)
    oe, de, ae = trace(ell, o, d, backward=True)
    np.testing.assert_array_equal(ac, ae)
    assert ac.sum() > 150
    np.testing.assert_allclose(oe[ae], oc[ac], atol=1e-12)
    np.testing.assert_allclose(de[ae], dc[ac], atol=1e-12)


def test_a_prolate_ellipsoid_of_eccentricity_one_over_n_focuses_without_aberration():
    """The Cartesian oval of parallel light entering glass of index n: a prolate ellipsoid
    with e = 1/n brings every ray parallel to the axis to its far focus, C (1 + e) behind the
    vertex; a sphere of the same vertex radius A^2 / C does not (spherical aberration)."""
    n, big = 1.5, 0.04  # index; the axial semi-axis C
    e = 1.0 / n
    small = big * math.sqrt(1 - e * e)
    focus = -big * (1 + e)
    film = {"kind": dtypes.PLANE, "z": focus, "n_after": n, "ax": 0.05, "ay": 0.05}
    rim = 0.9 * small * small / big  # within the vertex sphere too
    heights = np.linspace(1e-4, 0.95 * rim, 25)
    o = np.column_stack([heights, np.zeros(25), np.full(25, 0.05)])
    d = np.tile([0.0, 0.0, -1.0], (25, 1))

    def spot(front):
        out, _, alive = trace(stack(film, front), o, d, backward=True)
        assert alive.all()
        return out[:, 0]  # heights where the rays meet the focal plane

    oval = spot(_ellipsoid(small, small, -big, rim=rim))
    assert np.abs(oval).max() < 1e-12 * big / 1e-3
    sphere = spot(
        {
            "kind": dtypes.CAP,
            "z": 0.0,
            "radius": -small * small / big,
            "n_after": 1.0,
            "ax": rim,
            "ay": rim,
        }
    )
    assert np.abs(sphere).max() > 1e-4  # the marginal rays of a sphere cross short of it
    # Paraxially the two agree: the vertex curvature sets the power.
    assert abs(sphere[0]) < 1e-9


def test_ellipsoids_in_camera_files_and_host_camera(tmp_path, capsys):
    """A plano-convex lens with an ellipsoidal front: EFL = R / (n - 1), R = A^2 / C the vertex
    radius, whatever the thickness."""
    a, c, n = 0.02, 0.03, 1.5
    path = tmp_path / "ell.toml"
    path.write_text(
        f'[[element]]\ntype = "plane"\nz = 0.0\nn_after = {n}\ndiameter = 0.02\n'
        f'[[element]]\ntype = "ellipsoid"\nz = 0.004\nsemi_axes = [{a}, {a}, {-c}]\n'
        "diameter = 0.02\n"
    )
    d = describe(read_toml(path))
    assert d["effective_focal_length_m"] == pytest.approx(a * a / c / (n - 1), rel=1e-6)
    assert main(["camera", str(path)]) == 0
    assert f"{a * a / c / (n - 1) * 1000:.2f} mm" in capsys.readouterr().out
    path.write_text('[[element]]\ntype = "ellipsoid"\nsemi_axes = [0.01, 0.01]\ndiameter = 0.01\n')
    with pytest.raises(CameraError, match="element 1: an ellipsoid needs semi_axes"):
        read_toml(path)
    path.write_text(
        '[[element]]\ntype = "ellipsoid"\nsemi_axes = [0.004, 0.01, 0.01]\ndiameter = 0.01\n'
    )
    with pytest.raises(CameraError, match="rim reaches beyond"):
        read_toml(path)


# ---------------------------------------------------------------------------- pinhole


def test_the_pinhole_set_up_as_a_camera_makes_the_scenes_own_rays():
    """One uniform ray per pixel of the pinhole camera is the pixel-centre eye ray."""
    from tests.conftest import make_scene

    view = View((0, 0, -10), (0, 0, 0), (0, 1, 0), 45.0, hither=2.0)
    scene = make_scene(
        spheres=[((0.2, 0.1, 0.0), 1.5, 0)],
        lights=[(2, 3, -4)],
        view=view,
        background=(0.2, 0.3, 0.4),
    )
    image = ImageSpec(width=24, height=16)
    plain, _ = render(Request(scene, image, EngineSpec(threads=1)))
    camera, _ = render(Request(scene, image, EngineSpec(threads=1), PinholeSetup.of("uniform")))
    np.testing.assert_allclose(camera, plain, atol=1e-9)


def test_adaptive_pinhole_from_the_command_line(tmp_path, capsys):
    scene = ROOT / "bench" / "scenes" / "dof.nff"
    stats = tmp_path / "s.json"
    args = [
        "render",
        str(scene),
        "--width",
        "40",
        "--height",
        "30",
        "--mesh",
        "1x1",
        "--quiet",
        "-o",
        str(tmp_path / "a.png"),
    ]
    assert main([*args, "--sampling", "adaptive", "--spp", "16", "--stats", str(stats)]) == 0
    s = json.loads(stats.read_text())
    per_pixel = s["rays"]["eye_rays"] / (40 * 30)
    assert 2 <= per_pixel < 16
    assert s["camera"]["sampling"] == "adaptive" and s["camera"]["refined_pixels"] > 0
    # Options that do not apply fail by name; ones that change nothing warn by name.
    assert main([*args, "--generation", "2"]) == 2
    assert "--generation" in capsys.readouterr().err
    assert main([*args, "--threshold", "0.1"]) == 2
    assert "--threshold" in capsys.readouterr().err
    assert (
        main(
            [
                *args,
                "--camera",
                str(ROOT / "host/cameras/thin_f2.8.toml"),
                "--generation",
                "4",
                "--spp",
                "9",
            ]
        )
        == 0
    )
    assert "warning: --spp 9 changes nothing" in capsys.readouterr().err


def test_adaptive_pinhole_is_closer_to_the_many_ray_image_than_one_ray():
    from host.scene.nff import read_nff

    scene = read_nff(ROOT / "bench" / "scenes" / "dof.nff")
    image = ImageSpec(width=40, height=30)
    ref, _ = render(Request(scene, replace(image, spp=256, seed=9), EngineSpec(threads=2)))
    one, _ = render(Request(scene, image, EngineSpec(threads=2)))
    ada, stats = render(
        Request(scene, replace(image, spp=16), EngineSpec(threads=2), PinholeSetup.of("adaptive"))
    )
    assert stats["rays"]["eye_rays"] < 16 * 40 * 30

    def rms(a):
        return float(np.sqrt(np.mean((a - ref) ** 2)))

    assert rms(ada) < 0.5 * rms(one)


def test_lens_table_renders_from_the_command_line_with_film_size_and_f_number(tmp_path):
    lens = shared_lens("dgauss.50mm.dat")
    scene = tmp_path / "s.nff"
    scene.write_text(
        "v\nfrom 0 0 -3\nat 0 0 0\nup 0 1 0\nangle 40\nhither 0\nresolution 12 8\nb 1 1 1\n"
    )
    stats = tmp_path / "s.json"
    assert (
        main(
            [
                "render",
                str(scene),
                "--camera",
                str(lens),
                "--film-size",
                "24x16",
                "--f-number",
                "4",
                "--spp",
                "8",
                "--mesh",
                "1x1",
                "--quiet",
                "-o",
                str(tmp_path / "o.png"),
                "--stats",
                str(stats),
            ]
        )
        == 0
    )
    cam = json.loads(stats.read_text())["camera"]
    assert cam["f_number"] == pytest.approx(4.0, rel=1e-3)
    assert cam["rays_leaving_lens"] > 0.5


@pytest.mark.parametrize("which", ["pinhole", "lens table"])
def test_adaptive_pinhole_and_lens_tables_on_a_mesh_equal_one_node(which):
    """The pinhole's camera and a lens table's exit pupil travel in the CameraSpec: a 2x2 mesh
    (simulated) gives the single node's image."""
    from protocols.camera import CameraSpec
    from tests.meshsim import render_mesh
    from tests.test_sampling import dof_scene

    scene = dof_scene()
    spp = 9 if which == "pinhole" else 4
    image = ImageSpec(width=30, height=24, spp=spp, seed=3)
    if which == "pinhole":
        setup = PinholeSetup.of("adaptive")
    else:
        setup = CameraSetup(read_camera(shared_lens("wide.22mm.dat")), CameraSampling())
    ref, _ = render(Request(scene, image, EngineSpec(threads=1), setup))
    spec, _ = setup.spec(scene, image.sized(scene.view), lambda: None)
    assert CameraSpec.from_wire(spec.to_wire()) == spec
    img, _, nodes, _ = render_mesh(scene, 2, 2, 1.0, 30, 24, spp=spp, seed=3, camera=spec)
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-12)
    assert ref.mean() > 0.05


def test_a_camera_spec_refuses_unknown_kinds_and_flat_ellipsoids_by_name():
    from protocols.camera import CameraSpec
    from protocols.spec import SpecError

    good = stack(_ellipsoid(0.02, 0.02, -0.03))
    CameraSpec(good, 0.036, 0.024, -0.05)
    for field, value, words in (("cap_x", 0.0, "ellipsoid needs"), ("kind", 9, "kinds are")):
        bad = good.copy()
        bad[field] = value
        with pytest.raises(SpecError, match=f"(?s)CameraSpec.elements .*{words}"):
            CameraSpec(bad, 0.036, 0.024, -0.05)
