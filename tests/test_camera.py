"""Camera files and lens tables: readers, clear errors for impossible cameras, and the figures
`host camera` prints, checked against thin-lens optics."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from host.camera.lens import CameraError, describe
from host.camera.lensfile import read_camera, read_table, read_toml
from host.cli import main
from protocols import dtypes

CAMERAS = Path(__file__).resolve().parents[1] / "host" / "cameras"


def test_bundled_cameras_read_and_make_sense():
    for path in sorted(CAMERAS.iterdir()):
        d = describe(read_camera(path))
        assert d["effective_focal_length_m"] > 0 and d["f_number"] > 0.5, path
        assert 0 < d["field_of_view_deg"]["diagonal"] < 180, path


def test_thin_lens_camera_figures_match_thin_lens_formulas():
    cam = read_toml(CAMERAS / "thin_f2.8.toml")
    d = describe(cam, focus=2.0, coc=3e-5)
    f, n = 0.05, 2.8
    assert d["effective_focal_length_m"] == pytest.approx(f, rel=1e-9)
    assert d["f_number"] == pytest.approx(0.05 / 0.017857, rel=1e-4)
    assert d["film_z_m"] == pytest.approx(-1 / (1 / f - 1 / 2.0), rel=1e-9)
    assert d["hyperfocal_distance_m"] == pytest.approx(f * f / (d["f_number"] * 3e-5), rel=1e-9)
    image = 1 / (1 / f - 1 / 2.0)
    assert d["field_of_view_deg"]["horizontal"] == pytest.approx(
        2 * math.degrees(math.atan(0.018 / image)), rel=1e-9
    )
    assert n == pytest.approx(d["f_number"], rel=1e-4)


def test_lens_table_matches_the_same_lens_as_toml(tmp_path):
    # The biconvex lens as a table: scene side first, mm, last thickness = back focal distance.
    table = tmp_path / "biconvex.txt"
    table.write_text("# r t n aperture\n50 5 1.5 30\n-50 49.152542 0 30\n")
    t = describe(read_table(table))
    toml = describe(read_toml(CAMERAS / "biconvex.toml"))
    assert t["effective_focal_length_m"] == pytest.approx(
        toml["effective_focal_length_m"], rel=1e-9
    )
    assert t["back_focal_distance_m"] == pytest.approx(toml["back_focal_distance_m"], rel=1e-9)


@pytest.mark.parametrize(
    "text,where",
    [
        ("50 5 1.5\n", ":1:"),
        ("# c\n50 5 x 30\n", ":2:"),
        ("50 5 1.5 30\n-50 40 1.5 30\n", ":2:"),
        ("5 5 1.5 30\n", ":1:"),
    ],
)
def test_bad_lens_tables_name_the_line(tmp_path, text, where):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(CameraError, match=str(path).replace(".", r"\.") + where):
        read_table(path)


def test_impossible_cameras_fail_before_tracing(tmp_path):
    base = (CAMERAS / "thin_f2.8.toml").read_text()
    film_in_front = tmp_path / "a.toml"
    film_in_front.write_text(base.replace("[film]\n", "[film]\nz = 0.01\n"))
    with pytest.raises(CameraError, match="film"):
        read_toml(film_in_front)
    diverging = tmp_path / "b.toml"
    diverging.write_text(base.replace("focal = 0.05", "focal = -0.05"))
    with pytest.raises(CameraError, match="real image"):
        read_toml(diverging)
    inside = tmp_path / "c.toml"
    inside.write_text(base.replace("distance = 2.0", "distance = 0.03"))
    with pytest.raises(CameraError, match="focus"):
        read_toml(inside)
    unknown = tmp_path / "d.toml"
    unknown.write_text(base.replace('type = "thin_lens"', 'type = "mirror"'))
    with pytest.raises(CameraError, match="element 2"):
        read_toml(unknown)


def test_host_camera_command(capsys, tmp_path):
    assert main(["camera", str(CAMERAS / "hexagon.toml"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["effective_focal_length_m"] == pytest.approx(0.05, rel=1e-9)
    assert main(["camera", str(CAMERAS / "thin_f2.8.toml"), "--focus", "10"]) == 0
    out = capsys.readouterr().out
    assert "f/2.80" in out and "50.00 mm" in out
    assert main(["camera", str(tmp_path / "missing.toml")]) == 2


def _empty_scene():
    from protocols.scene import SceneData, View

    return SceneData(view=View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0), background=(1.0, 1.0, 1.0))


def _lens_with_stop(shape: str, stop_r: float, lens_r: float = 0.01):
    """A thin lens with a diaphragm in its own plane: the generation area is the lens rim, so
    a pixel sees the stop's share of it."""
    from host.camera.lens import Camera
    from tests.test_optics import stack

    elements = stack(
        {"kind": dtypes.THIN_LENS, "z": 0.0, "focal": 0.05, "ax": lens_r, "ay": lens_r},
        {
            "kind": dtypes.DIAPHRAGM,
            "z": 0.0,
            "ax": stop_r,
            "ay": stop_r,
            "shape": dtypes.POLYGON_RIM if shape == "hexagon" else dtypes.ELLIPSE,
            "sides": 6 if shape == "hexagon" else 0,
        },
    )
    return Camera(elements, 0.036, 0.024, None, 2.0)


