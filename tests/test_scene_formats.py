"""Scene formats beyond NFF: OBJ and PLY meshes give the image of the NFF that lists the same
faces; Inventor transforms match hand-computed NFF geometry and its scenes render the same on a
mesh of nodes as on one; every bad input names its file and line."""

import math
import re

import numpy as np
import plyfile
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from host.cli import main
from host.planning.request import Request
from host.run.oneprocess import render
from host.scene.formats import SceneError, read_scene
from host.scene.inventor import CAP_SIDES, parse_inventor
from host.scene.nff import parse_nff
from host.scene.settings import Settings
from meshnode.engine.counters import RAY_COUNTS
from protocols.render import EngineSpec, ImageSpec
from tests.meshsim import render_mesh

SIZE = 48
COUNTS = RAY_COUNTS

# The settings every mesh below shares, in TOML and in NFF.
SETTINGS = """resolution = [48, 48]
background = [0.1, 0.2, 0.3]
[view]
from = [0.5, 1.5, 6]
at = [0.25, 0, 0]
up = [0, 1, 0]
angle = 50
[[light]]
position = [2, 5, 6]
[[light]]
position = [-4, 2, 3]
colour = [0.5, 0.75, 1]
[material]
colour = [1, 0.5, 0.25]
kd = 0.75
ks = 0.25
shine = 8
"""
NFF_HEAD = """v
from 0.5 1.5 6
at 0.25 0 0
up 0 1 0
angle 50
resolution 48 48
b 0.1 0.2 0.3
l 2 5 6
l -4 2 3 0.5 0.75 1
f 1 0.5 0.25 0.75 0.25 8 0 1
"""

# Two quads, a triangle and a pentagon, all planar and counter-clockwise towards the eye;
# coordinates are exact in binary so text and float32 give the same numbers.
POINTS = np.array(
    [
        [-2, -1, 0],
        [0, -1, 0],
        [0, 1, 0],
        [-2, 1, 0],
        [1.5, -1, -1],
        [1.5, 1, -1],
        [-1, -1.5, 1],
        [1, -1.5, 1],
        [0, -0.5, 1.5],
        [1, 1.25, 0.5],
        [2, 1.25, 0.5],
        [2.5, 2, 0.5],
        [1.5, 2.5, 0.5],
        [0.75, 2, 0.5],
    ]
)
FACES = [[0, 1, 2, 3], [1, 4, 5, 2], [6, 7, 8], [9, 10, 11, 12, 13]]


def nff_of(faces, normals=None) -> str:
    """The NFF of these faces (patches when vertex normals are given), written directly."""
    out = [NFF_HEAD]
    for face in faces:
        if normals is None:
            out.append(
                f"p {len(face)}\n" + "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in POINTS[face])
            )
        else:
            out.append(
                f"pp {len(face)}\n"
                + "".join(
                    f"{p[0]:g} {p[1]:g} {p[2]:g} {n[0]:g} {n[1]:g} {n[2]:g}\n"
                    for p, n in zip(POINTS[face], normals[face], strict=True)
                )
            )
    return "".join(out)


def obj_of(faces, normals=None) -> str:
    text = "# test mesh\no thing\n" + "".join(f"v {x:g} {y:g} {z:g}\n" for x, y, z in POINTS)
    if normals is not None:
        text += "".join(f"vn {x:g} {y:g} {z:g}\n" for x, y, z in normals)
    text += "g faces\ns off\nusemtl any\n"
    for face in faces:
        # Mixed corner spellings: absolute, relative (negative) and with texture slots.
        if normals is None:
            corners = [str(i + 1) if k % 2 else str(i - len(POINTS)) for k, i in enumerate(face)]
        else:
            corners = [f"{i + 1}//{i + 1}" for i in face]
        text += "f " + " ".join(corners) + "\n"
    return text


def write_ply(path, faces, normals=None, text=True) -> None:
    kind = [("x", "f8"), ("y", "f8"), ("z", "f8")]
    if normals is not None:
        kind += [("nx", "f8"), ("ny", "f8"), ("nz", "f8")]
    vert = np.zeros(len(POINTS), kind)
    vert["x"], vert["y"], vert["z"] = POINTS.T
    if normals is not None:
        vert["nx"], vert["ny"], vert["nz"] = normals.T
    face = np.empty(len(faces), [("vertex_indices", "O")])
    face["vertex_indices"] = [np.array(f, np.int32) for f in faces]
    plyfile.PlyData(
        [plyfile.PlyElement.describe(vert, "vertex"), plyfile.PlyElement.describe(face, "face")],
        text=text,
    ).write(str(path))


