"""An NFF scene as POV-Ray 3 scene text in the SPD library's own POV-Ray 3 output style, so
`bench.spd` can time POV-Ray on a scene that has no shipped pov/NAME.pov (jacks).

Bench-only: it reads the scene with the project's NFF reader and writes what the SPD
generators write for POV-Ray 3 (`-r 4`): the background; a camera of unit direction and right
and up vectors scaled to the field of view; every light at 1/sqrt(number of lights); one
declared texture per NFF `f` in file order; then every object in file order (spheres, open
cones, triangles, smooth triangles for patches, larger polygons cut as the SPD cuts them).
Numbers are printed with C's %g, as the SPD prints them.

What NFF does not carry is written as NFF means it: ambient 0 (the SPD gives balls' floor 0.2
and jacks 0.1) and a highlight of weight Ks (the SPD's generators pass their own weight, e.g.
rings 0.3 for Ks 0.2), present where Shine is not the SPD's 100000 of no highlight. Neither
changes POV-Ray's trace time; tests/test_pov_scene.py checks everything else against the
shipped files. Geometry is written in world coordinates (the SPD writes transformed objects
such as jacks' as object coordinates plus scale and rotate)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bench.pov_split import split_polygon
from host.scene.nff import read_nff
from protocols.scene import SceneData, View

HEADER = "// POV-Ray 3 scene file"
NO_HIGHLIGHT = 100000.0  # the SPD's Phong power for a highlight angle of 0: none
INDENT = "    "


def write_pov(nff: Path, folder: Path) -> Path:
    """`nff` converted to `folder`/NAME.pov (never beside the scene: the scene folder is
    read-only data); returns that path."""
    out = Path(folder) / f"{Path(nff).stem}.pov"
    out.write_text(pov_text(read_nff(nff), f"converted from {Path(nff).name} by bench.pov_scene"))
    return out


def pov_text(scene: SceneData, note: str = "") -> str:
    """The whole POV-Ray 3 file of `scene`; `note`, if given, is a comment under the header."""
    parts = [HEADER + "\n"]
    if note:
        parts.append(f"// {note}\n")
    parts.append(f"background {{ color {_rgb(scene.background)} }}\n\n")
    parts.append(camera(scene.view))
    scale = 1.0 / math.sqrt(max(len(scene.lights), 1))
    parts += [light(rec["pos"], rec["rgb"] * scale) for rec in scene.lights]
    declared = 0
    for mat, text in _objects(scene):
        while declared <= mat:  # each `f` declared where it stood: before its objects
            parts.append(texture(declared, scene.materials[declared]))
            declared += 1
        parts.append(text)
    parts += [texture(m, scene.materials[m]) for m in range(declared, len(scene.materials))]
    return "".join(parts)


def camera(view: View) -> str:
    """The camera block: unit direction; right (pointing left, as the SPD writes it for
    POV-Ray's left-handed frame) and up orthogonal, each as long as the frustum's width or
    height at distance 1 (aspect: the NFF resolution's width over height)."""
    eye = np.asarray(view.eye, float)
    sight = _unit(np.asarray(view.at, float) - eye)
    right = _unit(np.cross(_unit(np.asarray(view.up, float)), sight))
    up = _unit(np.cross(sight, right))
    height = 2.0 * math.tan(math.radians(view.angle) / 2.0)
    width = height * view.width / view.height
    return (
        "camera {\n"
        f"{INDENT}location {_vec(eye)}\n"
        f"{INDENT}direction {_vec(sight)}\n"
        f"{INDENT}right     {_vec(-right * width)}\n"
        f"{INDENT}up        {_vec(up * height)}\n"
        "} // camera\n\n"
    )


def light(pos, rgb) -> str:
    """One point light."""
    return f"light_source {{\n{INDENT}{_vec(pos)} color {_rgb(rgb)}\n}} // light\n\n"


def texture(index: int, mat) -> str:
    """The declared texture of material `index` (an NFF `f`): pigment (filter for a
    transmitter), then the finish terms the SPD writes only when non-zero."""
    name = texture_name(index)
    kd, ks, shine, kt, ior = (float(mat[k]) for k in ("kd", "ks", "shine", "t", "ior"))
    pigment = _rgb(mat["rgb"]) + (f" filter {kt:g}" if kt > 0 else "")
    finish = [f"ambient {0:g}", f"diffuse {kd:g}"]
    if ks != 0 and shine < NO_HIGHLIGHT:
        finish.append(f"phong {ks:g}  phong_size {shine:g}")
    if ks != 0:
        finish.append(f"reflection {ks:g}")
    if kt != 0:
        finish.append(f"refraction 1.0 ior {ior:g}")
    body = "".join(f"{INDENT * 2}{line}\n" for line in finish)
    return (
        f"#declare {name} = texture {{\n"
        f"{INDENT}pigment {{\n{INDENT * 2}color {pigment}\n{INDENT}}} // pigment\n"
        f"{INDENT}// normal {{ bumps, ripples, etc. }}\n"
        f"{INDENT}finish {{\n{body}{INDENT}}} // finish\n"
        f"}} // texture {name}\n\n"
    )


def texture_name(index: int) -> str:
    """The SPD's name of the texture of material `index` (counted from txt001)."""
    return f"txt{index + 1:03d}"


def _objects(scene: SceneData) -> list[tuple[int, str]]:
    """(material, text) of every object, in the NFF file's order (by gid)."""
    items = [(s["gid"], s["mat"], _sphere(s)) for s in scene.spheres]
    items += [(c["gid"], c["mat"], _cone(c)) for c in scene.cones]
    for t in scene.triangles:
        normals = t["n"] if t["smooth"] else None
        items.append((t["gid"], t["mat"], _triangle(t["v"], normals, t["mat"])))
    for p in scene.polygons:
        pts = scene.vertices[p["start"] : p["start"] + p["count"]]
        text = "".join(_triangle(pts[list(tri)], None, p["mat"]) for tri in split_polygon(pts))
        items.append((p["gid"], p["mat"], text))
    items.sort(key=lambda item: item[0])  # stable: a patch's fanned triangles keep their order
    return [(int(mat), text) for _, mat, text in items]


def _sphere(rec) -> str:
    """A sphere on one line."""
    return (
        f"sphere {{ {_vec(rec['center'])}, {rec['radius']:g}  "
        f"texture {{ {texture_name(rec['mat'])} }} }}\n\n"
    )


def _cone(rec) -> str:
    """An open cone or cylinder, apex first (its end caps are separate NFF objects)."""
    return (
        "cone {\n"
        f"{INDENT}{_vec(rec['apex'])}, {rec['apex_r']:g},\n"
        f"{INDENT}{_vec(rec['base'])}, {rec['base_r']:g} open\n"
        f"{INDENT}texture {{ {texture_name(rec['mat'])} }}\n"
        "}\n\n"
    )


def _triangle(v, n, mat) -> str:
    """A triangle, or a smooth one when vertex normals `n` are given."""
    rows = [_vec(v[i]) + ("" if n is None else " " + _vec(n[i])) for i in range(3)]
    kind = "triangle" if n is None else "smooth_triangle"
    corners = ",\n".join(f"{INDENT * 2}{row}" for row in rows)
    return (
        f"object {{\n{INDENT}{kind} {{\n{corners}\n{INDENT}}} // tri\n"
        f"{INDENT}texture {{ {texture_name(mat)} }}\n}} // object\n\n"
    )


def _vec(v) -> str:
    """<x, y, z> with C's %g."""
    return "<{:g}, {:g}, {:g}>".format(*(float(c) for c in v))


def _rgb(c) -> str:
    """'red r green g blue b' with C's %g."""
    return "red {:g} green {:g} blue {:g}".format(*(float(x) for x in c))


def _unit(v: np.ndarray) -> np.ndarray:
    """`v` scaled to length 1."""
    return v / np.linalg.norm(v)