@pytest.mark.parametrize(
    "shape,stop_r,leaving",
    [
        ("ellipse", 0.005, None),  # round: rays are drawn in the exit pupil, few are lost
        ("hexagon", 0.01, 3 * math.sqrt(3) / (2 * math.pi)),  # aimed at the rim: hexagon / disc
    ],
)
def test_a_stop_loses_rays_but_the_centre_stays_as_bright_as_the_scene(shape, stop_r, leaving):
    """Under adaptation "all" a ray weighs the area it was drawn from over the area passing
    from the film's centre: however the rays are aimed, the centre of a uniform background is
    the background, and the share of rays stopped is the stop's share of the aimed area."""
    from host.planning.request import Request
    from host.run.oneprocess import render
    from tests.conftest import records

    scene = _empty_scene()
    cam = _lens_with_stop(shape, stop_r)
    rs = records(width=8, height=6, camera=cam, generation=2, spp=4096, adaptation="all", threads=1)
    img, stats = render(Request(scene, *rs))
    assert img[2:4, 3:5].mean() == pytest.approx(1.0, abs=0.02)
    share = stats["camera"]["centre_rays_leaving_camera"]
    if leaving is None:
        assert share > 0.9
    else:
        assert share == pytest.approx(leaving, abs=0.02)
    # Averaged over the rays that left the camera instead, nothing is lost.
    rs = records(
        width=8, height=6, camera=cam, generation=2, spp=4096, adaptation="left", threads=1
    )
    img, _ = render(Request(scene, *rs))
    np.testing.assert_allclose(img[2:4, 3:5], 1.0, atol=1e-12)


def test_camera_image_is_upright_and_not_mirrored():
    # An off-axis sphere lands in the same quadrant through the lens as through the pinhole.
    from host.planning.request import Request
    from host.run.oneprocess import render
    from protocols.scene import View
    from tests.conftest import make_scene, records

    scene = make_scene(
        spheres=[((1.0, 0.8, 0.0), 0.3, 0)],
        lights=[(0, 0, -10)],
        view=View((0, 0, -5), (0, 0, 0), (0, 1, 0), 45.0),
    )
    cam = read_toml(CAMERAS / "thin_f2.8.toml")
    centroids = []
    for camera in (None, cam):
        rs = records(
            width=40, height=40, camera=camera, **({"generation": 1} if camera else {}), threads=1
        )
        img, _ = render(Request(scene, *rs))
        ys, xs = np.nonzero(img.sum(axis=2) > 0.05)
        assert len(ys)
        centroids.append((np.sign(xs.mean() - 19.5), np.sign(ys.mean() - 19.5)))
    assert centroids[0] == centroids[1] and centroids[0] != (0, 0)


def test_host_render_through_a_camera(tmp_path, capsys):
    scene = Path(__file__).resolve().parents[1] / "host" / "examples" / "showcase.nff"
    out = tmp_path / "c.png"
    args = [
        "render",
        str(scene),
        "-o",
        str(out),
        "--width",
        "24",
        "--height",
        "16",
        "--spp",
        "4",
        "--quiet",
        "--stats",
        str(tmp_path / "s.json"),
    ]
    assert main([*args, "--camera", str(CAMERAS / "hexagon.toml")]) == 0
    stats = json.loads((tmp_path / "s.json").read_text())
    assert 0 < stats["rays"]["eye_rays"] <= 24 * 16 * 4  # lost rays are not traced
    bad = tmp_path / "bad.toml"
    bad.write_text("[[element]]\ntype = 'mirror'\n")
    assert main([*args, "--camera", str(bad)]) == 2
    assert "element 1" in capsys.readouterr().err


def test_spp_is_the_rays_per_pixel_through_a_camera_16_unless_given(tmp_path, capsys):
    """--spp N traces N rays a pixel through a camera as through the pinhole (a thin lens
    loses none: every ray is an eye ray); without it, a camera traces LENS_SPP = 16, as its
    help says; --lens-rays is gone (argparse: unrecognised)."""
    from host.camera.policy import LENS_SPP

    scene = tmp_path / "s.nff"
    scene.write_text(
        "v\nfrom 0 0 -3\nat 0 0 0\nup 0 1 0\nangle 40\nhither 0\nresolution 6 4\n"
        "b 0 0 0\nl 0 0 -3\nf 1 1 1 1 0 1 0 1\ns 0 0 0 1\n"
    )
    stats = tmp_path / "s.json"
    args = ["render", str(scene), "-o", str(tmp_path / "o.png"), "--quiet", "--mesh", "1x1"]
    args += ["--camera", str(CAMERAS / "thin_f2.8.toml"), "--stats", str(stats)]
    for given, per_pixel in ((["--spp", "3"], 3), ([], LENS_SPP)):
        assert main([*args, *given]) == 0
        s = json.loads(stats.read_text())
        assert s["image"]["spp"] == s["camera"]["rays_per_pixel"] == per_pixel
        assert s["rays"]["eye_rays"] == 6 * 4 * per_pixel
    assert LENS_SPP == 16
    with pytest.raises(SystemExit) as e:
        main([*args, "--lens-rays", "4"])
    assert e.value.code == 2 and "unrecognized arguments: --lens-rays" in capsys.readouterr().err


