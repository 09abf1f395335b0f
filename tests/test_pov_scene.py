"""bench.pov_scene against the SPD's own POV-Ray 3 files: converting each shipped NFF gives its
shipped pov/NAME.pov, number for number within the printed precision (C's %g: six digits), so
the version it writes of a scene without one (jacks) can be trusted for POV-Ray's times.

NFF carries neither an ambient term nor a highlight weight apart from Ks, so those two are
checked against NFF's meaning (ambient 0, phong Ks where the SPD writes a highlight), not the
generators' own values. Polygons larger than triangles are cut from six-digit vertices: where
two vertices tie at that precision the cut may differ from the generator's (gears), so those
are checked as the same polygon (vertices, area), the rest triangle for triangle."""

import re

import numpy as np
import pytest

from bench.pov_scene import pov_text
from bench.pov_split import split_polygon
from bench.spd_povray import GENERATED, pov_version
from host.scene.nff import read_nff
from tests.conftest import SCENES, shared_file

SHIPPED = ("balls", "tetra", "shells", "rings", "tree", "teapot", "gears")
RTOL, ATOL = 2e-5, 1e-6  # six printed digits, derived from six-digit inputs

_NUM = r"[-+0-9.eE]+"
_VEC = rf"<\s*({_NUM})\s*,\s*({_NUM})\s*,\s*({_NUM})\s*>"
_RGB = rf"red\s+({_NUM})\s+green\s+({_NUM})\s+blue\s+({_NUM})"
_TEX = r"texture\s*\{\s*(\w+)\s*\}"
_OBJECT = re.compile(
    rf"sphere\s*\{{\s*{_VEC}\s*,\s*({_NUM})\s+{_TEX}\s*\}}"
    rf"|cone\s*\{{\s*{_VEC}\s*,\s*({_NUM})\s*,\s*{_VEC}\s*,\s*({_NUM})\s+open\s+{_TEX}\s*\}}"
    rf"|(smooth_triangle|triangle)\s*\{{([^}}]*)\}}\s*{_TEX}"
)
_TEXTURE = re.compile(
    r"#declare\s+(\w+)\s*=\s*texture\s*\{\s*pigment\s*\{([^}]*)\}\s*finish\s*\{([^}]*)\}\s*\}"
)


def parse_pov(text: str) -> dict:
    """The numbers of a POV-Ray 3 file in the SPD's style: background, camera vectors, lights,
    textures by name and objects in order as (kind, texture, numbers)."""
    text = re.sub(r"//[^\n]*", "", text)
    cam = re.search(r"camera\s*\{([^}]*)\}", text).group(1)
    return {
        "background": _floats(re.search(rf"background\s*\{{\s*color\s+{_RGB}", text).groups()),
        "camera": {
            key: _floats(re.search(rf"{key}\s+{_VEC}", cam).groups())
            for key in ("location", "direction", "right", "up")
        },
        "lights": [
            _floats(m.groups())
            for m in re.finditer(rf"light_source\s*\{{\s*{_VEC}\s*color\s+{_RGB}", text)
        ],
        "textures": {m[1]: _texture(m[2], m[3]) for m in _TEXTURE.finditer(text)},
        "objects": [_object(m) for m in _OBJECT.finditer(text)],
    }


def _texture(pigment: str, finish: str) -> dict:
    """A texture's terms by name (absent terms absent), colour and filter included."""
    words = (pigment + " " + finish).replace("color", "").split()
    terms = {}
    for i in range(0, len(words), 2):
        terms[words[i]] = float(words[i + 1])
    return terms


def _object(m: re.Match) -> tuple[str, str, np.ndarray]:
    """(kind, texture, numbers) of one object match of `_OBJECT`."""
    g = m.groups()
    if g[0] is not None:
        return "sphere", g[4], _floats(g[:4])
    if g[5] is not None:
        return "cone", g[13], _floats(g[5:13])
    return g[14], g[16], _floats(re.findall(_NUM, g[15]))


def _floats(values) -> np.ndarray:
    return np.array([float(v) for v in values])


def _groups(scene) -> list[int]:
    """How many POV objects each NFF primitive becomes, in file order; negative for a polygon
    of more than three vertices (its count - 2 triangles, cut by bench.pov_split)."""
    sizes = {}
    for table in (scene.spheres, scene.cones, scene.triangles):
        for gid in table["gid"]:
            sizes[int(gid)] = sizes.get(int(gid), 0) + 1
    for p in scene.polygons:
        sizes[int(p["gid"])] = -(int(p["count"]) - 2)
    return [sizes[g] for g in sorted(sizes)]


def _area(tris: np.ndarray) -> float:
    """Total area of triangles (n, 3, 3)."""
    return (
        np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum() / 2
    )


def _close(a, b) -> bool:
    return np.allclose(a, b, rtol=RTOL, atol=ATOL)


