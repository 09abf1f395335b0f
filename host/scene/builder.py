"""A `SceneData` assembled from objects added in file order (meshes and Inventor scenes).

gids follow the order objects are added, as NFF's follow the file, and faces become records
through `host.scene.polygons`, as NFF's do, so a face gives the same records whichever file it came
from. Faces are added in bulk (a whole mesh or face set at once) and checked vectorised:

- a flat face with no area is dropped (meshes often carry such slivers; they are never hit),
- a face whose vertices are not in one plane is cut into a fan of flat triangles,

and each kind of fix is reported once, as a note naming the first place it happened.
"""

from __future__ import annotations

import numpy as np

from host.scene import polygons
from host.scene.errors import SceneError
from protocols import dtypes
from protocols.scene import SceneData, View


class SceneBuilder:
    """Collects materials, lights and objects; `build` turns them into record arrays."""

    def __init__(self, source: str):
        self.source = source
        self.materials: list[tuple] = []  # NFF's 8 numbers each
        self.lights: list[tuple] = []  # position, rgb
        self.spheres: list[tuple] = []  # gid, mat, centre, radius
        self.cones: list[tuple] = []  # gid, mat, base, base_r, apex, apex_r
        self.flat: list[tuple] = []  # (pts, counts, gids, mat) per batch
        self.smooth: list[tuple] = []  # (pts, normals, counts, gids, mat) per batch
        self.notes: list[str] = []
        self._fixed = {"dropped": [0, None], "fanned": [0, None]}
        self.gid = 0
        self.lo = np.full(3, np.inf)
        self.hi = np.full(3, -np.inf)

    # -- entities -------------------------------------------------------------------------------

    def material(self, row: tuple) -> int:
        """Add NFF's `f r g b Kd Ks Shine T ior`; returns its index (equal rows share one)."""
        row = tuple(float(x) for x in row)
        if row in self.materials:
            return self.materials.index(row)
        self.materials.append(row)
        return len(self.materials) - 1

    def light(self, pos, rgb=(1.0, 1.0, 1.0)) -> None:
        self.lights.append((tuple(map(float, pos)), tuple(map(float, rgb))))

    def sphere(self, centre, radius: float, mat: int) -> None:
        c = np.asarray(centre, float)
        self._grow(c - abs(radius), c + abs(radius))
        self.spheres.append((self._next(1)[0], mat, tuple(c), float(radius)))

    def cone(self, base, base_r: float, apex, apex_r: float, mat: int) -> None:
        """An open cone or cylinder, as NFF's `c`."""
        r = max(abs(base_r), abs(apex_r))
        ends = np.array([base, apex], float)
        self._grow(ends.min(0) - r, ends.max(0) + r)
        self.cones.append(
            (self._next(1)[0], mat, tuple(ends[0]), float(base_r), tuple(ends[1]), float(apex_r))
        )

    def faces(self, pts, counts, mat: int, lines, normals=None) -> None:
        """Faces as consecutive corners `pts` (n, 3), `counts` corners each, `lines` (the file
        line of each face, for notes and errors). With `normals` (n, 3) per corner the faces
        are smooth patches (NFF `pp`), without they are flat polygons (NFF `p`)."""
        pts = np.ascontiguousarray(pts, float).reshape(-1, 3)
        counts = np.asarray(counts, np.int64)
        lines = np.asarray(lines, np.int64)
        if not len(counts):
            return
        self._grow(pts.min(0), pts.max(0))
        if normals is not None:
            normals = np.asarray(normals, float).reshape(-1, 3)
            zero = np.flatnonzero(np.linalg.norm(normals, axis=1) == 0)
            if len(zero):
                face = int(np.searchsorted(np.cumsum(counts), zero[0], side="right"))
                raise SceneError(self.source, int(lines[face]), "vertex normal has zero length")
            self.smooth.append((pts, normals, counts, self._next(len(counts)), mat))
            return
        geom = polygons.planes(pts, counts)
        if geom.flat.any() or geom.off.any():
            pts, counts, lines = self._fix(pts, counts, lines, geom)
            if not len(counts):
                return
        self.flat.append((pts, counts, self._next(len(counts)), mat))

    # -- output ---------------------------------------------------------------------------------

    def build(self, view: View, background=(0.0, 0.0, 0.0)) -> SceneData:
        """The scene, with its notes (fixes made) in `self.notes`."""
        for kind, (n, line) in self._fixed.items():
            if n:
                face = "face" if n == 1 else "faces"
                what = (
                    f"{face} with no area dropped"
                    if kind == "dropped"
                    else f"{face} not in one plane cut into flat triangles"
                )
                self.notes.append(f"{self.source}: {n} {what} (first at line {line})")
        light = np.zeros(len(self.lights), dtypes.LIGHT)
        for i, (pos, rgb) in enumerate(self.lights):
            light[i] = (pos, rgb)
        mats = np.array(self.materials, float).reshape(-1, 8)
        mat = np.zeros(len(mats), dtypes.MATERIAL)
        mat["rgb"] = mats[:, :3]
        for j, name in enumerate(("kd", "ks", "shine", "t", "ior"), start=3):
            mat[name] = mats[:, j]
        sph = np.array(self.spheres, dtypes.SPHERE)
        cone = np.array(self.cones, dtypes.CONE)

        tri, poly, vertices = polygons.flat_records(*self._flat())
        smooth = polygons.fan(*self._smooth())
        return SceneData(
            view=view,
            background=tuple(float(c) for c in background),
            lights=light,
            materials=mat,
            spheres=sph,
            triangles=polygons.by_gid(tri, smooth),
            polygons=poly,
            vertices=vertices,
            cones=cone,
            source=self.source,
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box of every object added (a unit box around the origin if none)."""
        if not np.all(np.isfinite(self.lo)):
            return -np.ones(3), np.ones(3)
        return self.lo.copy(), self.hi.copy()

    # -- helpers --------------------------------------------------------------------------------

    def _next(self, n: int) -> np.ndarray:
        gids = np.arange(self.gid, self.gid + n, dtype=np.int64)
        self.gid += n
        return gids

    def _grow(self, lo, hi) -> None:
        self.lo = np.minimum(self.lo, lo)
        self.hi = np.maximum(self.hi, hi)

    def _fix(self, pts, counts, lines, geom):
        """Drop faces with no area; cut faces off their plane into flat fans (in place, so
        gids keep file order); drop fan triangles with no area."""
        starts = np.cumsum(counts) - counts
        for kind, mask in (("dropped", geom.flat), ("fanned", geom.off)):
            if mask.any():
                self._fixed[kind][0] += int(mask.sum())
                first = int(lines[np.flatnonzero(mask)[0]])
                old = self._fixed[kind][1]
                self._fixed[kind][1] = first if old is None else min(old, first)
        keep = ~geom.flat & ~geom.off
        cut = np.flatnonzero(geom.off)
        per = counts[cut] - 2
        owner = np.repeat(cut, per)
        sub = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per) + 1
        tri = np.stack((starts[owner], starts[owner] + sub, starts[owner] + sub + 1), axis=1)
        # Pieces in file order: kept faces whole (sub 0), cut ones as their triangles (sub k).
        kept_corners = np.flatnonzero(np.repeat(keep, counts))
        kept_face = np.repeat(np.arange(len(counts)), counts)[kept_corners]
        corners = np.concatenate((kept_corners, tri.reshape(-1)))
        face = np.concatenate((kept_face, np.repeat(owner, 3)))
        piece = np.concatenate((np.zeros(len(kept_corners), np.int64), np.repeat(sub, 3)))
        at = np.concatenate((kept_corners, np.tile(np.arange(3), len(owner))))
        out = pts[corners[np.lexsort((at, piece, face))]]
        kept = np.flatnonzero(keep)
        p_face = np.concatenate((kept, owner))
        p_order = np.lexsort((np.concatenate((np.zeros(len(kept), np.int64), sub)), p_face))
        p_counts = np.concatenate((counts[kept], np.full(len(owner), 3)))[p_order]
        p_lines = lines[p_face[p_order]]
        if len(owner):
            again = polygons.planes(out, p_counts)
            if again.flat.any():
                self._fixed["dropped"][0] += int(again.flat.sum())
                out = out[np.repeat(~again.flat, p_counts)]
                p_counts, p_lines = p_counts[~again.flat], p_lines[~again.flat]
        return out, p_counts, p_lines

    def _flat(self):
        if not self.flat:
            return (
                np.zeros((0, 3)),
                np.zeros(0, np.int64),
                np.zeros((0, 2), np.int64),
                np.zeros((0, 3)),
            )
        pts = np.concatenate([b[0] for b in self.flat])
        counts = np.concatenate([b[1] for b in self.flat])
        ids = np.concatenate(
            [np.stack((b[2], np.full(len(b[2]), b[3])), axis=1) for b in self.flat]
        )
        return pts, counts, ids, polygons.planes(pts, counts).unit

    def _smooth(self):
        if not self.smooth:
            return np.zeros((0, 3)), np.zeros((0, 3)), [], np.zeros((0, 2), np.int64)
        pos = np.concatenate([b[0] for b in self.smooth])
        nrm = np.concatenate([b[1] for b in self.smooth])
        counts = np.concatenate([b[2] for b in self.smooth])
        ids = np.concatenate(
            [np.stack((b[3], np.full(len(b[3]), b[4])), axis=1) for b in self.smooth]
        )
        return pos, nrm, counts, ids