def test_wide_angle_example_has_visible_barrel_distortion():
    # Chief rays (through the stop's centre) from field angles theta land at h(theta) on the
    # film focused at infinity; a distortion-free lens puts them at EFL tan(theta). The wide
    # lens agrees paraxially and bows inward further out (barrel): -1% at 10 deg, < -2% at 20.
    from host.camera.focus import cardinal, film_for_distance
    from meshnode.engine.optics import trace

    el = read_camera(CAMERAS / "wide.txt").elements
    efl = cardinal(el)["effective_focal_length"]
    film, front = film_for_distance(el, math.inf), float(el["z"].max())
    stop = int(np.flatnonzero(el["kind"] == dtypes.DIAPHRAGM)[0])

    def distortion(deg):
        d = (math.sin(math.radians(deg)), 0.0, -math.cos(math.radians(deg)))
        lo, hi = -0.05, 0.05  # entry height whose ray crosses the stop plane on the axis
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            o, dd, alive = trace(el[stop + 1 :], [(mid, 0.0, front + 0.01)], [d], backward=True)
            # A ray the front rims stop is far off the axis, on its entry height's side.
            x = o[0, 0] + (el["z"][stop] - o[0, 2]) * dd[0, 0] / dd[0, 2] if alive[0] else mid
            lo, hi = (lo, mid) if x > 0 else (mid, hi)
        o, dd, alive = trace(el, [(mid, 0.0, front + 0.01)], [d], backward=True)
        assert alive[0]
        h = abs(o[0, 0] + (film - o[0, 2]) * dd[0, 0] / dd[0, 2])
        return h / (efl * math.tan(math.radians(deg))) - 1

    d = [distortion(a) for a in (0.5, 5, 10, 15, 20)]
    assert abs(d[0]) < 1e-4
    assert all(a > b for a, b in zip(d, d[1:], strict=False))  # bowing grows with the field
    assert d[2] < -0.005 and d[4] < -0.02


@pytest.mark.parametrize(
    "film,element,what",
    [
        ("width = -0.036\nheight = 0.024", "focal = 0.05", "width and height must be positive"),
        ("width = inf\nheight = 0.024", "focal = 0.05", "width and height must be positive"),
        ("width = 0.036\nheight = 0", "focal = 0.05", "width and height must be positive"),
        ("width = 0.036\nheight = 0.024\nz = nan", "focal = 0.05", "z must be finite"),
        ("width = 0.036\nheight = 0.024", "focal = nan", "element 1: focal must be finite"),
        ("width = 0.036\nheight = 0.024", "focal = 0.05\nn_after = inf", "n_after must be"),
    ],
)
def test_a_camera_file_with_an_impossible_film_or_element_is_refused(tmp_path, film, element, what):
    f = tmp_path / "cam.toml"
    f.write_text(
        f'[film]\n{film}\n[[element]]\ntype = "thin_lens"\n{element}\ndiameter = 0.02\nz = 0.0\n'
    )
    with pytest.raises(CameraError, match="cam.toml") as e:
        read_camera(f)
    assert what in str(e.value)


def test_a_film_of_another_shape_than_the_image_is_reconciled_and_said(tmp_path, capsys):
    # 36 x 24 mm (3:2) on a square scene: without --width/--height the image becomes 3:2;
    # with both, the film is cropped to 24 x 24 mm. Never stretched, always said.
    scene = tmp_path / "s.nff"
    scene.write_text(
        "v\nfrom 0 0 -5\nat 0 0 0\nup 0 1 0\nangle 40\nhither 0\nresolution 48 48\nb 0.5 0.5 0.5\n"
    )
    camera = str(Path(__file__).resolve().parents[1] / "host" / "cameras" / "thin_f2.8.toml")
    stats = tmp_path / "s.json"
    common = [
        str(scene),
        "-o",
        str(tmp_path / "a.png"),
        "--camera",
        camera,
        "--stats",
        str(stats),
        "--quiet",
    ]
    assert main(["render", *common]) == 0
    assert "rendering 48x32 so nothing is stretched" in capsys.readouterr().err
    assert (
        json.loads(stats.read_text())["image"]["width"],
        json.loads(stats.read_text())["image"]["height"],
    ) == (48, 32)
    assert main(["render", *common, "--width", "40", "--height", "40"]) == 0
    assert "cropping the film to 24 x 24 mm" in capsys.readouterr().err