def _same_polygon(ours: list, theirs: list) -> bool:
    """Two cuts of one polygon: same texture, vertices and total area."""
    tris = [np.array([o[2] for o in objs]).reshape(-1, 3, 3) for objs in (ours, theirs)]
    areas = [_area(t) for t in tris]
    verts = [np.unique(np.round(t.reshape(-1, 3), 4), axis=0) for t in tris]
    return (
        {o[1] for o in ours} == {o[1] for o in theirs}
        and verts[0].shape == verts[1].shape
        and _close(verts[0], verts[1])
        and np.isclose(areas[0], areas[1], rtol=1e-4)
    )


@pytest.fixture(scope="module", params=SHIPPED)
def converted(request):
    """(scene, our file's numbers, the shipped file's numbers) of one shipped scene."""
    name = request.param
    shipped = shared_file(SCENES / "pov" / f"{name}.pov")
    scene = read_nff(shared_file(SCENES / f"{name}.nff"))
    return scene, parse_pov(pov_text(scene)), parse_pov(shipped.read_text())


def test_header_background_camera_and_lights_are_the_spds(converted):
    _, ours, theirs = converted
    assert _close(ours["background"], theirs["background"])
    for key, vec in theirs["camera"].items():
        assert _close(ours["camera"][key], vec), key
    assert len(ours["lights"]) == len(theirs["lights"])
    for a, b in zip(ours["lights"], theirs["lights"], strict=True):
        assert _close(a, b)  # position, and colour 1/sqrt(number of lights)


def test_textures_are_the_spds_but_what_nff_does_not_carry(converted):
    _, ours, theirs = converted
    assert list(ours["textures"]) == list(theirs["textures"])
    for name, want in theirs["textures"].items():
        got = ours["textures"][name]
        assert set(got) == set(want), name  # the same terms written, phong included
        for term in set(want) - {"ambient", "phong"}:
            assert _close(got[term], want[term]), (name, term)
        assert got["ambient"] == 0
        if "phong" in got:
            assert got["phong"] == got["reflection"]  # NFF's one Ks


def test_objects_are_the_spds_in_file_order(converted):
    scene, ours, theirs = converted
    assert len(ours["objects"]) == len(theirs["objects"])
    recut = exact = i = 0
    for size in _groups(scene):
        n = abs(size)
        mine, shipped = ours["objects"][i : i + n], theirs["objects"][i : i + n]
        i += n
        same = all(
            a[:2] == b[:2] and a[2].shape == b[2].shape and _close(a[2], b[2])
            for a, b in zip(mine, shipped, strict=True)
        )
        if same:
            exact += 1
        else:
            assert size < 0 and _same_polygon(mine, shipped), f"object {i - n}: {mine[0]}"
            recut += 1
    assert i == len(theirs["objects"])
    assert recut <= exact // 10, f"{recut} polygons cut otherwise, {exact} alike"


def test_a_concave_polygon_is_cut_into_triangles_that_tile_it():
    # an L: the ear at its first leftmost vertex holds the inner corner (1, 1), so a diagonal cut
    pts = np.array([[0, 0, 0], [4, 0, 0], [4, 1, 0], [1, 1, 0], [1, 3, 0], [0, 3, 0]], float)
    tris = split_polygon(pts)
    assert len(tris) == len(pts) - 2
    area = sum(abs(np.cross(pts[b] - pts[a], pts[c] - pts[a])[2]) / 2 for a, b, c in tris)
    assert area == pytest.approx(6.0)  # no triangle outside the L or overlapping another


def test_a_quad_is_cut_as_the_spd_cuts_balls_floor():
    pts = np.array([[12, 12, -0.5], [-12, 12, -0.5], [-12, -12, -0.5], [12, -12, -0.5]])
    assert split_polygon(pts) == [(0, 2, 3), (0, 1, 2)]


JACK = """b 0.2 0.05 0.2
v
from 0 0 -8
at 0 0 0
up 0 1 0
angle 25
hither 0.001
resolution 256 256
l -10 3 -20
f 0.737 0.561 0.561 0.7 0.7 11.1434 0 1
c -0.7 -0.1 -0.2 0.075 0.7 0.1 0.2 0.075
s 0.7 0.1 0.2 0.15
"""


def test_a_scene_without_a_shipped_pov_is_converted_outside_the_scene_folder(tmp_path):
    scenes, out = tmp_path / "scenes", tmp_path / "out"
    (scenes / "pov").mkdir(parents=True)
    out.mkdir()
    nff = scenes / "jack.nff"
    nff.write_text(JACK)
    path, source = pov_version(scenes, nff, out)
    assert (path.parent, source) == (out, GENERATED)
    assert not list(scenes.rglob("*.pov"))  # the scene folder is data: nothing written there
    got = parse_pov(path.read_text())
    assert [(o[0], o[1]) for o in got["objects"]] == [("cone", "txt001"), ("sphere", "txt001")]
    assert got["textures"]["txt001"] == {
        **{"red": 0.737, "green": 0.561, "blue": 0.561, "ambient": 0, "diffuse": 0.7},
        **{"phong": 0.7, "phong_size": 11.1434, "reflection": 0.7},
    }
    shipped = scenes / "pov" / "jack.pov"
    shipped.write_text(path.read_text())
    assert pov_version(scenes, nff, out) == (shipped, "shipped")
