"""PLY polygon meshes (ASCII or binary), read with plyfile: `vertex` x y z [nx ny nz] and
`face` vertex_indices (or vertex_index) lists of any length, kept whole.

plyfile is the PLY reader of record: pure Python over NumPy, kept up, and it keeps faces of any
size as lists (trimesh would split quads into triangles). Its errors name the header line, or
the element and row; rows of an ASCII file are lines, so errors name the file's line there
(binary files: the line that declares the element, and the row).
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import plyfile

from host.scene.errors import SceneError
from host.scene.meshfaces import MeshFaces

_FACE_LISTS = ("vertex_indices", "vertex_index")


def read_ply(path) -> MeshFaces:
    """Read a PLY file; errors are `file:line: what`."""
    source = str(path)
    with open(path, "rb") as f:
        head = f.read(65536)
        f.seek(0)
        header = _Header(head)
        try:
            ply = _read(f, header)
        except plyfile.PlyHeaderParseError as e:
            raise SceneError(source, int(e.line or 1), f"PLY header: {e.message}") from None
        except plyfile.PlyElementParseError as e:
            name = e.element.name if e.element is not None else "?"
            line = header.row_line(name, e.row, ascii_=header.ascii)
            prop = f" property {e.prop.name!r}:" if e.prop is not None else ""
            row = "" if header.ascii or e.row is None else f" row {e.row}:"
            raise SceneError(source, line, f"{name}{row}{prop} {e.message}") from None
        except (ValueError, EOFError, OverflowError) as e:
            # OverflowError: plyfile casts an ASCII list's count into its type as is (-9 as
            # a uchar count)
            raise SceneError(source, header.end, f"PLY data: {e}") from None
    names = [el.name for el in ply.elements]
    for need in ("vertex", "face"):
        if need not in names:
            raise SceneError(source, header.end, f"PLY file has no {need!r} element")
    vert, face = ply["vertex"], ply["face"]
    props = {p.name for p in vert.properties}
    missing = [c for c in "xyz" if c not in props]
    if missing:
        raise SceneError(source, header.decl("vertex"), f"vertex lacks {', '.join(missing)}")
    points = np.stack([np.array(vert[c], float) for c in "xyz"], axis=1)
    normals = None
    if {"nx", "ny", "nz"} <= props:
        normals = np.stack([np.array(vert[c], float) for c in ("nx", "ny", "nz")], axis=1)
    key = next((k for k in _FACE_LISTS if k in {p.name for p in face.properties}), None)
    if key is None:
        raise SceneError(source, header.decl("face"), "face has no vertex_indices list")
    lists = face[key]
    if lists.dtype != object:  # read as fixed-length lists: one (faces, k) array
        counts = np.full(len(lists), lists.shape[1], np.int64)
        corner_v = lists.astype(np.int64).reshape(-1)
    else:
        counts = np.fromiter(map(len, lists), np.int64, len(lists))
        corner_v = np.concatenate(lists).astype(np.int64) if len(lists) else np.zeros(0, np.int64)
    rows = np.arange(len(counts))
    lines = (
        header.row_line("face", 0, True) + rows
        if header.ascii
        else np.full(len(counts), header.decl("face"))
    )
    for bad, what in (
        (counts < 3, "a face needs at least 3 corners"),
        (~np.isfinite(points).all(1), "non-finite vertex"),
    ):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            element = "face" if what.startswith("a face") else "vertex"
            raise SceneError(
                source, header.row_line(element, i, header.ascii), f"{element} {i}: {what}"
            )
    out = np.flatnonzero((corner_v < 0) | (corner_v >= len(points)))
    if len(out):
        f = int(np.searchsorted(np.cumsum(counts), out[0], side="right"))
        raise SceneError(
            source,
            int(lines[f]),
            f"face {f}: vertex index {corner_v[out[0]]} "
            f"out of range (the file has {len(points)} vertices)",
        )
    corner_n = corner_v if normals is not None else None
    return MeshFaces(points, normals, corner_v, corner_n, counts, lines)


class _Header:
    """Where the header's lines are: the element declarations and the first data line."""

    def __init__(self, head: bytes):
        end = head.find(b"end_header")
        text = head[: end if end >= 0 else len(head)].decode("latin-1")
        self.lines = text.split("\n")
        self.end = len(self.lines)  # the end_header line
        self.ascii = bool(re.search(r"^format\s+ascii", text, re.M))
        self.order: list[tuple[str, int, int]] = []  # name, count, declaration line
        for i, ln in enumerate(self.lines, 1):
            m = re.match(r"\s*element\s+(\S+)\s+(\d+)", ln)
            if m:
                self.order.append((m.group(1), int(m.group(2)), i))

    def decl(self, name: str) -> int:
        return next((line for n, _, line in self.order if n == name), 1)

    def row_line(self, name: str, row, ascii_: bool) -> int:
        """The file line of `row` of element `name` (ASCII: one row a line)."""
        if not ascii_ or row is None:
            return self.decl(name)
        before = 0
        for n, count, _ in self.order:
            if n == name:
                return self.end + before + int(row) + 1
            before += count
        return self.end


def _read(f, header: _Header) -> plyfile.PlyData:
    """The PLY data; numpy's warnings (an empty list in an ASCII row) are left out, as the
    checks after reading say what is wrong with the line."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return _read_lists(f, header)


def _read_lists(f, header: _Header) -> plyfile.PlyData:
    """plyfile reads a binary list property row by row (seconds for a large mesh) unless told
    its length, when it maps all rows at once and checks every length: so a binary file is
    tried as all triangles, then all quads, then read row by row."""
    for k in () if header.ascii else (3, 4):
        f.seek(0)
        try:
            return plyfile.PlyData.read(f, known_list_len={"face": dict.fromkeys(_FACE_LISTS, k)})
        except plyfile.PlyElementParseError as e:
            if e.message != "unexpected list length":
                raise
    f.seek(0)
    return plyfile.PlyData.read(f)
