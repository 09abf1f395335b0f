"""Write a `SceneData` as an NFF file that `read_nff` reads back as the same records.

Many tools and tests take a scene *path*; a generated scene becomes one here. Numbers are
written with 17 significant digits, so they read back bit for bit (a smooth
triangle's normal within an ulp: the reader normalises it again). Objects go out in gid order,
each `f` line before the first object of its material: when materials follow gid order (as
every NFF file's do) the materials table reads back unchanged, unused rows included; otherwise
an `f` line is repeated wherever the material changes (the same look, a longer table). Smooth
triangles sharing a gid (a fanned `pp` patch) go back out as that one patch.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from protocols.scene import SceneData


def _num(a) -> np.ndarray:
    """Numbers as exact decimal text ("%.17g"), element by element."""
    return np.char.mod("%.17g", np.asarray(a, float))


def _rows(*columns) -> np.ndarray:
    """One line per row from per-row text columns (each (n,) or (n, k)) joined by spaces."""
    text = np.concatenate([c[:, None] if c.ndim == 1 else c for c in columns], axis=1)
    out = text[:, 0]
    for k in range(1, text.shape[1]):
        out = np.char.add(np.char.add(out, " "), text[:, k])
    return out


def _header(scene: SceneData) -> list[str]:
    """Background, view and lights."""
    v = scene.view

    def nums(x):
        return " ".join(_num(np.atleast_1d(x)))

    lines = [
        f"b {nums(scene.background)}",
        "v",
        f"from {nums(v.eye)}",
        f"at {nums(v.at)}",
        f"up {nums(v.up)}",
        f"angle {nums(v.angle)}",
        f"hither {nums(v.hither)}",
        f"resolution {v.width} {v.height}",
    ]
    for pos, rgb in zip(scene.lights["pos"], scene.lights["rgb"], strict=True):
        colour = "" if np.all(rgb == 1.0) else f" {nums(rgb)}"
        lines.append(f"l {nums(pos)}{colour}")
    return lines


class _Lines:
    """Object lines keyed (gid, place in the object) for sorting, and each object's material."""

    def __init__(self):
        self.gid, self.sub, self.text, self.objects, self.mats = [], [], [], [], []

    def add(self, gid, sub, text) -> None:
        self.gid.append(np.asarray(gid)), self.sub.append(np.asarray(sub))
        self.text.append(np.asarray(text, str))

    def objects_of(self, rec) -> None:
        self.objects.append(rec["gid"]), self.mats.append(rec["mat"])

    def one_line(self, rec, word: str, *columns) -> None:
        """Objects of one line each: `word` and the numbers."""
        self.objects_of(rec)
        self.add(rec["gid"], np.zeros(len(rec), int), np.char.add(word, _rows(*columns)))

    def polygons(self, rec, vertices) -> None:
        """`p` blocks: a count line, then the polygon's vertices."""
        self.objects_of(rec)
        self.add(rec["gid"], np.zeros(len(rec), int), np.char.add("p ", rec["count"].astype(str)))
        at = np.repeat(rec["start"] - (np.cumsum(rec["count"]) - rec["count"]), rec["count"])
        at = at + np.arange(len(at))
        sub = at - np.repeat(rec["start"], rec["count"]) + 1
        self.add(np.repeat(rec["gid"], rec["count"]), sub, _rows(_num(vertices[at])))

    def patches(self, tri) -> None:
        """Smooth triangles back into their `pp` patches: a fan (v0, vi, vi+1) sharing a gid is
        the patch v0, v1, ..., vk (the triangle's first corner, its second, then every third)."""
        tri = tri[np.argsort(tri["gid"], kind="stable")]
        first = np.r_[True, tri["gid"][1:] != tri["gid"][:-1]]
        starts = np.flatnonzero(first)
        rank = np.arange(len(tri)) - np.repeat(starts, np.diff(np.r_[starts, len(tri)]))
        self.objects_of(tri[starts])
        sizes = np.diff(np.r_[starts, len(tri)]) + 2
        self.add(tri["gid"][starts], np.zeros(len(starts), int), [f"pp {k}" for k in sizes])
        lines = _rows(_num(tri["v"].reshape(-1, 3)), _num(tri["n"].reshape(-1, 3))).reshape(-1, 3)
        keep = (rank[:, None] == 0) | (np.arange(3) == 2)
        sub = np.where(rank[:, None] == 0, np.arange(1, 4), rank[:, None] + 3)
        gid = np.broadcast_to(tri["gid"][:, None], (len(tri), 3))
        self.add(gid[keep], sub[keep], lines[keep])


def _objects(scene: SceneData) -> _Lines:
    """Every object's lines."""
    out = _Lines()
    s, c, t = scene.spheres, scene.cones, scene.triangles
    if len(s):
        out.one_line(s, "s ", _num(s["center"]), _num(s["radius"]))
    if len(c):
        out.one_line(
            c, "c ", _num(c["base"]), _num(c["base_r"]), _num(c["apex"]), _num(c["apex_r"])
        )
    if len(scene.polygons):
        out.polygons(scene.polygons, scene.vertices)
    flat = t[t["smooth"] == 0]
    if len(flat):
        as_polygons = np.zeros(len(flat), scene.polygons.dtype)
        as_polygons["gid"], as_polygons["mat"], as_polygons["count"] = flat["gid"], flat["mat"], 3
        as_polygons["start"] = 3 * np.arange(len(flat))
        out.polygons(as_polygons, flat["v"].reshape(-1, 3))
    if np.any(t["smooth"] == 1):
        out.patches(t[t["smooth"] == 1])
    return out


def nff_text(scene: SceneData) -> str:
    """The scene as NFF text."""
    lines = _objects(scene)
    m = scene.materials
    rows = np.column_stack([m["rgb"], *(m[k] for k in ("kd", "ks", "shine", "t", "ior"))])
    f_lines = np.char.add("f ", _rows(_num(rows))) if len(rows) else np.zeros(0, str)
    gid = np.concatenate(lines.objects) if lines.objects else np.zeros(0, int)
    mat = np.concatenate(lines.mats)[np.argsort(gid)] if lines.objects else np.zeros(0, int)
    gid = np.sort(gid)
    if np.all(np.diff(mat) >= 0):
        # Material k goes out before the first object of a material >= k: the table reads back.
        used = np.arange(len(f_lines))
        at = np.r_[gid, gid[-1] + 1 if len(gid) else 0][np.searchsorted(mat, used)]
    else:  # a line wherever the material changes
        change = np.flatnonzero(np.r_[True, mat[1:] != mat[:-1]])
        used, at = mat[change], gid[change]
    lines.add(at, np.arange(len(used)) - len(used), f_lines[used])
    g, sub, text = (np.concatenate(x) for x in (lines.gid, lines.sub, lines.text))
    body = text[np.lexsort((sub, g))]
    return "\n".join([*_header(scene), *body]) + "\n"


def write_nff(scene: SceneData, path) -> Path:
    """Write `scene` as NFF to `path`; returns the path."""
    path = Path(path)
    path.write_text(nff_text(scene))
    return path
