"""Tests of the NFF reader: exact records per entity, `file:line:` errors, the SPD scenes."""

import pickle

import numpy as np
import pytest

from host.scene.nff import SceneError, parse_nff, read_nff
from protocols import dtypes
from protocols.scene import View
from tests.conftest import spd_scene

# A minimal valid head: view on lines 1-5, material on line 6; objects start on line 7.
HEAD = "v\nfrom 0 0 5\nat 0 0 0\nup 0 1 0\nangle 45\nf 1 0.5 0.25 0.8 0.2 10 0 1\n"


def scene(body: str):
    return parse_nff(HEAD + body, "t.nff")


def error_of(text: str, source: str = "t.nff") -> SceneError:
    with pytest.raises(SceneError) as info:
        parse_nff(text, source)
    return info.value


def assert_error(text: str, line: int, *words: str) -> None:
    """The message is `t.nff:<line>: ...` and mentions every word given."""
    msg = str(error_of(text))
    assert msg.startswith(f"t.nff:{line}: "), msg
    for w in words:
        assert w in msg, msg


# --- entities ---------------------------------------------------------------------------------


def test_view_keywords_any_order_with_all_fields():
    s = parse_nff(
        "v resolution 640 480 up 0 0 1\nangle 30 yon 1000 at 1 2 3\nhither 0.5 from -1 -2 -3\n"
        "f 1 1 1 1 0 0 0 0\ns 0 0 0 1\n"
    )
    assert s.view == View(
        eye=(-1.0, -2.0, -3.0),
        at=(1.0, 2.0, 3.0),
        up=(0.0, 0.0, 1.0),
        angle=30.0,
        hither=0.5,
        width=640,
        height=480,
    )
    assert s.source == "<string>"


def test_view_defaults_and_empty_scene():
    s = parse_nff("v from 0 0 5 at 0 0 0 up 0 1 0 angle 45")
    assert (s.view.hither, s.view.width, s.view.height) == (0.0, 512, 512)
    assert s.background == (0.0, 0.0, 0.0)
    assert s.n_objects == 0
    for name, dt in [
        ("lights", dtypes.LIGHT),
        ("materials", dtypes.MATERIAL),
        ("spheres", dtypes.SPHERE),
        ("triangles", dtypes.TRIANGLE),
        ("polygons", dtypes.POLYGON),
        ("cones", dtypes.CONE),
    ]:
        arr = getattr(s, name)
        assert arr.dtype == dt and len(arr) == 0, name
    assert s.vertices.shape == (0, 3)


def test_second_view_before_objects_replaces_the_first():
    s = parse_nff("v from 0 0 5 at 0 0 0 up 0 1 0 angle 45\nv from 1 1 1 at 0 0 0 up 0 0 1 angle 9")
    assert s.view.eye == (1.0, 1.0, 1.0) and s.view.angle == 9.0


def test_background_and_comments():
    s = parse_nff("# scene\nb 0.1 0.2 0.3 # sky\nv from 0 0 5 at 0 0 0 up 0 1 0 angle 45#x\n")
    assert s.background == (0.1, 0.2, 0.3)
    assert s.view.angle == 45.0


