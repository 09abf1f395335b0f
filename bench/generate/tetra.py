"""SPD `tetra`: a recursive tetrahedron (Sierpinski), 4^n matte triangles and one light."""

import numpy as np

from bench.generate.records import SpdScene
from protocols.scene import SceneData, View

DEFAULT = 6  # tetra.nff: 4,096 triangles
VIEW = View(
    eye=(1.022846, -3.177154, -2.174512),
    at=(-0.004103, -0.004103, 0.216539),
    up=(-0.816497, -0.816497, 0.816497),
    angle=45.0,
    hither=1.0,
)
LIGHTS = ((2.0, -18.0, -5.0),)
# The corners of the SPD tetrahedron and its faces, in the generator's output order.
CORNERS = np.array([[-1, -1, 1], [-1, 1, -1], [1, -1, -1], [1, 1, 1]], float)
FACES = np.array([[0, 1, 2], [3, 2, 1], [2, 3, 0], [1, 0, 3]])


def tetra_count(n: int) -> int:
    """Triangles of `tetra(n)`."""
    return 4**n


def tetra_triangles(n: int) -> np.ndarray:
    """(4^n, 3, 3) triangles of the SPD recursive tetrahedron of size factor n >= 1: each
    level replaces a tetrahedron by the four half-size ones at its corners (depth first, as
    the SPD generator writes them); a leaf writes its four faces."""
    if n < 1:
        raise ValueError(f"tetra: size factor must be >= 1, got {n}")
    centres, half = np.zeros((1, 3)), 1.0
    for _ in range(n - 1):
        half /= 2
        centres = (centres[:, None, :] + half * CORNERS).reshape(-1, 3)
    corners = centres[:, None, :] + half * CORNERS  # (T, 4, 3)
    return corners[:, FACES, :].reshape(-1, 3, 3)


def tetra(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `tetra` at size factor n: 4^n red matte triangles, one light."""
    scene = SpdScene(VIEW, LIGHTS)
    mat = scene.material((1.0, 0.2, 0.2), 1.0, 0.0, 0.0, 0.0, 0.0)
    tris = tetra_triangles(n)
    scene.polygons(tris.reshape(-1, 3), np.full(len(tris), 3), mat)
    return scene.build(f"<generated tetra {n}>", printed)
