"""The scene as arrays: what the host reads from a file and what a node receives.

Independent of the file format: the NFF reader fills it, the engine builds its kernels' tables
from it, and the mesh downloads slices of it.
"""

from dataclasses import asdict, dataclass, field

import numpy as np

from protocols import dtypes

# Scene numbers the tracer can square and multiply in float64 without overflow or underflow
# (lengths, dot products, quadratic discriminants): beyond them a render would go non-finite.
MAX_COORDINATE = 1e100
MIN_LENGTH = 1e-100


def _point(v) -> str:
    return "(" + ", ".join(f"{float(x):g}" for x in v) + ")"


@dataclass(frozen=True)
class View:
    """A pinhole eye as NFF states it; `angle` is the full field of view in degrees measured
    between the centres of the outermost pixel rows/columns (aspect 1)."""

    eye: tuple[float, float, float]
    at: tuple[float, float, float]
    up: tuple[float, float, float]
    angle: float
    hither: float = 0.0
    width: int = 512
    height: int = 512

    def __post_init__(self):
        """A view every node can build a camera basis from: finite, the eye apart from the
        target, `up` not along the line of sight (a degenerate basis would hang or blacken
        a render)."""
        try:
            eye, at, up = (np.asarray(v, float) for v in (self.eye, self.at, self.up))
            numbers = np.concatenate([eye, at, up, [self.angle, self.hither]]).astype(float)
        except (TypeError, ValueError):
            raise ValueError("view: eye, at and up must be three numbers each") from None
        if eye.shape != (3,) or at.shape != (3,) or up.shape != (3,):
            raise ValueError("view: eye, at and up must be three numbers each")
        if not np.all(np.isfinite(numbers)) or np.abs(numbers).max() > MAX_COORDINATE:
            raise ValueError(f"view: every number must be finite and within +-{MAX_COORDINATE:g}")
        sight = at - eye
        scale = max(float(np.abs(np.concatenate([eye, at])).max()), MIN_LENGTH)
        if not np.linalg.norm(sight) > max(1e-12 * scale, MIN_LENGTH):
            raise ValueError(
                f"view: 'from' {_point(eye)} and 'at' {_point(at)} coincide (or are "
                f"closer than {MIN_LENGTH:g}: scale the scene up)"
            )
        across = np.cross(sight / np.linalg.norm(sight), up)
        if not np.linalg.norm(up) > 0 or not np.linalg.norm(across) > 1e-9 * np.linalg.norm(up):
            raise ValueError(f"view: 'up' {_point(up)} is zero or along the line of sight")
        if not 0.0 < self.angle < 180.0 or self.hither < 0:
            raise ValueError("view: angle must be in (0, 180) degrees and hither >= 0")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 0 < v <= 32768:
                raise ValueError(f"view: {name} must be a whole number from 1 to 32768")


def _empty(dtype):
    return field(default_factory=lambda: np.zeros(0, dtype))


# The primitive tables of a scene, in the order gids and engine-local ids follow: the one list of
# object kinds every reader, the download, the node's checks and the engine's variants use.
OBJECT_KINDS = ("spheres", "triangles", "polygons", "cones")
# every record array of a scene: what its memory is counted from
SCENE_TABLES = (*OBJECT_KINDS, "vertices", "materials", "lights")
# each table's records as they travel (OBJECTS): vertices flat, three numbers a vertex
TABLE_DTYPES = {
    "spheres": dtypes.SPHERE,
    "triangles": dtypes.TRIANGLE,
    "polygons": dtypes.POLYGON,
    "cones": dtypes.CONE,
    "vertices": np.dtype("<f8"),
    "materials": dtypes.MATERIAL,
    "lights": dtypes.LIGHT,
}
assert set(TABLE_DTYPES) == set(SCENE_TABLES)


@dataclass(frozen=True)
class SceneHeader:
    """What of a scene is not its objects: the view and the background colour. CONFIG
    carries it (`to_wire`); the objects follow as OBJECTS tables (`SceneData.tables`)."""

    view: View
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def to_wire(self) -> dict:
        return {"view": asdict(self.view), "background": [float(c) for c in self.background]}

    @classmethod
    def from_wire(cls, wire) -> "SceneHeader":
        """The header a peer sent, checked: ValueError naming the field (a view every node
        can build a camera from, a background of three finite numbers)."""
        if not isinstance(wire, dict) or set(wire) != {"view", "background"}:
            raise ValueError("scene: want a map of view and background")
        view = wire["view"]
        if not isinstance(view, dict):
            raise ValueError("scene.view: want a map")
        try:
            view = View(**{k: tuple(v) if isinstance(v, list) else v for k, v in view.items()})
        except TypeError as e:  # a field missing or unknown
            raise ValueError(f"scene.view: {e}") from None
        except ValueError as e:  # View's own checks, which name it ("view: ...")
            raise ValueError(f"scene.{e}") from None
        background = wire["background"]
        if not (
            isinstance(background, list)
            and len(background) == 3
            and all(
                isinstance(c, int | float) and not isinstance(c, bool) and np.isfinite(c)
                for c in background
            )
        ):
            raise ValueError("scene.background must be three finite numbers")
        return cls(view, tuple(float(c) for c in background))


@dataclass
class SceneData:
    """Every entity of a scene as record arrays of `protocols.dtypes` types."""

    view: View
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lights: np.ndarray = _empty(dtypes.LIGHT)
    materials: np.ndarray = _empty(dtypes.MATERIAL)
    spheres: np.ndarray = _empty(dtypes.SPHERE)
    triangles: np.ndarray = _empty(dtypes.TRIANGLE)
    polygons: np.ndarray = _empty(dtypes.POLYGON)
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cones: np.ndarray = _empty(dtypes.CONE)
    source: str = "<memory>"

    @property
    def header(self) -> SceneHeader:
        return SceneHeader(self.view, tuple(float(c) for c in self.background))

    def tables(self) -> dict[str, np.ndarray]:
        """Every record array by table name (`TABLE_DTYPES`), vertices flat: what OBJECTS
        carries of this scene, materials and lights first."""
        return {
            "materials": self.materials,
            "lights": self.lights,
            **{kind: getattr(self, kind) for kind in OBJECT_KINDS},
            "vertices": self.vertices.reshape(-1),
        }

    @classmethod
    def from_tables(cls, header: SceneHeader, tables: dict, source: str = "<memory>"):
        """The scene of `header` and record arrays by table name (`tables()`' form; a table
        not given is empty)."""

        def table(name):
            got = tables.get(name)
            return got if got is not None else np.zeros(0, TABLE_DTYPES[name])

        return cls(
            view=header.view,
            background=header.background,
            **{name: table(name) for name in SCENE_TABLES if name != "vertices"},
            vertices=table("vertices").reshape(-1, 3),
            source=source,
        )

    @property
    def records_by_kind(self) -> dict[str, int]:
        """Records of each object table (`OBJECT_KINDS`): a polygon split or a patch
        tessellated counts each of its records, as engines build and hold them."""
        return {kind: len(getattr(self, kind)) for kind in OBJECT_KINDS}

    @property
    def n_objects(self) -> int:
        """Number of NFF primitives (distinct gids)."""
        gids = [getattr(self, kind)["gid"] for kind in OBJECT_KINDS]
        return len(np.unique(np.concatenate(gids))) if any(len(g) for g in gids) else 0