def smooth_normals():
    """Vertex normals leaning away from +z by different amounts, exact in binary."""
    n = np.zeros((len(POINTS), 3))
    n[:, 2] = 1.0
    n[:, 0] = POINTS[:, 0] / 4
    n[:, 1] = POINTS[:, 1] / 8
    return n


def single(scene):
    """Image and ray counts on one node (CSR storage: fewer kernel variants to compile)."""
    img, stats = render(
        Request(scene, ImageSpec(width=SIZE, height=SIZE), EngineSpec(threads=1, storage="csr"))
    )
    return img, {k: stats["rays"][k] for k in COUNTS}


def assert_same_records(a, b):
    for name in ("spheres", "triangles", "polygons", "cones", "lights", "materials"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    assert (a.view, a.background) == (b.view, b.background)


# --- OBJ and PLY against NFF ------------------------------------------------------------------


@pytest.mark.parametrize("smooth", [False, True], ids=["flat", "vertex-normals"])
def test_obj_and_ply_render_the_equivalent_nff_bit_for_bit(tmp_path, smooth):
    normals = smooth_normals() if smooth else None
    (tmp_path / "m.obj").write_text(obj_of(FACES, normals))
    write_ply(tmp_path / "a.ply", FACES, normals, text=True)
    write_ply(tmp_path / "b.ply", FACES, normals, text=False)
    for stem in ("m", "a", "b"):
        (tmp_path / f"{stem}.toml").write_text(SETTINGS)
    ref = parse_nff(nff_of(FACES, normals), "ref.nff")
    assert len(ref.polygons) == (0 if smooth else 3)  # quads and the pentagon stay polygons
    ref_img, ref_counts = single(ref)
    assert ref_counts["eye_hits"] > SIZE * SIZE // 4  # the faces fill a good part of the image
    for name in ("m.obj", "a.ply", "b.ply"):
        scene = read_scene(tmp_path / name)
        assert_same_records(scene, ref)
        img, counts = single(scene)
        assert counts == ref_counts, name
        np.testing.assert_array_equal(img, ref_img, err_msg=name)


def test_mesh_with_normals_on_some_faces_mixes_patches_and_polygons(tmp_path):
    normals = smooth_normals()
    text = obj_of(FACES, normals).replace(
        f"f {' '.join(f'{i + 1}//{i + 1}' for i in FACES[1])}",
        "f " + " ".join(str(i + 1) for i in FACES[1]),
    )
    (tmp_path / "m.obj").write_text(text)
    (tmp_path / "m.toml").write_text(SETTINGS)
    ref = parse_nff(
        nff_of(FACES[:1], normals)
        + nff_of(FACES[1:2])[len(NFF_HEAD) :]
        + nff_of(FACES[2:], normals)[len(NFF_HEAD) :],
        "ref.nff",
    )
    assert_same_records(read_scene(tmp_path / "m.obj"), ref)


def test_mesh_without_settings_frames_itself_and_says_so(tmp_path):
    (tmp_path / "m.obj").write_text(obj_of(FACES))
    notes = []
    scene = read_scene(tmp_path / "m.obj", note=notes.append)
    assert len(notes) == 1 and "no m.toml beside it" in notes[0] and "camera" in notes[0]
    assert len(scene.lights) == 1 and len(scene.materials) == 1
    eye, at = np.array(scene.view.eye), np.array(scene.view.at)
    sight = (at - eye) / np.linalg.norm(at - eye)
    rays = POINTS - eye
    off_axis = np.degrees(np.arccos(rays @ sight / np.linalg.norm(rays, axis=1)))
    assert off_axis.max() < scene.view.angle / 2  # every vertex is in the picture
    light = np.array(scene.lights["pos"][0])
    assert np.linalg.norm(light - eye) < np.linalg.norm(eye - POINTS.mean(0))  # near the eye


def test_degenerate_and_warped_faces_are_dropped_or_cut_with_a_note(tmp_path):
    # A sliver (three collinear corners) and a quad with one corner lifted off its plane.
    text = obj_of(FACES) + "v 3 0 0\nv 4 0 0\nv 5 0 0\nf 15 16 17\n"
    text += "v 0 3 0\nv 1 3 0\nv 1 4 1\nv 0 4 0\nf 18 19 20 21\n"
    (tmp_path / "m.obj").write_text(text)
    (tmp_path / "m.toml").write_text(SETTINGS)
    notes = []
    scene = read_scene(tmp_path / "m.obj", note=notes.append)
    assert any("1 face with no area dropped (first at line 27)" in n for n in notes), notes
    assert any("1 face not in one plane" in n and "line 32" in n for n in notes), notes
    warped = scene.triangles[scene.triangles["v"][:, :, 1].min(axis=1) >= 3]
    assert len(warped) == 2 and len(set(warped["gid"])) == 2  # two flat triangles
    np.testing.assert_array_equal(
        warped["v"].reshape(-1, 3)[[0, 1, 2, 3, 4, 5]],
        [[0, 3, 0], [1, 3, 0], [1, 4, 1], [0, 3, 0], [1, 4, 1], [0, 4, 0]],
    )


# --- Inventor ---------------------------------------------------------------------------------

HEAD = "#Inventor V2.1 ascii\n"
EVERY_NODE = (
    HEAD
    + """
DEF top Separator {
  PerspectiveCamera { position 0.5 1.5 9 orientation 1 0 0 -0.15 heightAngle 0.7
                      focalDistance 9 nearDistance 1 }
  PointLight { location 3 5 6 color 1 0.9 0.8 intensity 0.9 }
  DirectionalLight { direction -1 -2 -1 intensity 0.4 }
  DEF red Material { diffuseColor 0.9 0.2 0.2 specularColor 0.3 0.3 0.3 shininess 0.3 }
  Separator {
    Transform { translation -2 0 0 rotation 0 1 0 0.5 scaleFactor 1.2 1.2 1.2 }
    Sphere { radius 0.8 }
  }
  Separator {
    Rotation { rotation 1 0 0 0.3 }
    Material { diffuseColor 0.2 0.8 0.3 transparency 0.3 }
    Cone { bottomRadius 0.7 height 1.5 }
  }
  Separator {
    Translation { translation 2 0 0 }
    Scale { scaleFactor 0.5 0.8 0.5 }
    Cylinder { radius 1 height 2 parts (SIDES | TOP) }
  }
  Separator {
    Translation { translation 0 -1.5 0 }
    Cube { width 6 height 0.2 depth 4 }
  }
  Group {
    Translation { translation 0 1.6 -1 }
    Coordinate3 { point [ -0.5 0 0, 0.5 0 0, 0.5 0.8 0, -0.5 0.8 0, 0 1.2 0 ] }
    IndexedFaceSet { coordIndex [ 0, 1, 2, 3, -1, 3, 2, 4, -1 ] }
  }
  Info { string "every node kind" }
}
"""
)


def test_inventor_scene_with_every_node_renders_the_same_on_a_mesh():
    scene = parse_inventor(EVERY_NODE, "all.iv")
    assert (len(scene.spheres), len(scene.cones), len(scene.lights)) == (1, 2, 2)
    # Cube 6, cone bottom cap, cylinder top cap, face set quad; its triangle is a triangle.
    assert len(scene.polygons) == 9 and len(scene.triangles) == 1
    ref_img, ref_counts = single(scene)
    assert ref_counts["refracted_rays"] > 0 and ref_counts["shadow_rays_blocked"] > 0
    for rows, cols in ((1, 1), (2, 2)):
        img, totals, _, _ = render_mesh(scene, rows, cols, 1, SIZE, SIZE)
        assert {k: totals[k] for k in COUNTS} == ref_counts, (rows, cols)
        np.testing.assert_allclose(img, ref_img, rtol=0, atol=1e-5)


def inventor_angle(height_angle: float, n: int) -> float:
    """NFF's angle (between outermost pixel centres) of an edge-to-edge height angle."""
    half_edge = math.tan(height_angle / 2)
    return 2 * math.degrees(math.atan(half_edge * (n - 1) / n))


def ring(radius, x0, y0, z, facing_plus_z):
    """NFF `p 64` of a 64-gon circumscribing a circle in the plane z, counter-clockwise seen
    from +z (facing +z) or from -z, written out for the hand-made NFF."""
    a = 2 * math.pi * np.arange(CAP_SIDES) / CAP_SIDES
    r = radius / math.cos(math.pi / CAP_SIDES)
    turn = 1.0 if facing_plus_z else -1.0
    return f"p {CAP_SIDES}\n" + "".join(
        f"{x0 + r * math.cos(t)!r} {y0 + turn * r * math.sin(t)!r} {z!r}\n" for t in a
    )


def same_faces(got, want):
    """Every polygon of `want` is in `got`: matched by centroid, same material, same corners
    in the same cyclic order (so the same side faces out), to round-off."""

    def faces(scene):
        v, p = scene.vertices, scene.polygons
        return [(v[s : s + c], m) for s, c, m in zip(p["start"], p["count"], p["mat"], strict=True)]

    g, w = faces(got), faces(want)
    assert len(g) == len(w)
    centres = np.array([v.mean(0) for v, _ in g])
    for vw, mw in w:
        k = int(np.argmin(np.linalg.norm(centres - vw.mean(0), axis=1)))
        vg, mg = g[k]
        assert mg == mw and len(vg) == len(vw)
        start = int(np.argmin(np.linalg.norm(vw - vg[0], axis=1)))
        np.testing.assert_allclose(vg, np.roll(vw, -start, axis=0), atol=1e-12)


def test_inventor_transforms_match_hand_computed_nff():
    iv = (
        HEAD
        + """
PerspectiveCamera { position 0 0 12 heightAngle 0.6 }
PointLight { location 4 6 10 }
Material { diffuseColor 1 0.5 0.25 }
Separator {
  Translation { translation 1 0 0 }
  Scale { scaleFactor 2 2 2 }
  Material { diffuseColor 0 0 1 transparency 0.5 }
  Sphere { radius 0.5 }
}
Separator {
  Transform { translation -2 1 0 rotation 0 0 1 1.5707963267948966 scaleFactor 1 2 0.5 }
  Cube { }
}
Separator {
  Transform { translation 0 -2 0 rotation 1 0 0 1.5707963267948966 }
  Cylinder { radius 0.5 height 2 }
}
Separator {
  Transform { scaleFactor 3 1 1 scaleOrientation 0 0 1 0.7853981633974483 center 0 0 1 }
  Coordinate3 { point [ 0 0 1, 1 0 1, 0 1 1 ] }
  IndexedFaceSet { coordIndex [ 0, 1, 2 ] }
}
Sphere { radius 0.25 }
"""
    )
    # By hand: the sphere doubles about its centre and is blue glass (ior 1); the 2 x 2 x 2
    # cube scaled to 2 x 4 x 1, turned a quarter about z and moved is the box [-4, 0] x [0, 2]
    # x [-0.5, 0.5]; the cylinder turned a quarter about x runs along +z around (0, -2),
    # capped at z = -1 (facing -z) and z = 1; the triangle in the plane z = 1 is stretched 3
    # times along the diagonal (1, 1), so (1, 0) -> (2, 1) and (0, 1) -> (1, 2) (the centre
    # lies in its plane); the last sphere, outside every Separator, is at the origin and
    # orange again.
    nff = f"""v from 0 0 12 at 0 0 7 up 0 1 0 angle {inventor_angle(0.6, SIZE)!r}
resolution {SIZE} {SIZE}
l 4 6 10
f 0 0 1 1 0 25.6 0.5 1
s 1 0 0 1
f 1 0.5 0.25 1 0 25.6 0 1
p 4 -4 0 -0.5 -4 0 0.5 -4 2 0.5 -4 2 -0.5
p 4 0 0 -0.5 0 2 -0.5 0 2 0.5 0 0 0.5
p 4 -4 0 -0.5 0 0 -0.5 0 0 0.5 -4 0 0.5
p 4 -4 2 -0.5 -4 2 0.5 0 2 0.5 0 2 -0.5
p 4 -4 0 -0.5 -4 2 -0.5 0 2 -0.5 0 0 -0.5
p 4 -4 0 0.5 0 0 0.5 0 2 0.5 -4 2 0.5
c 0 -2 -1 0.5 0 -2 1 0.5
{ring(0.5, 0, -2, -1, facing_plus_z=False)}{ring(0.5, 0, -2, 1, facing_plus_z=True)}\
p 3 0 0 1 2 1 1 1 2 1
s 0 0 0 0.25
"""
    got = parse_inventor(iv, "t.iv", Settings(resolution=(SIZE, SIZE)))
    want = parse_nff(nff, "hand.nff")
    for name in ("spheres", "cones", "triangles"):
        for key in getattr(want, name).dtype.names:
            np.testing.assert_allclose(
                getattr(got, name)[key],
                getattr(want, name)[key],
                atol=1e-12,
                err_msg=f"{name}.{key}",
            )
    same_faces(got, want)
    np.testing.assert_array_equal(got.materials, want.materials)
    assert got.view.angle == pytest.approx(want.view.angle, abs=1e-12)
    np.testing.assert_allclose(
        [got.view.eye, got.view.at, got.view.up],
        [want.view.eye, want.view.at, want.view.up],
        atol=1e-12,
    )
    img, counts = single(got)
    ref_img, ref_counts = single(want)
    assert counts == ref_counts
    np.testing.assert_allclose(img, ref_img, rtol=0, atol=1e-6)


def test_separator_restores_state_and_mirrors_keep_faces_outward():
    iv = (
        HEAD
        + """Separator { Scale { scaleFactor -1 1 1 } Material { diffuseColor 0 1 0 }
Cube { width 2 height 4 depth 6 } }
Cube { }
"""
    )
    scene = parse_inventor(iv, "t.iv")
    v, p = scene.vertices, scene.polygons
    assert list(p["mat"]) == [0] * 6 + [1] * 6  # the second cube is out of the Separator
    for s, c in zip(p["start"], p["count"], strict=True):
        face = v[s : s + c]
        normal = np.cross(face[1] - face[0], face[2] - face[0])
        assert normal @ face.mean(0) > 0  # both cubes centred on the origin: out is away
    assert np.abs(v[:24]).max(0).tolist() == [1, 2, 3] and np.abs(v[24:]).max() == 1


def test_use_repeats_a_defined_node_and_lights_follow_the_matrix():
    iv = (
        HEAD
        + """DEF ball Sphere { radius 0.5 }
Translation { translation 3 0 0 }
USE ball
PointLight { location 0 1 0 color 1 0.5 0 intensity 0.5 }
DirectionalLight { on FALSE }
"""
    )
    notes = []
    scene = parse_inventor(iv, "t.iv", note=notes.append)
    assert scene.spheres["center"].tolist() == [[0, 0, 0], [3, 0, 0]]
    assert scene.lights["pos"].tolist() == [[3, 1, 0]]
    assert scene.lights["rgb"].tolist() == [[0.5, 0.25, 0]]
    assert notes == ["t.iv: no camera in the file: using a camera framing the scene"]


# --- errors name the file and line ------------------------------------------------------------


def file_error(path, text: str) -> tuple:
    """(path, message) of the SceneError that reading `text` written to `path` raises."""
    path.write_text(text)
    with pytest.raises(SceneError) as info:
        read_scene(path)
    return path, str(info.value)


def error_of(text: str, source: str = "t.iv") -> str:
    with pytest.raises(SceneError) as info:
        parse_inventor(text, source)
    return str(info.value)


@pytest.mark.parametrize(
    "body,line,words",
    [
        ("Separator {\n  Foo { }\n}\n", 3, "unknown node 'Foo'"),
        ("Sphere { radius 1\n", 3, "never closed"),
        ("Sphere { size 1 }\n", 2, "Sphere has no field 'size'"),
        ("Sphere { radius x }\n", 2, "expected a number, got 'x'"),
        ("Cube { Sphere { } }\n", 2, "Cube cannot have child nodes"),
        ("USE nothing\n", 2, "no node was DEF'd"),
        ("\nScale { scaleFactor 1 2 1 }\nSphere { }\n", 4, "ellipsoid"),
        ("Scale { scaleFactor 2 1 1 }\n\nCone { }\n", 4, "not a circle"),
        (
            "Coordinate3 { point [0 0 0, 1 0 0, 0 1 0] }\n"
            "IndexedFaceSet {\n coordIndex [0, 1, 3]\n}\n",
            4,
            "coordIndex 3 is out of range",
        ),
        ("IndexedFaceSet { coordIndex [0, 1, 2] }\n", 2, "no Coordinate3"),
        ("Material { diffuseColor [1 0 0, 0 1 0] }\n", 2, "one material per shape"),
        ("Cylinder { parts (SIDES | LID) }\n", 2, "parts ['LID'] unknown"),
        ("Rotation { rotation 0 0 0 1 }\n", 2, "zero axis"),
    ],
)
def test_inventor_errors_name_file_and_line(body, line, words):
    msg = error_of(HEAD + body)
    assert msg.startswith(f"t.iv:{line}: ") and words in msg, msg


def test_inventor_header_is_required():
    assert error_of("#VRML V1.0 ascii\nSphere { }\n").startswith("t.iv:1: not an Open Inventor")


@pytest.mark.parametrize(
    "text,line,words",
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", 4, "face names vertex 4 but the file has 3"),
        ("v 0 0 0\nv 1 0 x\n", 2, "expected a number, got 'x'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4, "at least 3 corners"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", 4, "counts back past the first"),
        (
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//2 3//1\n",
            5,
            "normal 2 but the file has 1",
        ),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\ncurv 0 1 1 2\n", 5, "free-form"),
        ("v 0 0 0\nbogus 1\n", 2, "unknown statement 'bogus'"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nf 1//1 2//1 3//1\n", 5, "zero length"),
    ],
)
def test_obj_errors_name_file_and_line(tmp_path, text, line, words):
    path, msg = file_error(tmp_path / "t.obj", text)
    assert msg.startswith(f"{path}:{line}: ") and words in msg, msg


PLY_HEAD = (
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
)


@pytest.mark.parametrize(
    "text,line,words",
    [
        (PLY_HEAD + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", 13, "vertex index 7 out of range"),
        (PLY_HEAD + "0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n", 11, "vertex"),
        (PLY_HEAD.replace("format ascii", "format asky"), 2, "PLY header"),
        (
            PLY_HEAD.replace("property float z\n", "") + "0 0\n1 0\n0 1\n3 0 1 2\n",
            3,
            "vertex lacks z",
        ),
        (PLY_HEAD + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n", 13, "at least 3 corners"),
        # a negative list count (plyfile's OverflowError): the data's first line
        (PLY_HEAD + "0 0 0\n1 0 0\n0 1 0\n-9 0 1 2\n", 9, "PLY data: Python integer -9"),
    ],
)
def test_ply_errors_name_file_and_line(tmp_path, text, line, words):
    path, msg = file_error(tmp_path / "t.ply", text)
    assert msg.startswith(f"{path}:{line}: ") and words in msg, msg


@pytest.mark.parametrize(
    "toml,line,words",
    [
        ("[view]\nfrom = [0, 0, 5]\nangle = 'wide'\n", 3, "angle must be a number"),
        ("[material]\nkd = 1\nglow = 2\n", 3, "unknown key 'glow'"),
        ("resolution = [64, 64]\n[[light]]\ncolour = [1, 1, 1]\n", 2, "needs a position"),
        ("[view\n", 1, "TOML"),
        ("[material]\nks = -1\n", 2, "negative ks"),
        ("[view]\nfrom = [0, 0, 0]\nat = [0, 0, 0]\n", 1, "coincide"),
    ],
)
def test_settings_errors_name_file_and_line(tmp_path, toml, line, words):
    (tmp_path / "t.toml").write_text(toml)
    _, msg = file_error(tmp_path / "t.obj", obj_of(FACES))
    assert msg.startswith(f"{tmp_path / 't.toml'}:{line}: ") and words in msg, msg


def test_inventor_settings_take_resolution_and_background_only(tmp_path):
    (tmp_path / "t.iv").write_text(HEAD + "Sphere { }\n")
    (tmp_path / "t.toml").write_text("resolution = [40, 30]\nbackground = [0, 0, 1]\n")
    scene = read_scene(tmp_path / "t.iv")
    assert (scene.view.width, scene.view.height, scene.background) == (40, 30, (0, 0, 1))
    (tmp_path / "t.toml").write_text("resolution = [40, 30]\n\n[view]\nangle = 30\n")
    with pytest.raises(SceneError, match=r"t\.toml:3: unknown key 'view'"):
        read_scene(tmp_path / "t.iv")


def test_cli_renders_every_format_and_refuses_bad_ones_in_one_line(tmp_path, capsys):
    (tmp_path / "m.obj").write_text(obj_of(FACES))
    (tmp_path / "s.toml").write_text(SETTINGS)
    (tmp_path / "all.iv").write_text(EVERY_NODE)
    for scene, extra in (("m.obj", ["--settings", str(tmp_path / "s.toml")]), ("all.iv", [])):
        out = tmp_path / f"{scene}.png"
        assert (
            main(
                [
                    "render",
                    str(tmp_path / scene),
                    "-o",
                    str(out),
                    "--width",
                    "16",
                    "--height",
                    "16",
                    "--mesh",
                    "1x1",
                    "--threads",
                    "1",
                    "--storage",
                    "csr",
                ]
                + extra
            )
            == 0
        )
        assert out.exists()
    err = capsys.readouterr().err
    assert "using" not in err  # both files give camera and light: nothing was defaulted
    (tmp_path / "bad.iv").write_text(HEAD + "Sphere { }\nFoo { }\n")
    (tmp_path / "x.dxf").write_text("0\n")
    for name, what in (("bad.iv", "bad.iv:3: unknown node 'Foo'"), ("x.dxf", "unknown scene")):
        assert main(["render", str(tmp_path / name), "-o", str(tmp_path / "o.png")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and what in err and "Traceback" not in err, err


def test_obj_corner_spellings_and_binary_triangle_ply_read_alike(tmp_path):
    tris = [[0, 1, 2], [0, 2, 3], [6, 7, 8]]
    plain = "".join(f"v {x:g} {y:g} {z:g}\n" for x, y, z in POINTS) + "vt 0 0\nvn 0 0 1\n"
    spelled = {"v": "{}", "vt": "{}/1", "vtn": "{}/1/1", "mixed": None}
    scenes = []
    for name, form in spelled.items():
        faces = ""
        for f in tris:
            forms = list(spelled.values())[:3] if form is None else [form] * 3
            faces += "f " + " ".join(fm.format(i + 1) for fm, i in zip(forms, f, strict=True))
            faces += "\n"
        (tmp_path / f"{name}.obj").write_text(plain + faces)
        (tmp_path / f"{name}.toml").write_text(SETTINGS)
        scenes.append(read_scene(tmp_path / f"{name}.obj"))
    # v, v/t and a mix are flat; v/t/n all smooth (every corner has the one normal).
    assert_same_records(scenes[0], scenes[1])
    assert_same_records(scenes[0], scenes[3])
    assert scenes[2].triangles["smooth"].all() and not scenes[0].triangles["smooth"].any()
    np.testing.assert_array_equal(scenes[2].triangles["v"], scenes[0].triangles["v"])
    write_ply(tmp_path / "t.ply", tris, text=False)  # all triangles: the memory-mapped path
    (tmp_path / "t.toml").write_text(SETTINGS)
    assert_same_records(read_scene(tmp_path / "t.ply"), scenes[0])


@pytest.mark.parametrize("name", ["primitives.iv", "pyramid.obj"])
def test_examples_read_without_defaults(name):
    from pathlib import Path

    notes = []
    scene = read_scene(Path(__file__).parents[1] / "host" / "examples" / name, note=notes.append)
    assert notes == [] and scene.n_objects > 0 and len(scene.lights) > 0


PIECES = [
    "{",
    "}",
    "[",
    "]",
    "(",
    ")",
    "|",
    ",",
    "-1",
    "0",
    "1e400",
    "nan",
    "DEF",
    "USE",
    "Sphere",
    "Separator",
    '"',
    "\n",
    "#",
    "TRUE",
    "99",
    "IndexedFaceSet",
    "f",
    "v",
    "vn",
    "1//",
    "/",
    "-9",
    "[view]",
    "=",
]


@settings(max_examples=150, deadline=None)
@given(
    edits=st.lists(
        st.tuples(st.floats(0, 1), st.booleans(), st.sampled_from(PIECES), st.integers(1, 8)),
        min_size=1,
        max_size=4,
    )
)
def test_mangled_inputs_fail_only_with_a_file_and_line(tmp_path_factory, edits):
    """Whatever is inserted or deleted, a reader either reads the file or names where it is
    wrong: no other exception, no empty message."""
    folder = tmp_path_factory.mktemp("mangled")
    files = {
        "m.iv": EVERY_NODE,
        "m.obj": obj_of(FACES),
        "m.toml": SETTINGS,
        "p.ply": PLY_HEAD + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    }
    for name, text in files.items():
        for where, delete, piece, n in edits:
            i = int(where * len(text))
            text = text[:i] + text[i + n :] if delete else f"{text[:i]} {piece} {text[i:]}"
        (folder / name).write_text(text)
    for name in ("m.iv", "m.obj", "p.ply"):
        try:
            read_scene(folder / name)
        except SceneError as e:
            assert e.what and re.match(rf"{re.escape(str(folder))}/\w+\.\w+:\d+: ", str(e))
