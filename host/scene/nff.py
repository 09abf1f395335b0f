"""NFF (Neutral File Format) scene reader: text -> `SceneData` (DESIGN.md section 3).

The tokens and their number readers are `host.scene.nfftokens`; this module is the grammar on
top of them. Records go into flat Python lists and become NumPy record arrays once at the end,
and polygon geometry is checked in bulk with NumPy, so a file of 100,000 primitives costs
per-token work only.

Every problem is a `SceneError` reading `file:line: what is wrong`, raised before any node starts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from host.scene import polygons
from host.scene.errors import SceneError
from host.scene.nfftokens import INT, Tokens
from protocols import dtypes
from protocols.scene import SceneData, View

_VIEW_ARITY = {"from": 3, "at": 3, "up": 3, "angle": 1, "hither": 1, "resolution": 2, "yon": 1}
_VIEW_REQUIRED = ("from", "at", "up", "angle")
_OBJECTS = frozenset(("s", "p", "pp", "c"))
_MATERIAL_FIELDS = ("red", "green", "blue", "Kd", "Ks", "Shine", "T", "ior")


def read_nff(path) -> SceneData:
    """Read an NFF file; errors name the path as given."""
    # latin-1 never fails to decode: stray bytes become tokens that are reported with a line.
    text = Path(path).read_text(encoding="latin-1")
    return parse_nff(text, str(path))


def parse_nff(text: str, source: str = "<string>") -> SceneData:
    """Parse NFF text into a `SceneData`; `source` names the text in error messages."""
    scan = _Scan(text, source)
    try:
        scan.run()
    except SceneError as err:
        # Geometry is checked in bulk after the token pass; a bad polygon that precedes the
        # syntax error is still the first error in the file, so report that one.
        earlier = scan.geometry_error()
        if earlier is not None and earlier.line <= err.line:
            raise earlier from None
        raise
    late = scan.geometry_error()
    if late is not None:
        raise late
    if scan.view is None:
        raise SceneError(source, scan.n_lines, "missing view")
    return scan.build()


class _Scan(Tokens):
    """One pass over the tokens, collecting records into flat lists."""

    def __init__(self, text: str, source: str):
        super().__init__(text, source)
        self.view: View | None = None
        self.background = (0.0, 0.0, 0.0)
        self.lights: list[float] = []  # 6 per light
        self.materials: list[float] = []  # 8 per material
        self.spheres: list[float] = []  # 4 per sphere
        self.sphere_ids: list[int] = []  # gid, mat per sphere
        self.cones: list[float] = []  # 8 per cone
        self.cone_ids: list[int] = []
        self.polys: list[float] = []  # 3 per vertex, `p` of any size
        self.poly_n: list[int] = []
        self.poly_ids: list[int] = []
        self.poly_tok: list[int] = []  # token index of the `p`
        self.patches: list[float] = []  # 6 per vertex
        self.patch_n: list[int] = []
        self.patch_ids: list[int] = []
        self.patch_tok: list[int] = []
        self._poly_geom = None  # unit normals of the `p` polygons, set by geometry_error()

    # -- entities -----------------------------------------------------------------------------

    def read_view(self, i: int) -> int:
        """Keyword groups after the `v` at token i, in any order; returns the next token index."""
        toks, n = self.toks, len(self.toks)
        got: dict[str, tuple[list, int]] = {}
        j = i + 1
        while j < n and toks[j] in _VIEW_ARITY:
            key = toks[j]
            if key in got:
                raise self.error(j, f"view: duplicate '{key}'")
            k = _VIEW_ARITY[key]
            if key == "resolution":
                self.need(j + 1, 2, j)
                vals = []
                for m in (j + 1, j + 2):
                    tok = toks[m]
                    if not INT.fullmatch(tok) or int(tok) <= 0:
                        raise self.error(m, f"resolution must be positive integers, got {tok!r}")
                    vals.append(int(tok))
            else:
                vals = self.nums(j + 1, k, j)
            got[key] = (vals, j)
            j += 1 + k
        missing = [key for key in _VIEW_REQUIRED if key not in got]
        if missing:
            raise self.error(i, f"view lacks {', '.join(missing)}")
        angle, at = got["angle"]
        if not 0.0 < angle[0] < 180.0:
            raise self.error(at + 1, f"view angle must be in (0, 180) degrees, got {angle[0]:g}")
        width, height = got.get("resolution", ([512, 512], i))[0]
        try:
            self.view = View(
                eye=tuple(got["from"][0]),
                at=tuple(got["at"][0]),
                up=tuple(got["up"][0]),
                angle=angle[0],
                hither=got.get("hither", ([0.0], i))[0][0],
                width=width,
                height=height,
            )
        except ValueError as e:
            raise self.error(i, str(e)) from None
        return j

    def read_material(self, i: int) -> None:
        vals = self.nums(i + 1, 8, i)
        # ior only matters for a transmitter; SPD writes ior 0 for opaque materials.
        if min(vals[:5]) < 0 or vals[6] < 0 or vals[7] < 0 or (vals[6] > 0 and vals[7] == 0):
            for j in (0, 1, 2, 3, 4, 6):
                if vals[j] < 0:
                    raise self.error(i + 1 + j, f"material: negative {_MATERIAL_FIELDS[j]}")
            raise self.error(i + 8, "material: ior must be positive")
        self.materials.extend(vals)

    def run(self) -> None:
        """The token pass: dispatch on each entity keyword, most frequent first."""
        toks, n, nums = self.toks, len(self.toks), self.nums
        spheres, sphere_ids = self.spheres, self.sphere_ids
        polys, poly_n, poly_ids, poly_tok = self.polys, self.poly_n, self.poly_ids, self.poly_tok
        gid = 0
        mat = -1
        i = 0
        while i < n:
            t = toks[i]
            if t in _OBJECTS:
                if self.view is None:
                    raise self.error(i, "object before view")
                if mat < 0:
                    raise self.error(i, "no material: object before any 'f'")
                if t == "s":
                    vals = nums(i + 1, 4, i)
                    if vals[3] == 0:
                        raise self.error(i + 4, "sphere radius is 0")
                    spheres.extend(vals)
                    sphere_ids.extend((gid, mat))
                    i += 5
                elif t == "p":
                    m = self.count(i + 1, i)
                    polys.extend(nums(i + 2, 3 * m, i))
                    poly_n.append(m)
                    poly_ids.extend((gid, mat))
                    poly_tok.append(i)
                    i += 2 + 3 * m
                elif t == "pp":
                    m = self.count(i + 1, i)
                    self.patches.extend(nums(i + 2, 6 * m, i))
                    self.patch_n.append(m)
                    self.patch_ids.extend((gid, mat))
                    self.patch_tok.append(i)
                    i += 2 + 6 * m
                else:  # "c"
                    vals = nums(i + 1, 8, i)
                    if vals[0:3] == vals[4:7]:
                        raise self.error(i, "cone base and apex coincide")
                    if vals[3] == 0 and vals[7] == 0:
                        raise self.error(i, "cone has both radii 0")
                    self.cones.extend(vals)
                    self.cone_ids.extend((gid, mat))
                    i += 9
                gid += 1
            elif t == "f":
                self.read_material(i)
                mat += 1
                i += 9
            elif t == "l":
                if gid:
                    raise self.error(i, "lights must precede objects")
                vals = nums(i + 1, 3, i)
                if self.is_number(i + 4):
                    vals += nums(i + 4, 3, i)
                    i += 7
                else:
                    vals += (1.0, 1.0, 1.0)
                    i += 4
                self.lights.extend(vals)
            elif t == "b":
                self.background = tuple(nums(i + 1, 3, i))
                i += 4
            elif t == "v":
                if gid:
                    raise self.error(i, "second view after objects")
                i = self.read_view(i)
            else:
                raise self.error(i, f"unknown entity {t!r}")

    # -- geometry -----------------------------------------------------------------------------

    def geometry_error(self) -> SceneError | None:
        """The first (by line) degenerate `p` polygon or zero patch normal, or None.

        Patches are not tested for area: SPD's teapot has collinear `pp 3` slivers, which are
        harmless (a zero-area triangle is never hit) and must load.
        """
        errs = []
        normals, err = _check_polygons(self, self.polys, self.poly_n, self.poly_tok, 3)
        self._poly_geom = normals
        errs.append(err)
        if self.patches:
            nrm = np.array(self.patches).reshape(-1, 6)[:, 3:]
            zero = np.flatnonzero(np.linalg.norm(nrm, axis=1) == 0)
            if len(zero):
                errs.append(
                    self.error(
                        _vertex_token(self.patch_n, self.patch_tok, zero[0], 6, 3),
                        "patch vertex normal has zero length",
                    )
                )
        errs = [e for e in errs if e is not None]
        return min(errs, key=lambda e: e.line) if errs else None

    # -- output -------------------------------------------------------------------------------

    def build(self) -> SceneData:
        """Turn the flat lists into record arrays (geometry_error() has run)."""
        lights = np.array(self.lights, float).reshape(-1, 6)
        light_rec = np.zeros(len(lights), dtypes.LIGHT)
        light_rec["pos"], light_rec["rgb"] = lights[:, :3], lights[:, 3:]

        mats = np.array(self.materials, float).reshape(-1, 8)
        mat_rec = np.zeros(len(mats), dtypes.MATERIAL)
        mat_rec["rgb"] = mats[:, :3]
        for j, name in enumerate(("kd", "ks", "shine", "t", "ior"), start=3):
            mat_rec[name] = mats[:, j]

        sph = np.array(self.spheres, float).reshape(-1, 4)
        sph_rec = np.zeros(len(sph), dtypes.SPHERE)
        _ids(sph_rec, self.sphere_ids)
        sph_rec["center"], sph_rec["radius"] = sph[:, :3], sph[:, 3]

        cone = np.array(self.cones, float).reshape(-1, 8)
        cone_rec = np.zeros(len(cone), dtypes.CONE)
        _ids(cone_rec, self.cone_ids)
        cone_rec["base"], cone_rec["base_r"] = cone[:, 0:3], cone[:, 3]
        cone_rec["apex"], cone_rec["apex_r"] = cone[:, 4:7], cone[:, 7]

        pts = np.array(self.polys, float).reshape(-1, 3)
        tri_rec, poly_rec, vertices = polygons.flat_records(
            pts, self.poly_n, self.poly_ids, self._poly_geom
        )
        patches = np.array(self.patches, float).reshape(-1, 6)
        smooth = polygons.fan(patches[:, :3], patches[:, 3:], self.patch_n, self.patch_ids)
        triangles = polygons.by_gid(tri_rec, smooth)

        return SceneData(
            view=self.view,
            background=tuple(float(c) for c in self.background),
            lights=light_rec,
            materials=mat_rec,
            spheres=sph_rec,
            triangles=triangles,
            polygons=poly_rec,
            vertices=vertices,
            cones=cone_rec,
            source=self.source,
        )


def _ids(rec: np.ndarray, ids: list[int]) -> None:
    pairs = np.array(ids, np.int64).reshape(-1, 2)
    rec["gid"], rec["mat"] = pairs[:, 0], pairs[:, 1]


def _vertex_token(counts, toks, v: int, stride: int, offset: int = 0) -> int:
    """Token index of component `offset` of global vertex v of the `p`/`pp` entities."""
    ends = np.cumsum(counts)
    k = int(np.searchsorted(ends, v, side="right"))
    local = v - (int(ends[k]) - counts[k])
    return toks[k] + 2 + stride * local + offset


def _check_polygons(scan: _Scan, flat: list[float], counts, toks, stride: int):
    """Unit normals of all polygons and the first degenerate one as a SceneError (or None)."""
    if not counts:
        return np.zeros((0, 3)), None
    pts = np.array(flat, float).reshape(-1, stride)[:, :3]
    geom = polygons.planes(pts, counts)
    starts = np.cumsum(counts) - np.asarray(counts, np.int64)
    err = None
    first_flat = np.flatnonzero(geom.flat)
    if len(first_flat):
        err = scan.error(toks[first_flat[0]], "degenerate polygon: no area")
    first_off = np.flatnonzero(geom.off)
    if len(first_off):
        k = first_off[0]
        dist = geom.dist[starts[k] : starts[k] + counts[k]]
        v = int(np.argmax(dist))
        e = scan.error(
            toks[k] + 2 + stride * v,
            f"degenerate polygon: vertex {v + 1} is {dist[v]:.3g} off the plane",
        )
        if err is None or e.line < err.line:
            err = e
    return geom.unit, err