def test_lights_with_and_without_colour():
    s = parse_nff(
        "l 1 2 3\nl 4 5 6 0.1 0.2 0.3\nl 7 8 9\nv from 0 0 5 at 0 0 0 up 0 1 0 angle 45\n"
    )
    np.testing.assert_array_equal(s.lights["pos"], [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    np.testing.assert_array_equal(s.lights["rgb"], [[1, 1, 1], [0.1, 0.2, 0.3], [1, 1, 1]])


def test_light_colour_then_entity_on_same_line():
    s = parse_nff("v from 0 0 5 at 0 0 0 up 0 1 0 angle 45 l 1 2 3 f 1 1 1 1 0 0 0 0 s 0 0 0 1")
    np.testing.assert_array_equal(s.lights["rgb"], [[1, 1, 1]])
    assert len(s.spheres) == 1


def test_material_fields():
    s = scene("f 0.5 0.6 0.7 0.1 0.2 30 0.9 1.5\n")
    m = s.materials
    assert len(m) == 2
    np.testing.assert_array_equal(m["rgb"], [[1, 0.5, 0.25], [0.5, 0.6, 0.7]])
    assert list(m[1][["kd", "ks", "shine", "t", "ior"]]) == [0.1, 0.2, 30.0, 0.9, 1.5]


def test_opaque_material_with_ior_zero_is_fine():
    # SPD writes `... 0 0` (T = 0, ior = 0) for opaque materials.
    s = scene("f 1 1 1 1 0 100000 0 0\n")
    assert s.materials["ior"][1] == 0.0


def test_transmitting_material_with_positive_ior_is_fine():
    m = scene("f 1 1 1 0.1 0.1 101.148 0.9 1.5\n").materials[1]
    assert (m["t"], m["ior"]) == (0.9, 1.5)


def test_sphere_and_negative_radius_kept():
    s = scene("s 1 2 3 0.5\ns -1 -2 -3 -2\n")
    np.testing.assert_array_equal(s.spheres["center"], [[1, 2, 3], [-1, -2, -3]])
    np.testing.assert_array_equal(s.spheres["radius"], [0.5, -2])
    np.testing.assert_array_equal(s.spheres["gid"], [0, 1])
    np.testing.assert_array_equal(s.spheres["mat"], [0, 0])


def test_cone_on_one_line_equals_cone_on_three_lines():
    one = scene("c 0 0 0 1 0 0 2 0.5\n").cones
    three = scene("c\n0 0 0 1\n0 0 2 0.5\n").cones
    assert one.tobytes() == three.tobytes()
    c = one[0]
    assert (c["gid"], c["mat"]) == (0, 0)
    assert list(c["base"]) == [0, 0, 0] and c["base_r"] == 1
    assert list(c["apex"]) == [0, 0, 2] and c["apex_r"] == 0.5


def test_cone_negative_and_one_zero_radius_kept():
    c = scene("c 0 0 0 -1 0 0 2 0\n").cones[0]
    assert (c["base_r"], c["apex_r"]) == (-1.0, 0.0)


def test_p3_is_a_flat_triangle_with_unit_geometric_normal():
    s = scene("p 3\n0 0 0\n2 0 0\n0 2 0\np 3 0 0 1 0 0 0 0 3 0\n")
    t = s.triangles
    assert len(t) == 2 and len(s.polygons) == 0 and len(s.vertices) == 0
    np.testing.assert_array_equal(t["v"][0], [[0, 0, 0], [2, 0, 0], [0, 2, 0]])
    np.testing.assert_array_equal(t["n"][0], [[0, 0, 1]] * 3)  # counter-clockwise: +z front
    np.testing.assert_array_equal(t["n"][1], [[1, 0, 0]] * 3)
    np.testing.assert_array_equal(t["smooth"], [0, 0])
    np.testing.assert_array_equal(t["gid"], [0, 1])


def test_p4_concave_polygon_kept_with_its_vertices():
    # An arrowhead: the fourth vertex points into the quad.
    dart = [[0, 0, 0], [4, 0, 0], [2, 1, 0], [0, 4, 0]]
    s = scene("p 4\n" + "\n".join(" ".join(map(str, v)) for v in dart) + "\n")
    assert len(s.triangles) == 0
    p = s.polygons
    assert len(p) == 1 and (p[0]["gid"], p[0]["mat"], p[0]["start"], p[0]["count"]) == (0, 0, 0, 4)
    np.testing.assert_array_equal(s.vertices, dart)


def test_l_shaped_polygon_and_vertex_table_slices():
    ell = [[0, 0, 1], [2, 0, 1], [2, 1, 1], [1, 1, 1], [1, 2, 1], [0, 2, 1]]
    quad = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    body = "p 4 " + " ".join(map(str, np.ravel(quad))) + "\n"
    body += "p 3 0 0 0 1 0 0 0 1 0\n"
    body += "p 6 " + " ".join(map(str, np.ravel(ell))) + "\n"
    s = scene(body)
    p = s.polygons
    np.testing.assert_array_equal(p["gid"], [0, 2])
    np.testing.assert_array_equal(p["start"], [0, 4])
    np.testing.assert_array_equal(p["count"], [4, 6])
    np.testing.assert_array_equal(s.vertices, quad + ell)
    np.testing.assert_array_equal(s.triangles["gid"], [1])


def test_polygon_with_collinear_first_vertices_is_accepted():
    # The first three vertices lie on a line; a normal from them alone would be zero.
    s = scene("p 4 0 0 0 1 0 0 2 0 0 1 1 0\n")
    assert len(s.polygons) == 1


def test_pp4_fans_into_two_smooth_triangles_sharing_gid():
    s = scene("s 5 5 5 1\npp 4\n0 0 0 0 0 2\n1 0 0 0 0 3\n1 1 0 0 3 4\n0 1 0 0 0 -1\ns 6 6 6 1\n")
    t = s.triangles
    assert len(t) == 2 and len(s.polygons) == 0
    np.testing.assert_array_equal(t["gid"], [1, 1])
    np.testing.assert_array_equal(t["smooth"], [1, 1])
    np.testing.assert_array_equal(t["v"][0], [[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    np.testing.assert_array_equal(t["v"][1], [[0, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_allclose(t["n"][0], [[0, 0, 1], [0, 0, 1], [0, 0.6, 0.8]], atol=1e-15)
    np.testing.assert_allclose(t["n"][1], [[0, 0, 1], [0, 0.6, 0.8], [0, 0, -1]], atol=1e-15)
    np.testing.assert_array_equal(s.spheres["gid"], [0, 2])
    assert s.n_objects == 3


def test_pp3_is_one_smooth_triangle():
    t = scene("pp 3 0 0 0 1 0 0  1 0 0 0 1 0  0 1 0 0 0 1\n").triangles
    assert len(t) == 1 and t["smooth"][0] == 1
    np.testing.assert_array_equal(t["n"][0], np.eye(3))


def test_gid_and_mat_across_several_materials():
    s = scene(
        "s 0 0 0 1\n"
        "f 0 0 0 0 0 0 0 1\n"
        "p 3 0 0 0 1 0 0 0 1 0\n"
        "c 0 0 0 1 0 0 1 1\n"
        "f 1 1 1 0 0 0 0 1\n"
        "f 0.5 0.5 0.5 0 0 0 0 1\n"
        "pp 3 0 0 0 0 0 1 1 0 0 0 0 1 0 1 0 0 0 1\n"
        "p 4 0 0 0 1 0 0 1 1 0 0 1 0\n"
        "s 1 1 1 1\n"
    )
    assert len(s.materials) == 4
    assert s.spheres[["gid", "mat"]].tolist() == [(0, 0), (5, 3)]
    assert s.triangles[["gid", "mat"]].tolist() == [(1, 1), (3, 3)]
    np.testing.assert_array_equal(s.triangles["smooth"], [0, 1])
    assert s.cones[["gid", "mat"]].tolist() == [(2, 1)]
    assert s.polygons[["gid", "mat"]].tolist() == [(4, 3)]
    assert s.n_objects == 6


def test_number_spellings():
    s = scene("s 1e-16 -0 +3 .5E+1\n")
    np.testing.assert_array_equal(s.spheres["center"], [[1e-16, 0, 3]])
    assert s.spheres["radius"][0] == 5.0


def test_read_nff_names_the_path_as_given(tmp_path, monkeypatch):
    (tmp_path / "ok.nff").write_text(HEAD + "s 0 0 0 1\n")
    (tmp_path / "bad.nff").write_text(HEAD + "s 0 0 0 1\nq\n")
    monkeypatch.chdir(tmp_path)
    assert read_nff("ok.nff").source == "ok.nff"
    assert read_nff(tmp_path / "ok.nff").source == str(tmp_path / "ok.nff")
    with pytest.raises(SceneError, match=r"^bad\.nff:8: "):
        read_nff("bad.nff")


def test_scene_error_is_a_value_error_and_pickles():
    err = error_of(HEAD + "zz\n")
    assert isinstance(err, ValueError)
    back = pickle.loads(pickle.dumps(err))
    assert str(back) == str(err) == "t.nff:7: unknown entity 'zz'"
    assert (back.source, back.line) == ("t.nff", 7)


# --- errors -----------------------------------------------------------------------------------


def test_unknown_entity():
    assert_error(HEAD + "s 0 0 0 1\n\nsphere 0 0 0 1\n", 9, "unknown entity", "'sphere'")


@pytest.mark.parametrize("tok", ["abc", "1,5", "0x10", "1_0", "\u0663", "--1"])
def test_non_numeric_number_reports_the_token(tok):
    assert_error(HEAD + f"s 0 0\n0 {tok}\n", 8, "expected a number", repr(tok))


@pytest.mark.parametrize("tok", ["nan", "inf", "-Infinity", "1e999"])
def test_non_finite_number(tok):
    assert_error(HEAD + f"s 0 0\n0\n{tok}\n", 9, "non-finite", repr(tok))


def test_a_huge_token_is_quoted_short_with_its_length():
    # A 10 MB number (or word) in a scene file was echoed whole in the error.
    for tok in ("7" * 1_000_000, "x" * 1_000_000):
        e = error_of(HEAD + f"s 0 0\n0 {tok}\n")
        assert e.line == 8 and len(str(e)) < 200
        assert "(1,000,00" in str(e) and tok[:40] in str(e)  # its length, quotes and all


def test_next_entity_where_a_number_belongs():
    assert_error(HEAD + "s 0 0 0\ns 0 0 0 1\n", 8, "expected a number", "'s'")


def test_missing_numbers_at_end_of_file_reported_at_the_entity():
    assert_error(HEAD + "s 0 0 0 1\np 4\n0 0 0\n1 0 0\n", 8, "'p' needs 12 numbers", "after 6")
    assert_error(HEAD + "\nc 0 0 0 1\n0 0", 8, "'c' needs 8 numbers")
    assert_error(HEAD + "p", 7, "'p' needs a vertex count")
    assert_error("v from 0 0 5 at 0 0 0 up 0 1 0 angle", 1, "'angle' needs 1 number but")


@pytest.mark.parametrize("count", ["3.0", "x", "2", "0", "-4"])
def test_bad_vertex_count(count):
    assert_error(HEAD + f"s 0 0 0 1\np\n{count} 0 0 0 1 0 0 0 1 0\n", 9, "vert")
    assert_error(HEAD + f"pp {count} 0 0 0 0 0 1\n", 7, "vert")


def test_object_before_view():
    assert_error("f 1 1 1 1 0 0 0 0\n\ns 0 0 0 1\n", 3, "object before view")


def test_object_before_material():
    assert_error(
        "v from 0 0 5 at 0 0 0 up 0 1 0 angle 45\nl 0 0 9\np 3 0 0 0 1 0 0 0 1 0", 3, "no material"
    )


def test_light_after_object():
    assert_error(HEAD + "l 0 0 9\ns 0 0 0 1\nl 0 0 10\n", 9, "lights must precede objects")


def test_second_view_after_objects():
    assert_error(HEAD + "s 0 0 0 1\nv from 0 0 5 at 0 0 0 up 0 1 0 angle 45\n", 8, "view")


def test_missing_view_reports_last_line():
    assert_error("b 0 0 0\nl 0 0 1\n\n# end\n", 4, "missing view")
    assert_error("b 0 0 0\nl 0 0 1\n\n# end", 4, "missing view")
    assert_error("", 1, "missing view")


def test_view_missing_required_keyword_reported_at_v():
    assert_error(
        "b 0 0 0\nv\nfrom 0 0 5\nup 0 1 0\nangle 45\nf 1 1 1 1 0 0 0 0\n", 2, "view lacks at"
    )
    assert_error("v from 0 0 5 at 0 0 0 up 0 1 0\nangle 45 angle 40\n", 2, "duplicate 'angle'")


@pytest.mark.parametrize("angle", ["0", "180", "-10", "200"])
def test_bad_view_angle(angle):
    assert_error(f"v from 0 0 5 at 0 0 0 up 0 1 0\nangle\n{angle}\n", 3, "angle")


@pytest.mark.parametrize("res", ["0 512", "512 -1", "512 2.5", "x 512"])
def test_bad_resolution(res):
    assert_error(f"v from 0 0 5 at 0 0 0 up 0 1 0 angle 45\nresolution {res}\n", 2, "resolution")


def test_degenerate_triangles():
    assert_error(HEAD + "s 0 0 0 1\np 3\n0 0 0\n1 1 1\n2 2 2\n", 8, "degenerate polygon")
    assert_error(HEAD + "p 3 1 1 1 1 1 1 1 1 1\n", 7, "degenerate polygon")


def test_degenerate_polygon_all_collinear_and_tiny_area():
    assert_error(HEAD + "p 4 0 0 0 1 0 0 2 0 0 3 0 0\n", 7, "degenerate polygon")
    # Area about 1e-13 of the longest edge squared: numerically a line.
    assert_error(HEAD + "\np 4 0 0 0 1 0 0 2 1e-13 0 3 0 0\n", 8, "degenerate polygon")


def test_small_but_sound_polygon_accepted():
    s = scene("p 3 0 0 0 1e-9 0 0 0 1e-9 0\n")
    np.testing.assert_array_equal(s.triangles["n"][0], [[0, 0, 1]] * 3)


def test_non_planar_polygon_reported_at_the_vertex_off_the_plane():
    assert_error(HEAD + "p 5\n0 0 0\n1 0 0\n1 1 0\n0.5 1.5 0.1\n0 1 0\n", 11, "off the plane")
    # 1e-3 of the size off the plane is too much; 1e-8 is rounding and is accepted.
    assert_error(HEAD + "p 5 0 0 0 1 0 0 1 1 0 0.5 1.5 0.002 0 1 0\n", 7, "vertex 4")
    assert len(scene("p 5 0 0 0 1 0 0 1 1 0 0.5 1.5 1e-8 0 1 0\n").polygons) == 1


def test_zero_patch_normal_reported_at_its_vertex():
    assert_error(HEAD + "pp 3\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 0\n", 10, "normal")


def test_zero_sphere_radius():
    assert_error(HEAD + "s 0 0 0\n0\n", 8, "radius")
    assert_error(HEAD + "s 0 0 0 -0\n", 7, "radius")


def test_degenerate_cones():
    assert_error(HEAD + "c\n1 2 3 1\n1 2 3 0.5\n", 7, "base and apex")
    assert_error(HEAD + "s 0 0 0 1\nc\n0 0 0 0\n0 0 1 -0\n", 8, "both radii 0")


@pytest.mark.parametrize(
    ("fields", "bad_line", "word"),
    [
        ("-0.1 1 1\n1 0 0\n0 1", 1, "red"),
        ("1 1 -1\n1 0 0\n0 1", 1, "blue"),
        ("1 1 1\n-1 0 0\n0 1", 2, "Kd"),
        ("1 1 1\n1 -0.5 0\n0 1", 2, "Ks"),
        ("1 1 1\n1 0 0\n-0.5 1", 3, "T"),
        ("1 1 1\n1 0 0\n0 -1", 3, "ior"),
        ("1 1 1\n1 0 0\n0.5 0", 3, "ior"),
    ],
)
def test_bad_material(fields, bad_line, word):
    # The material starts on line 2; its numbers run over three lines.
    text = "v from 0 0 5 at 0 0 0 up 0 1 0 angle 45\nf " + fields + "\n"
    assert_error(text, 1 + bad_line, "material", word)


def test_first_error_in_file_order_wins_over_later_syntax_error():
    # The degenerate polygon is only found by the bulk geometry check after the token pass.
    assert_error(HEAD + "p 3 0 0 0 1 0 0 2 0 0\ns 0 0 0 1\nbogus\n", 7, "degenerate polygon")
    assert_error(HEAD + "bogus\np 3 0 0 0 1 0 0 2 0 0\n", 7, "unknown entity")


# --- SPD scenes -------------------------------------------------------------------------------

# file: spheres, triangles, polygons, cones, lights (README.md in the scenes folder).
SPD_COUNTS = {
    "balls.nff": (7381, 0, 1, 0, 3),
    "balls_s1.nff": (10, 0, 1, 0, 3),
    "balls_s2.nff": (91, 0, 1, 0, 3),
    "balls_s3.nff": (820, 0, 1, 0, 3),
    "tetra.nff": (0, 4096, 0, 0, 1),
    "tetra_s1.nff": (0, 4, 0, 0, 1),
    "tetra_s2.nff": (0, 16, 0, 0, 1),
    "tetra_s3.nff": (0, 64, 0, 0, 1),
    "tetra_s4.nff": (0, 256, 0, 0, 1),
    "tetra_s5.nff": (0, 1024, 0, 0, 1),
    "shells.nff": (5761, 0, 0, 0, 1),
    "gears_s1.nff": (0, 0, 147, 0, 5),
    "mount_s1.nff": (4, 8, 0, 0, 1),
    "rings_s1.nff": (30, 0, 1, 30, 3),
    "teapot_s1.nff": (0, 56, 1, 0, 2),
    "tree_s1.nff": (3, 0, 1, 3, 7),
    "jacks.nff": (6, 0, 0, 3, 1),
}


@pytest.mark.parametrize("name", sorted(SPD_COUNTS))
def test_spd_scene_counts(name):
    s = read_nff(spd_scene(name))
    n_sph, n_tri, n_poly, n_cone, _ = SPD_COUNTS[name]
    got = (len(s.spheres), len(s.triangles), len(s.polygons), len(s.cones), len(s.lights))
    assert got == SPD_COUNTS[name]
    assert s.n_objects == n_sph + n_tri + n_poly + n_cone  # every SPD patch is a `pp 3`
    gids = np.sort(
        np.concatenate([s.spheres["gid"], s.triangles["gid"], s.polygons["gid"], s.cones["gid"]])
    )
    np.testing.assert_array_equal(gids, np.arange(s.n_objects))


def test_spd_balls_view_and_floor_exact():
    s = read_nff(spd_scene("balls.nff"))
    assert s.view == View(
        eye=(2.1, 1.3, 1.7), at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), angle=45.0, hither=0.01
    )
    assert s.background == (0.078, 0.361, 0.753)
    np.testing.assert_array_equal(s.lights["pos"], [[4, 3, 2], [1, -4, 4], [-3, 1, 5]])
    assert s.polygons[0]["count"] == 4 and s.polygons[0]["gid"] == 0
    np.testing.assert_array_equal(
        s.vertices, [[12, 12, -0.5], [-12, 12, -0.5], [-12, -12, -0.5], [12, -12, -0.5]]
    )
    assert s.spheres[0]["gid"] == 1 and s.spheres[0]["mat"] == 1
    assert list(s.spheres[0]["center"]) == [0, 0, 0] and s.spheres[0]["radius"] == 0.5


def test_spd_gears_many_vertex_faces():
    s = read_nff(spd_scene("gears_s1.nff"))
    counts = s.polygons["count"]
    assert np.count_nonzero(counts == 144) == 2 and np.count_nonzero(counts == 4) == 145
    assert len(s.vertices) == counts.sum()
    np.testing.assert_array_equal(s.polygons["start"], np.cumsum(counts) - counts)


def test_spd_teapot_patches_smooth_and_rings_cones():
    t = read_nff(spd_scene("teapot_s1.nff")).triangles
    assert t["smooth"].all() and len(np.unique(t["gid"])) == 56
    np.testing.assert_allclose(np.linalg.norm(t["n"], axis=2), 1.0, rtol=1e-12)
    r = read_nff(spd_scene("rings_s1.nff"))
    c = r.cones[0]
    assert list(c["base"]) == [0.930995, 2.61313, 0] and c["apex_r"] == 0.07412


# --- size -------------------------------------------------------------------------------------


def test_generated_100k_scene():
    n = 50_000
    k = np.arange(n)
    parts = [HEAD]
    parts += [f"s {i} 0.5 {-i} 0.25\np 3\n{i} 0 0\n{i + 1} 0 0\n{i} 1 0\n" for i in k.tolist()]
    s = parse_nff("".join(parts), "big.nff")
    assert (len(s.spheres), len(s.triangles), s.n_objects) == (n, n, 2 * n)
    np.testing.assert_array_equal(s.spheres["gid"], 2 * k)
    np.testing.assert_array_equal(s.triangles["gid"], 2 * k + 1)
    np.testing.assert_array_equal(s.spheres["center"][:, 0], k)
    np.testing.assert_array_equal(s.triangles["v"][:, 1, 0], k + 1)
    np.testing.assert_array_equal(s.triangles["n"][:, 2], np.tile([0.0, 0, 1], (n, 1)))


@pytest.mark.parametrize(
    "view,what",
    [
        ("from 1 2 3\nat 1 2 3\nup 0 1 0", "coincide"),
        ("from 0 0 -5\nat 0 0 0\nup 0 0 1", "along the line of sight"),
        ("from 0 0 -5\nat 0 0 0\nup 0 0 0", "zero or along"),
    ],
)
def test_a_degenerate_view_is_refused_with_its_line(view, what):
    text = f"b 0 0 0\nv\n{view}\nangle 45\nhither 1\nresolution 8 8\n"
    with pytest.raises(SceneError, match=rf"scene.nff:2: view: .*{what}"):
        parse_nff(text, "scene.nff")


@pytest.mark.parametrize(
    "k,where,what",
    [(1e-300, ":1:", "coincide (or are closer than 1e-100"), (1e300, ":2:", "beyond +-1e+100")],
)
def test_a_scene_scaled_past_float64_is_refused_naming_the_line(k, where, what):
    # Scaled by 1e-300 the eye and target cannot be told apart; by 1e300 squares overflow.
    text = (
        f"v\nfrom {2 * k:g} {k:g} {k:g}\nat 0 0 0\nup 0 0 1\nangle 40\nhither 0\n"
        f"f 1 0 0 1 0 1 0 0\ns 0 0 0 {k:g}\n"
    )
    with pytest.raises(SceneError, match=where) as e:
        parse_nff(text, "scaled.nff")
    assert what in str(e.value)


def test_an_ior_past_the_tracers_range_is_refused():
    with pytest.raises(SceneError, match=r"t\.nff:1: 1e308 is beyond"):
        parse_nff("f 1 1 1 0 0 1 0.5 1e308\n", "t.nff")
