"""The scene as arrays: what the host reads from a file and what a node receives.

Independent of the file format: the NFF reader fills it, the engine builds its kernels' tables
from it, and the mesh downloads slices of it.
"""

from dataclasses import dataclass, field

import numpy as np

from protocols import dtypes


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


def _empty(dtype):
    return field(default_factory=lambda: np.zeros(0, dtype))


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
    def n_objects(self) -> int:
        """Number of NFF primitives (distinct gids)."""
        gids = [t["gid"] for t in (self.spheres, self.triangles, self.polygons, self.cones)]
        return len(np.unique(np.concatenate(gids))) if any(len(g) for g in gids) else 0
