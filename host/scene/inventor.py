"""Open Inventor 2.1 ASCII scenes (a subset) as NFF-like scenes.

Nodes: Separator (pushes and pops the traversal state) and Group (does not), Transform,
Translation, Rotation, Scale (composed into the current matrix, Inventor's order), Material,
Coordinate3, IndexedFaceSet, Sphere, Cone, Cylinder, Cube, PerspectiveCamera, PointLight,
DirectionalLight, Info; DEF and USE. Anything else is refused with `file:line: what`.

How Inventor maps onto what the tracer draws:
- Sphere: NFF sphere, its centre and radius through the matrix; a sphere under a non-uniform
  scale would be an ellipsoid and is refused.
- Cone, Cylinder: NFF's open cone `c` along the transformed y axis (their cross-section must
  stay a circle), plus the caps Inventor draws (`parts`) as 64-sided polygons circumscribing
  the rim, so no gap shows between cap and side.
- Cube: six polygons. IndexedFaceSet: one polygon per face (NFF `p`), corners through the
  matrix. Corners stay counter-clockwise about the outward normal, also under a mirroring
  matrix (the tracer shades polygons from both sides, as Inventor does without ShapeHints).
- Material: diffuseColor is NFF's colour with Kd 1, the largest specularColor component is
  Ks (which in NFF also reflects), shininess * 128 the Phong exponent, transparency T with
  ior 1 (Inventor does not bend light). Fields a Material leaves out keep their value.
- PerspectiveCamera: the first one is the view; heightAngle spans the image edge to edge.
- PointLight: an NFF light of colour * intensity; DirectionalLight: a light far away against
  its direction. Lights light the whole scene (NFF has no light scopes).

The text is parsed into a tree by `host.scene.inventorparser`; this module walks the tree.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from host.scene.builder import SceneBuilder
from host.scene.errors import SceneError
from host.scene.inventorparser import Node, Parser
from host.scene.settings import Settings, beside, default_light, framing, read_settings
from protocols.scene import SceneData, View

CAP_SIDES = 64
_PARTS = {"Cone": {"SIDES", "BOTTOM", "ALL"}, "Cylinder": {"SIDES", "TOP", "BOTTOM", "ALL"}}
_MATERIAL = {
    "diffuseColor": (0.8, 0.8, 0.8),
    "specularColor": (0.0, 0.0, 0.0),
    "shininess": 0.2,
    "transparency": 0.0,
}


def read_inventor(path, settings=None, note: Callable[[str], None] | None = None) -> SceneData:
    """Read an Inventor file; `settings`: a TOML giving resolution and background (default:
    the one beside the file)."""
    path = Path(path)
    text = path.read_text(encoding="latin-1")
    toml = Path(settings) if settings is not None else beside(path)
    given = read_settings(toml, {"resolution", "background"}) if toml is not None else Settings()
    return parse_inventor(text, str(path), given, note)


def parse_inventor(
    text: str,
    source: str = "<string>",
    settings: Settings | None = None,
    note: Callable[[str], None] | None = None,
) -> SceneData:
    """Parse Inventor text into a scene; `source` names it in errors and notes."""
    settings = settings or Settings()
    roots = Parser(text, source).parse()
    walk = _Walk(source, settings.size())
    for root in roots:
        walk.node(root)
    return walk.finish(settings, note)


# -- traversal ----------------------------------------------------------------------------------


@dataclass
class _State:
    """What a Separator saves and restores."""

    matrix: np.ndarray
    material: dict
    coords: np.ndarray | None = None


class _Walk:
    """Traverses the tree in Inventor's order, adding objects to a SceneBuilder."""

    def __init__(self, source: str, size: tuple[int, int]):
        self.source, self.size = source, size
        self.build = SceneBuilder(source)
        self.state = _State(np.eye(4), dict(_MATERIAL))
        self.view: View | None = None
        self.directional: list[tuple] = []
        self.notes: list[str] = []

    def error(self, node: Node, what: str, fieldname: str | None = None) -> SceneError:
        line = node.fields[fieldname][1] if fieldname in node.fields else node.line
        return SceneError(self.source, line, f"{node.kind}: {what}")

    def node(self, node: Node) -> None:
        kind = node.kind
        if kind == "Separator":
            saved = self.state
            self.state = _State(saved.matrix.copy(), dict(saved.material), saved.coords)
            try:
                for child in node.children:
                    self.node(child)
            finally:
                self.state = saved
        elif kind == "Group":
            for child in node.children:
                self.node(child)
        elif kind in ("Transform", "Translation", "Rotation", "Scale"):
            self.state.matrix = self.state.matrix @ self.transform(node)
        elif kind == "Material":
            self.material(node)
        elif kind == "Coordinate3":
            self.state.coords = np.array(node.get("point", [(0.0, 0.0, 0.0)]), float)
        elif kind != "Info":
            getattr(self, kind.lower())(node)

    # -- property nodes -------------------------------------------------------------------------

    def transform(self, node: Node) -> np.ndarray:
        """The node's matrix: T C R SR S SR^-1 C^-1 (Inventor's Transform)."""
        t = _translate(node.get("translation", (0.0, 0.0, 0.0)))
        r = self.rotation(node, "rotation")
        scale = node.get("scaleFactor", (1.0, 1.0, 1.0))
        if min(abs(s) for s in scale) == 0:
            raise self.error(node, "scaleFactor 0 flattens everything", "scaleFactor")
        s = np.diag([*scale, 1.0])
        sr = self.rotation(node, "scaleOrientation")
        c = _translate(node.get("center", (0.0, 0.0, 0.0)))
        c_inv = _translate([-x for x in node.get("center", (0.0, 0.0, 0.0))])
        return t @ c @ r @ sr @ s @ sr.T @ c_inv

    def rotation(self, node: Node, name: str) -> np.ndarray:
        x, y, z, angle = node.get(name, (0.0, 0.0, 1.0, 0.0))
        axis = np.array([x, y, z])
        length = np.linalg.norm(axis)
        if length == 0:
            if angle == 0:
                return np.eye(4)
            raise self.error(node, f"{name} has a zero axis", name)
        k = axis / length
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        m = np.eye(4)
        m[:3, :3] = np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * (kx @ kx)
        return m

    def material(self, node: Node) -> None:
        for name in _MATERIAL:
            if name not in node.fields:
                continue
            vals = node.fields[name][0]
            if len(vals) != 1:
                raise self.error(
                    node,
                    f"{name} has {len(vals)} values: one material per "
                    "shape only (no per-face materials)",
                    name,
                )
            v = vals[0]
            lo_ok = min(v) >= 0 if isinstance(v, tuple) else 0 <= v <= 1
            if not lo_ok:
                raise self.error(node, f"{name} out of range: {v}", name)
            self.state.material[name] = v

    def mat(self) -> int:
        m = self.state.material
        row = (
            *m["diffuseColor"],
            1.0,
            max(m["specularColor"]),
            m["shininess"] * 128.0,
            m["transparency"],
            1.0,
        )
        return self.build.material(row)

    # -- shapes ---------------------------------------------------------------------------------

    def linear(self) -> np.ndarray:
        return self.state.matrix[:3, :3]

    def points(self, local) -> np.ndarray:
        """Local points (n, 3) through the current matrix."""
        local = np.asarray(local, float).reshape(-1, 3)
        return local @ self.state.matrix[:3, :3].T + self.state.matrix[:3, 3]

    def faces(self, local, counts, lines) -> None:
        """Faces given counter-clockwise in local space, kept so in the world (a mirroring
        matrix reverses each face's corners)."""
        pts = self.points(local)
        counts = np.asarray(counts, np.int64)
        if np.linalg.det(self.linear()) < 0:
            starts = np.cumsum(counts) - counts
            face = np.repeat(np.arange(len(counts)), counts)
            at = np.arange(len(pts)) - starts[face]
            pts = pts[starts[face] + counts[face] - 1 - at]
        self.build.faces(pts, counts, self.mat(), lines)

    def sphere(self, node: Node) -> None:
        r = node.get("radius", 1.0)
        if r <= 0:
            raise self.error(node, f"radius must be positive, got {r:g}", "radius")
        lin = self.linear()
        gram = lin.T @ lin
        s2 = np.trace(gram) / 3
        if np.abs(gram - s2 * np.eye(3)).max() > 1e-9 * s2:
            raise self.error(
                node,
                "under a non-uniform scale a sphere is an ellipsoid, which "
                "the tracer cannot draw; scale it the same on every axis",
            )
        self.build.sphere(self.points([0.0, 0.0, 0.0])[0], r * math.sqrt(s2), self.mat())

    def cube(self, node: Node) -> None:
        half = np.array([node.get(k, 2.0) for k in ("width", "height", "depth")]) / 2
        if half.min() <= 0:
            raise self.error(node, "width, height and depth must be positive")
        quads = []
        for axis in range(3):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            for sign in (-1.0, 1.0):
                # Corners counter-clockwise about +axis (u, v, axis right-handed); reversed
                # for the -axis face.
                ring = [(-1, -1), (1, -1), (1, 1), (-1, 1)][:: int(sign)]
                for a, b in ring:
                    p = np.zeros(3)
                    p[axis], p[u], p[v] = sign * half[axis], a * half[u], b * half[v]
                    quads.append(p)
        self.faces(quads, [4] * 6, [node.line] * 6)

    def cone(self, node: Node) -> None:
        self.round(node, node.get("bottomRadius", 1.0), 0.0)

    def cylinder(self, node: Node) -> None:
        r = node.get("radius", 1.0)
        self.round(node, r, r)

    def round(self, node: Node, bottom: float, top: float) -> None:
        """Cone or cylinder along local y, centred: the open side and the caps asked for."""
        h = node.get("height", 2.0)
        if h <= 0 or max(bottom, top) <= 0 or min(bottom, top) < 0:
            raise self.error(node, "height and radius must be positive")
        parts = node.get("parts", {"ALL"})
        bad = parts - _PARTS[node.kind]
        if bad:
            raise self.error(
                node,
                f"parts {sorted(bad)} unknown (a {node.kind} has "
                f"{', '.join(sorted(_PARTS[node.kind]))})",
                "parts",
            )
        lin = self.linear()
        ex, ey, ez = lin[:, 0], lin[:, 1], lin[:, 2]
        sx, sz = np.linalg.norm(ex), np.linalg.norm(ez)
        tol = 1e-9 * max(sx, sz, np.linalg.norm(ey))
        if abs(sx - sz) > tol or max(abs(ex @ ez), abs(ex @ ey), abs(ez @ ey)) > tol * sx:
            raise self.error(
                node,
                "under this scale its cross-section is not a circle, "
                "which the tracer cannot draw; scale x and z alike",
            )
        everything = "ALL" in parts
        if everything or "SIDES" in parts:
            base, apex = self.points([[0.0, -h / 2, 0.0], [0.0, h / 2, 0.0]])
            self.build.cone(base, bottom * sx, apex, top * sx, self.mat())
        angle = 2 * math.pi * np.arange(CAP_SIDES) / CAP_SIDES
        reach = 1.0 / math.cos(math.pi / CAP_SIDES)  # circumscribed: covers the whole disc
        for part, y, r in (("BOTTOM", -h / 2, bottom), ("TOP", h / 2, top)):
            if r > 0 and (everything or part in parts):
                ring = np.stack((np.cos(angle), np.zeros(CAP_SIDES), np.sin(angle)), axis=1)
                ring *= r * reach
                ring[:, 1] = y
                # Increasing angle in (x, z) turns about -y: right for the bottom cap.
                self.faces(ring if part == "BOTTOM" else ring[::-1], [CAP_SIDES], [node.line])

    def indexedfaceset(self, node: Node) -> None:
        coords = self.state.coords
        index = np.array(node.get("coordIndex", []), np.int64)
        if coords is None:
            raise self.error(node, "no Coordinate3 before it")
        if not len(index):
            return
        ends = np.flatnonzero(index == -1)
        if len(index) and index[-1] != -1:
            ends = np.append(ends, len(index))
        starts = np.concatenate(([0], ends[:-1] + 1))
        counts = ends - starts
        if counts.min() < 3:
            raise self.error(node, "a face has fewer than 3 corners", "coordIndex")
        corners = np.delete(index, np.flatnonzero(index == -1))
        bad = np.flatnonzero((corners < 0) | (corners >= len(coords)))
        if len(bad):
            raise self.error(
                node,
                f"coordIndex {corners[bad[0]]} is out of range (the "
                f"Coordinate3 has {len(coords)} points)",
                "coordIndex",
            )
        line = node.fields["coordIndex"][1]
        self.faces(coords[corners], counts, [line] * len(counts))

    # -- camera and lights ----------------------------------------------------------------------

    def perspectivecamera(self, node: Node) -> None:
        if self.view is not None:
            self.notes.append(
                f"{self.source}:{node.line}: a second camera: the first one is the view"
            )
            return
        height_angle = node.get("heightAngle", math.pi / 4)
        focal = node.get("focalDistance", 5.0)
        if not 0 < height_angle < math.pi or focal <= 0:
            raise self.error(node, "heightAngle must be in (0, pi) and focalDistance positive")
        r = self.rotation(node, "orientation")[:3, :3]
        pos = np.array(node.get("position", (0.0, 0.0, 1.0)))
        eye, at = self.points([pos, pos + r @ [0.0, 0.0, -focal]])
        up = self.linear() @ r @ [0.0, 1.0, 0.0]
        # NFF's angle spans the centres of the outermost pixels, Inventor's the image edges.
        n = max(self.size)
        angle = 2 * math.degrees(math.atan(math.tan(height_angle / 2) * (n - 1) / n))
        try:
            self.view = View(
                eye=_floats(eye),
                at=_floats(at),
                up=_floats(up),
                angle=angle,
                hither=0.0,
                width=self.size[0],
                height=self.size[1],
            )
        except ValueError as e:
            raise self.error(node, str(e)) from None

    def pointlight(self, node: Node) -> None:
        if node.get("on", True):
            rgb = np.array(node.get("color", (1.0, 1.0, 1.0))) * node.get("intensity", 1.0)
            self.build.light(self.points(node.get("location", (0.0, 0.0, 1.0)))[0], rgb)

    def directionallight(self, node: Node) -> None:
        if node.get("on", True):
            d = self.linear() @ np.array(node.get("direction", (0.0, 0.0, -1.0)))
            if not np.linalg.norm(d) > 0:
                raise self.error(node, "direction is zero", "direction")
            rgb = np.array(node.get("color", (1.0, 1.0, 1.0))) * node.get("intensity", 1.0)
            self.directional.append((d / np.linalg.norm(d), rgb))

    # -- the end --------------------------------------------------------------------------------

    def finish(self, settings: Settings, note) -> SceneData:
        lo, hi = self.build.bounds()
        used, lacks = [], []
        view = self.view
        if view is None:
            view = framing(lo, hi, settings)
            used.append("a camera framing the scene")
            lacks.append("camera")
        centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-300)
        for d, rgb in self.directional:  # far enough that its rays are parallel to 1e-6
            self.build.light(centre - d * radius * 1e6, rgb)
        if not self.build.lights:
            self.build.light(*default_light(lo, hi, view))
            used.append("one white light above the eye")
            lacks.append("light")
        scene = self.build.build(view, settings.background or (0.0, 0.0, 0.0))
        if note is not None:
            for line in self.notes + self.build.notes:
                note(line)
            if used:
                note(f"{self.source}: no {' or '.join(lacks)} in the file: using {', '.join(used)}")
        return scene


def _translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def _floats(v) -> tuple[float, ...]:
    return tuple(float(c) for c in v)
