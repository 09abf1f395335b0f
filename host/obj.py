"""Wavefront OBJ polygon meshes: `v`, `vn` and `f` (`i`, `i/t`, `i//n`, `i/t/n`, negative
indices counting back), faces of any size kept whole.

Why not a library: trimesh and meshio read OBJ, but trimesh splits every quad and polygon into
triangles (a quad would no longer be NFF's `p 4`, nor give its image), logs and skips bad
records instead of naming them, and meshio drops the `vn` index of each corner (it keeps
normals only when there is one per vertex) and misreads negative indices. OBJ is one record a
line, so a line loop here is short; indices and normals are checked in bulk afterwards.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from host.meshfaces import MeshFaces
from host.scenefile import SceneError

# Statements that describe nothing the tracer draws: texture, grouping, materials by name,
# smoothing groups, lines and points.
_IGNORED = frozenset(("vt", "o", "g", "s", "usemtl", "mtllib", "l", "p", "mg", "vp"))
_FREEFORM = frozenset(("cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm",
                       "trim", "hole", "scrv", "sp", "end", "con", "ctech", "stech"))  # fmt: skip


def read_obj(path) -> MeshFaces:
    """Read an OBJ file; errors are `file:line: what`."""
    source = str(path)
    text = Path(path).read_text(encoding="latin-1")
    points: list[list[float]] = []
    normals: list[list[float]] = []
    corner_v: list[int] = []
    corner_n: list[int] = []
    counts: list[int] = []
    lines: list[int] = []
    pending = ""
    start = 0
    for number, raw in enumerate(text.split("\n"), 1):
        line = raw.split("#", 1)[0].rstrip()
        if line.endswith("\\"):  # continuation onto the next line
            pending, start = pending + line[:-1] + " ", start or number
            continue
        line, at = pending + line, start or number
        pending, start = "", 0
        parts = line.split()
        if not parts:
            continue
        key = parts[0]
        try:
            if key == "v":
                points.append(_xyz(parts, (3, 4, 6, 7)))
            elif key == "vn":
                normals.append(_xyz(parts, (3,)))
            elif key == "f":
                if len(parts) < 4:
                    raise ValueError(f"a face needs at least 3 corners, got {len(parts) - 1}")
                for corner in parts[1:]:
                    v, n = _corner(corner, len(points), len(normals))
                    corner_v.append(v)
                    corner_n.append(n)
                counts.append(len(parts) - 1)
                lines.append(at)
            elif key in _FREEFORM:
                raise ValueError(f"free-form geometry ({key!r}) is not supported: polygons only")
            elif key not in _IGNORED:
                raise ValueError(f"unknown statement {key!r}")
        except ValueError as e:
            raise SceneError(source, at, str(e)) from None
    faces = MeshFaces(np.array(points, float).reshape(-1, 3),
                      np.array(normals, float).reshape(-1, 3) if normals else None,
                      np.array(corner_v, np.int64), np.array(corner_n, np.int64),
                      np.array(counts, np.int64), np.array(lines, np.int64))  # fmt: skip
    _check_indices(source, faces)
    return faces


def _xyz(parts: list[str], arity) -> list[float]:
    """The first three numbers of a `v` (x y z [w] or x y z r g b) or `vn` record."""
    if len(parts) - 1 not in arity:
        raise ValueError(f"{parts[0]!r} needs {' or '.join(map(str, arity))} numbers, "
                         f"got {len(parts) - 1}")  # fmt: skip
    vals = []
    for tok in parts[1:4]:
        try:
            x = float(tok)
        except ValueError:
            raise ValueError(f"{parts[0]!r}: expected a number, got {tok!r}") from None
        if not np.isfinite(x):
            raise ValueError(f"{parts[0]!r}: non-finite number {tok!r}")
        vals.append(x)
    return vals


def _corner(tok: str, nv: int, nn: int) -> tuple[int, int]:
    """Vertex and normal index (0-based, -1: no normal) of a face corner `v[/t[/n]]`;
    negative indices count back from the last vertex (normal) read so far."""
    fields = tok.split("/")
    if len(fields) > 3 or not fields[0]:
        raise ValueError(f"bad face corner {tok!r} (v, v/t, v//n or v/t/n)")
    try:
        v = int(fields[0])
        n = int(fields[2]) if len(fields) == 3 and fields[2] else 0
        if len(fields) > 1 and fields[1]:
            int(fields[1])
    except ValueError:
        raise ValueError(f"bad face corner {tok!r}: indices are whole numbers") from None
    if v == 0 or (len(fields) == 3 and fields[2] and n == 0):
        raise ValueError(f"bad face corner {tok!r}: OBJ indices start at 1")
    v = v - 1 if v > 0 else nv + v
    n = -1 if n == 0 else (n - 1 if n > 0 else nn + n)
    if v < 0 or n < -1:
        raise ValueError(f"face corner {tok!r} counts back past the first vertex or normal")
    return v, n


def _check_indices(source: str, faces: MeshFaces) -> None:
    """Every corner names a vertex (and normal) that the file has."""
    face_of = np.repeat(np.arange(len(faces.counts)), faces.counts)
    nn = 0 if faces.normals is None else len(faces.normals)
    for idx, total, what in ((faces.corner_v, len(faces.points), "vertex"),
                             (faces.corner_n, nn, "normal")):  # fmt: skip
        bad = np.flatnonzero(idx >= total)
        if len(bad):
            line = int(faces.lines[face_of[bad[0]]])
            raise SceneError(source, line, f"face names {what} {idx[bad[0]] + 1} but the "
                             f"file has {total} {what}{'s' * (total != 1)}")  # fmt: skip
