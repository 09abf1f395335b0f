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

from host.scene.errors import SceneError
from host.scene.meshfaces import MeshFaces

# Statements that describe nothing the tracer draws: texture, grouping, materials by name,
# smoothing groups, lines and points.
_IGNORED = frozenset(("vt", "o", "g", "s", "usemtl", "mtllib", "l", "p", "mg", "vp"))
_FREEFORM = frozenset(
    (
        "cstype",
        "deg",
        "bmat",
        "step",
        "curv",
        "curv2",
        "surf",
        "parm",
        "trim",
        "hole",
        "scrv",
        "sp",
        "end",
        "con",
        "ctech",
        "stech",
    )
)


def read_obj(path) -> MeshFaces:
    """Read an OBJ file; errors are `file:line: what`.

    The line loop only sorts tokens by record; numbers and face corners are converted in bulk
    (a per-corner Python function would cost seconds on a mesh of 100,000 faces), and only
    when a conversion fails are the tokens walked again to name the line."""
    source = str(path)
    text = Path(path).read_text(encoding="latin-1")
    recs = {"v": ([], []), "vn": ([], [])}  # tokens (3 a record), line of each record
    ftok: list[str] = []
    counts: list[int] = []
    lines: list[int] = []
    seen_v: list[int] = []  # vertices and normals read before each face (negative indices)
    seen_n: list[int] = []
    pending, start = "", 0
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
        if key in recs:
            arity = (3, 4, 6, 7) if key == "v" else (3,)
            if len(parts) - 1 not in arity:
                raise SceneError(
                    source,
                    at,
                    f"{key!r} needs {' or '.join(map(str, arity))} numbers, got {len(parts) - 1}",
                )
            recs[key][0].extend(parts[1:4])
            recs[key][1].append(at)
        elif key == "f":
            if len(parts) < 4:
                raise SceneError(
                    source, at, f"a face needs at least 3 corners, got {len(parts) - 1}"
                )
            ftok.extend(parts[1:])
            counts.append(len(parts) - 1)
            lines.append(at)
            seen_v.append(len(recs["v"][1]))
            seen_n.append(len(recs["vn"][1]))
        elif key in _FREEFORM:
            raise SceneError(
                source, at, f"free-form geometry ({key!r}) is not supported: polygons only"
            )
        elif key not in _IGNORED:
            raise SceneError(source, at, f"unknown statement {key!r}")
    points, normals = (_numbers(source, key, *recs[key]) for key in ("v", "vn"))
    counts_a, lines_a = np.array(counts, np.int64), np.array(lines, np.int64)
    corner_v, corner_n = _corners(
        source, ftok, counts_a, lines_a, np.array(seen_v, np.int64), np.array(seen_n, np.int64)
    )
    faces = MeshFaces(
        points, normals if len(normals) else None, corner_v, corner_n, counts_a, lines_a
    )
    _check_indices(source, faces)
    return faces


def _numbers(source: str, key: str, toks: list[str], lines: list[int]) -> np.ndarray:
    """(n, 3) floats of `v` or `vn` records, checked finite; errors name the record's line."""
    try:
        vals = np.array(toks, float).reshape(-1, 3)
    except ValueError:
        for i, tok in enumerate(toks):
            try:
                float(tok)
            except ValueError:
                raise SceneError(
                    source, lines[i // 3], f"{key!r}: expected a number, got {tok!r}"
                ) from None
        raise
    bad = np.flatnonzero(~np.isfinite(vals).all(axis=1))
    if len(bad):
        raise SceneError(source, lines[bad[0]], f"{key!r}: non-finite number")
    return vals


def _corners(source, toks, counts, lines, seen_v, seen_n):
    """Vertex and normal index (0-based; normal -1: none) of every face corner `v[/t[/n]]`;
    negative indices count back from the last vertex (normal) read before the face.

    Files spell every corner alike (`v`, `v/t`, `v//n` or `v/t/n`), so all corners are
    converted at once; anything else, or any bad corner, goes one corner at a time."""
    nums = None
    if toks:
        slashes = np.char.count(np.array(toks), "/")
        k = int(slashes[0])
        if k <= 2 and (slashes == k).all():
            joined = " ".join(toks)
            if k == 2:
                joined = joined.replace("//", "/0/")
            try:
                nums = np.array(joined.replace("/", " ").split(), np.int64).reshape(len(toks), -1)
            except ValueError:
                nums = None
    if (
        nums is None
        or nums.shape[1] != k + 1
        or (nums[:, 0] == 0).any()
        or (k == 2 and (nums[:, 2] == 0).any())
    ):
        return _corners_slowly(source, toks, counts, lines, seen_v, seen_n)
    face = np.repeat(np.arange(len(counts)), counts)
    v = np.where(nums[:, 0] > 0, nums[:, 0] - 1, seen_v[face] + nums[:, 0])
    n = np.full(len(v), -1, np.int64)
    if k == 2:
        n = np.where(nums[:, 2] > 0, nums[:, 2] - 1, seen_n[face] + nums[:, 2])
    if (v < 0).any() or (n < -1).any() or (k == 2 and (n < 0).any()):
        return _corners_slowly(source, toks, counts, lines, seen_v, seen_n)
    return v, n


def _corners_slowly(source, toks, counts, lines, seen_v, seen_n):
    """`_corners` one corner at a time: for mixed corner spellings, and to name the line of
    a bad corner."""
    v, n = np.empty(len(toks), np.int64), np.empty(len(toks), np.int64)
    i = 0
    for f, c in enumerate(counts):
        for _ in range(c):
            try:
                v[i], n[i] = _corner(toks[i], int(seen_v[f]), int(seen_n[f]))
            except ValueError as e:
                raise SceneError(source, int(lines[f]), str(e)) from None
            i += 1
    return v, n


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
    for idx, total, what in (
        (faces.corner_v, len(faces.points), "vertex"),
        (faces.corner_n, nn, "normal"),
    ):
        bad = np.flatnonzero(idx >= total)
        if len(bad):
            line = int(faces.lines[face_of[bad[0]]])
            raise SceneError(
                source,
                line,
                f"face names {what} {idx[bad[0]] + 1} but the "
                f"file has {total} {what}{'s' * (total != 1)}",
            )
