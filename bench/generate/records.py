"""A generated SPD scene's entities in NFF file order, turned into `SceneData` records the way
`host.scene.nff.read_nff` makes them (through `host.scene.polygons`), so a generated scene and the
SPD file of the same size are the same records.

Objects are added in bulk (arrays) with their gids, so a generator can interleave kinds (a cone,
then a sphere, ...) without a loop per object. `build(printed=True)` first rounds every number
to the six significant digits the SPD library prints (`printf("%g")`): that scene is the one
`read_nff` makes of the SPD's file, normals and all, not just close to it.
"""

from __future__ import annotations

import math

import numpy as np

from host.scene import polygons
from protocols import dtypes
from protocols.scene import SceneData, View

SPD_BACKGROUND = (0.078, 0.361, 0.753)  # "UNC sky blue", every SPD scene but jacks


def phong(angle: float) -> float:
    """The SPD library's highlight power for a highlight half-angle in degrees (its NFF
    `f` line prints this, not the angle): cos(angle)^power = 1/2."""
    rad = math.pi * angle / 180.0
    if rad <= 0.0:
        return 100000.0
    if rad >= math.pi / 2:
        return 1.0
    return math.log(0.5) / math.log(math.cos(rad))


def surface(rgb, kd: float, ks: float, angle: float, kt: float, ior: float) -> list[float]:
    """An NFF `f` row (r g b Kd Ks Shine T ior) from the arguments of the SPD's
    `lib_output_color` that NFF keeps (ambient and specular colour are dropped)."""
    return [*map(float, rgb), kd, ks, phong(angle), kt, ior]


def printed(x) -> np.ndarray:
    """`x` as the SPD library prints it (`%g`: six significant digits) and NFF reads it back."""
    a = np.asarray(x, float)
    return np.char.mod("%g", a).astype(float) if a.size else a.copy()


def rotation(axis: str, angle) -> np.ndarray:
    """(..., 3, 3) rotations about x, y or z by `angle` radians in the SPD library's row-vector
    convention (`p @ R`, R = lib_create_rotate_matrix), counter-clockwise seen from +axis."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.zeros((*np.shape(angle), 3, 3))
    r[..., 3 - i - j, 3 - i - j] = 1.0
    r[..., i, i] = r[..., j, j] = c
    r[..., i, j], r[..., j, i] = s, -s
    return r


def gather(counts: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Indices of the vertices of polygons `order` (each `counts` long, stored one after the
    other), in that order."""
    starts = np.cumsum(counts) - counts
    n = counts[order]
    first = np.repeat(starts[order] - (np.cumsum(n) - n), n)
    return first + np.arange(int(n.sum()))


