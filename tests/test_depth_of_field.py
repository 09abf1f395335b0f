"""Focusing a camera for a depth of field, and autofocus, checked by tracing rays from points
at the limiting distances through the stopped lens: their blur spot on the film must be the
largest circle of confusion asked for."""

import math

import numpy as np
import pytest

from host.camera.focus import circle_of_confusion, dof_from_near_far
from host.camera.lens import Camera, CameraError, entrance_pupil_radius, focused, with_f_number
from host.cli import main
from host.planning.request import Request
from host.run.oneprocess import render
from meshnode.engine.optics import trace
from protocols import dtypes
from protocols.scene import View
from tests.conftest import make_scene, records
from tests.test_optics import stack

F = 0.05
COC = 30e-6


def lens_camera(rim=0.02, focus=2.0):
    return Camera(
        stack({"kind": dtypes.THIN_LENS, "z": 0.0, "focal": F, "ax": rim, "ay": rim}),
        0.036,
        0.024,
        None,
        focus,
    )


def spot_diameter(cam: Camera, distance: float) -> float:
    """Blur spot on the film of an on-axis point `distance` in front of the lens: rays from
    it over the whole aperture, traced through the elements to the film plane."""
    front = float(cam.elements["z"].max())
    r = float(cam.elements["ax"].min()) * (1 - 1e-9)  # the stop, in the lens plane here
    a = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1)
    aim = np.concatenate([ring * r * s for s in np.linspace(0.5, 1.0, 50)])
    aim[:, 2] = front
    src = np.array([0.0, 0.0, front + distance])
    o, d, alive = trace(cam.elements, np.broadcast_to(src, aim.shape), aim - src, backward=True)
    film = cam.focused_film_z()
    t = (film - o[alive, 2]) / d[alive, 2]
    p = o[alive, :2] + t[:, None] * d[alive, :2]
    return 2 * np.hypot(p[:, 0], p[:, 1]).max()


@pytest.mark.parametrize("near,far", [(1.5, 4.0), (0.8, 1.2), (3.0, math.inf)])
def test_near_far_depth_of_field_blurs_both_limits_by_the_coc(near, far):
    cam = focused(lens_camera(), near=near, far=far, coc=COC)
    s, n = dof_from_near_far(F, COC, near, far)
    assert cam.focus_distance == pytest.approx(s)
    assert F / (2 * entrance_pupil_radius(cam.elements)) == pytest.approx(n, rel=1e-3)
    # The spot of a point at either limit is the circle of confusion (its edge is the rim of
    # the stop, traced ray by ray; the outermost traced ring is the rim itself).
    assert spot_diameter(cam, near) == pytest.approx(COC, rel=2e-3)
    if math.isfinite(far):
        assert spot_diameter(cam, far) == pytest.approx(COC, rel=2e-3)
    assert spot_diameter(cam, s) < 1e-3 * COC


def test_tolerance_keeps_focus_plus_minus_tolerance_sharp():
    cam = focused(lens_camera(), focus=2.5, tolerance=0.3, coc=COC)
    assert cam.focus_distance == 2.5
    assert spot_diameter(cam, 2.2) == pytest.approx(COC, rel=2e-3)  # the binding near side
    assert spot_diameter(cam, 2.8) < COC
    n = F / (2 * entrance_pupil_radius(cam.elements))
    assert circle_of_confusion(F, n, 2.5, 2.8) == pytest.approx(spot_diameter(cam, 2.8), rel=3e-3)


def test_impossible_depth_of_field_fails_clearly():
    with pytest.raises(CameraError, match="inside the focal length"):
        focused(lens_camera(), near=0.04, far=1.0, coc=COC)
    # A shallow range at 1 m needs f/0.4: wider than the 40 mm lens opens.
    with pytest.raises(CameraError, match="opens only to"):
        with_f_number(lens_camera(rim=0.02), 0.4)
    with pytest.raises(CameraError, match="tolerance"):
        focused(lens_camera(), focus=2.0, tolerance=3.0)


def test_autofocus_finds_the_depth_at_the_image_centre():
    # A wall square to the axis 3.7 m away, seen off-centre too: the probe averages depth
    # along the axis, so it is 3.7 whatever the ray angles; a far wall behind does not count.
    view = View(eye=(0.3, 0.2, -1.0), at=(0.3, 0.2, 0.0), up=(0, 1, 0), angle=40.0)
    wall = [(-5, -5, 2.7), (5, -5, 2.7), (5, 5, 2.7), (-5, 5, 2.7)]
    scene = make_scene(polygons=[(wall, 0)], lights=[(0, 0, -3)], view=view)
    rs = records(width=16, height=12, camera=lens_camera(), distance="auto", threads=1)
    _, stats = render(Request(scene, *rs))
    cam = stats["camera"]
    assert cam["focus_distance_m"] == pytest.approx(3.7, rel=1e-9)
    assert cam["autofocus"]["probe_hits"] == cam["autofocus"]["probe_rays"]
    si = 1 / (1 / F - 1 / 3.7)  # and the film sits where the thin-lens law puts it
    assert cam["film_z_m"] == pytest.approx(-si, rel=1e-9)


def test_host_render_depth_of_field_options(tmp_path, capsys):
    import json

    from tests.test_camera import CAMERAS

    scene = tmp_path / "s.nff"
    scene.write_text(
        "v\nfrom 0 0 -3\nat 0 0 0\nup 0 1 0\nangle 40\nhither 0\nresolution 8 8\n"
        "b 0 0 0\nl 0 0 -3\nf 1 1 1 1 0 1 0 1\ns 0 0 0 1\n"
    )
    out, stats = tmp_path / "o.png", tmp_path / "s.json"
    args = [
        "render",
        str(scene),
        "-o",
        str(out),
        "--stats",
        str(stats),
        "--quiet",
        "--mesh",
        "1x1",
        "--camera",
        str(CAMERAS / "thin_f2.8.toml"),
    ]
    assert main([*args, "--dof-near", "2", "--dof-far", "4"]) == 0
    cam = json.loads(stats.read_text())["camera"]
    assert cam["focus_distance_m"] == pytest.approx(2 * 2 * 4 / 6)
    assert main([*args, "--focus", "auto", "--sampling", "adaptive"]) == 0
    # The sphere's nearest point is 2 m away; the probe's patch around it is a little deeper.
    depth = json.loads(stats.read_text())["camera"]["focus_distance_m"]
    assert 2.0 < depth < 2.01
    assert main([*args, "--dof-near", "0.01"]) == 2
    assert "inside the focal length" in capsys.readouterr().err
    assert main([*args, "--focus", "near"]) == 2


@pytest.mark.parametrize(
    "name", ["balls_s1.nff", "gears_s1.nff", "teapot_s1.nff", "tree_s1.nff", "rings_s1.nff"]
)
def test_mesh_autofocus_probes_only_the_objects_in_its_cone(name):
    # The host focuses a mesh render with an engine over the objects inside the probe's cone:
    # the same depth as a whole-scene engine (a probe ray can hit nothing else), fewer objects.
    from host.camera.autofocus import autofocus_distance, in_probe_cone, probe_engine
    from host.scene.nff import read_nff
    from meshnode.engine import Engine
    from tests.conftest import spd_scene

    scene = read_nff(spd_scene(name))
    whole, _ = autofocus_distance(Engine(scene), scene.view, 64, 48)
    probe, seen = autofocus_distance(probe_engine(scene, 64, 48), scene.view, 64, 48)
    assert probe == whole and seen["probe_hits"] > 0
    keep = in_probe_cone(scene, 64, 48)
    assert keep.sum() < len(keep)
