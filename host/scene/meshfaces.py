"""A polygon mesh as read from a mesh file (OBJ, PLY), before it becomes scene records."""

from dataclasses import dataclass

import numpy as np


@dataclass
class MeshFaces:
    """Vertex positions and optional normals, and for each face its corner indices
    (consecutive), corner count and file line (for messages)."""

    points: np.ndarray  # (nv, 3)
    normals: np.ndarray | None  # (nn, 3)
    corner_v: np.ndarray  # (corners,) vertex index per corner
    corner_n: np.ndarray | None  # (corners,) normal index per corner, -1 for none
    counts: np.ndarray  # (faces,)
    lines: np.ndarray  # (faces,)

    def corners(self) -> np.ndarray:
        """Position of every face corner, faces consecutive."""
        return self.points[self.corner_v]

    def smooth(self) -> np.ndarray:
        """Per face: every corner has a normal (the face is a smooth patch, NFF `pp`)."""
        if self.corner_n is None or self.normals is None or not len(self.counts):
            return np.zeros(len(self.counts), bool)
        starts = np.cumsum(self.counts) - self.counts
        has = (self.corner_n >= 0).astype(np.int64)
        return np.add.reduceat(has, starts) == self.counts