class SpdScene:
    """Materials and objects added in file order; `build` makes the records."""

    def __init__(self, view: View, lights, background=SPD_BACKGROUND):
        self.view, self.background = view, background
        self.lights = np.asarray(lights, float).reshape(-1, 3)
        self.rows: list[np.ndarray] = []  # `f` rows, in file order
        self.n_materials = 0
        self.gid = 0
        self.kinds: dict[str, list[tuple]] = {k: [] for k in ("s", "c", "p", "pp")}

    def materials(self, rows) -> np.ndarray:
        """Append `f` rows (n, 8) in file order; their material indices."""
        rows = np.asarray(rows, float).reshape(-1, 8)
        self.rows.append(rows)
        self.n_materials += len(rows)
        return np.arange(self.n_materials - len(rows), self.n_materials)

    def material(self, *args) -> int:
        """Append one `f` row from `surface`'s arguments; its index."""
        return int(self.materials([surface(*args)])[0])

    def take(self, n: int) -> np.ndarray:
        """The next n gids (objects are numbered in file order)."""
        self.gid += n
        return np.arange(self.gid - n, self.gid)

    def spheres(self, centres, radii, mat, gids=None) -> None:
        radii = np.asarray(radii, float).reshape(-1)
        self._add("s", gids, mat, len(radii), np.asarray(centres, float).reshape(-1, 3), radii)

    def cones(self, base, base_r, apex, apex_r, mat, gids=None) -> None:
        base = np.asarray(base, float).reshape(-1, 3)
        n = len(base)
        r0, r1 = (np.broadcast_to(np.asarray(r, float), (n,)) for r in (base_r, apex_r))
        self._add("c", gids, mat, n, base, r0, np.asarray(apex, float).reshape(-1, 3), r1)

    def polygons(self, pts, counts, mat, gids=None) -> None:
        """Flat polygons (NFF `p`): consecutive vertices `pts`, `counts` each."""
        counts = np.asarray(counts, np.int64).reshape(-1)
        self._add("p", gids, mat, len(counts), np.asarray(pts, float).reshape(-1, 3), counts)

    def patches(self, pts, normals, counts, mat, gids=None) -> None:
        """Smooth polygons (NFF `pp`): vertices and their normals, `counts` each."""
        counts = np.asarray(counts, np.int64).reshape(-1)
        pts, nrm = (np.asarray(a, float).reshape(-1, 3) for a in (pts, normals))
        self._add("pp", gids, mat, len(counts), pts, nrm, counts)

    def _add(self, kind: str, gids, mat, n: int, *arrays) -> None:
        gids = self.take(n) if gids is None else np.asarray(gids, np.int64).reshape(-1)
        mats = np.broadcast_to(np.asarray(mat, np.int64), (n,))
        self.kinds[kind].append((gids, mats, *arrays))

    def _joined(self, kind: str) -> list[np.ndarray]:
        """The batches of one kind concatenated field by field (gid, mat, then its arrays)."""
        batches = self.kinds[kind]
        return [np.concatenate([b[k] for b in batches]) for k in range(len(batches[0]))]

    def build(self, source: str, printed_numbers: bool = False) -> SceneData:
        """The records; with `printed_numbers` every number first as the SPD file prints it."""
        rnd = printed if printed_numbers else (lambda a: np.asarray(a, float))
        v = self.view
        view = View(
            tuple(rnd(v.eye)),
            tuple(rnd(v.at)),
            tuple(rnd(v.up)),
            float(rnd(v.angle)),
            float(rnd(v.hither)),
            v.width,
            v.height,
        )
        light = np.zeros(len(self.lights), dtypes.LIGHT)
        light["pos"], light["rgb"] = rnd(self.lights), 1.0
        rows = rnd(np.concatenate(self.rows)) if self.rows else np.zeros((0, 8))
        mats = np.zeros(len(rows), dtypes.MATERIAL)
        mats["rgb"] = rows[:, :3]
        for j, name in enumerate(("kd", "ks", "shine", "t", "ior"), start=3):
            mats[name] = rows[:, j]
        scene = SceneData(
            view=view,
            background=tuple(float(c) for c in rnd(self.background)),
            lights=light,
            materials=mats,
            source=source,
        )
        scene.spheres, scene.cones = self._spheres(rnd), self._cones(rnd)
        flat, scene.polygons, scene.vertices = self._flat(rnd)
        scene.triangles = polygons.by_gid(flat, self._smooth(rnd))
        return scene

    def _spheres(self, rnd) -> np.ndarray:
        if not self.kinds["s"]:
            return np.zeros(0, dtypes.SPHERE)
        gid, mat, centre, radius = self._joined("s")
        order = np.argsort(gid, kind="stable")
        rec = np.zeros(len(gid), dtypes.SPHERE)
        rec["gid"], rec["mat"] = gid[order], mat[order]
        rec["center"], rec["radius"] = rnd(centre)[order], rnd(radius)[order]
        return rec

    def _cones(self, rnd) -> np.ndarray:
        if not self.kinds["c"]:
            return np.zeros(0, dtypes.CONE)
        gid, mat, base, base_r, apex, apex_r = self._joined("c")
        order = np.argsort(gid, kind="stable")
        rec = np.zeros(len(gid), dtypes.CONE)
        rec["gid"], rec["mat"] = gid[order], mat[order]
        rec["base"], rec["base_r"] = rnd(base)[order], rnd(base_r)[order]
        rec["apex"], rec["apex_r"] = rnd(apex)[order], rnd(apex_r)[order]
        return rec

    def _flat(self, rnd):
        if not self.kinds["p"]:
            return np.zeros(0, dtypes.TRIANGLE), np.zeros(0, dtypes.POLYGON), np.zeros((0, 3))
        gid, mat, pts, counts = self._joined("p")
        order = np.argsort(gid, kind="stable")
        pts = rnd(pts)[gather(counts, order)]
        counts, ids = counts[order], np.stack([gid[order], mat[order]], axis=1)
        return polygons.flat_records(pts, counts, ids, polygons.planes(pts, counts).unit)

    def _smooth(self, rnd) -> np.ndarray:
        if not self.kinds["pp"]:
            return np.zeros(0, dtypes.TRIANGLE)
        gid, mat, pts, nrm, counts = self._joined("pp")
        order = np.argsort(gid, kind="stable")
        at = gather(counts, order)
        ids = np.stack([gid[order], mat[order]], axis=1)
        return polygons.fan(rnd(pts)[at], rnd(nrm)[at], counts[order], ids)
