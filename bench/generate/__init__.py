"""Eric Haines' SPD scenes `tetra` and `balls` at any size factor, built in memory.

The SPD files exist only up to the literature's default sizes (tetra 6, balls 4); the scaling
benchmark needs larger ones, and arrays make a million objects in seconds without writing and
parsing the ~65 MB of NFF text they would be. Geometry, order, view, lights and materials follow
the SPD generators, so a generated scene equals `read_nff` of the SPD file of the same size
(tests/test_generate.py checks it against the files that exist). Records are built with
`host.scene.polygons`, as the NFF reader builds them.

    tetra(n): recursive tetrahedron, 4^n triangles (tetra.nff is n = 6: 4,096)
    balls(n): sphereflake, 1 + 9 + ... + 9^n spheres and a floor (balls.nff is n = 4: 7,381)
"""

import numpy as np

from host.scene import polygons
from protocols import dtypes
from protocols.scene import SceneData, View

SPD_BACKGROUND = (0.078, 0.361, 0.753)

TETRA_VIEW = View(
    eye=(1.02285, -3.17715, -2.17451),
    at=(-0.004103, -0.004103, 0.216539),
    up=(-0.816497, -0.816497, 0.816497),
    angle=45.0,
    hither=1.0,
)
TETRA_LIGHTS = ((2.0, -18.0, -5.0),)
TETRA_MATERIAL = ((1.0, 0.2, 0.2), 1.0, 0.0, 100000.0, 0.0, 0.0)  # rgb kd ks shine t ior
# The corners of the SPD tetrahedron and its faces, in the generator's output order.
TETRA_CORNERS = np.array([[-1, -1, 1], [-1, 1, -1], [1, -1, -1], [1, 1, 1]], float)
TETRA_FACES = np.array([[0, 1, 2], [3, 2, 1], [2, 3, 0], [1, 0, 3]])

BALLS_VIEW = View(
    eye=(2.1, 1.3, 1.7), at=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), angle=45.0, hither=0.01
)
BALLS_LIGHTS = ((4.0, 3.0, 2.0), (1.0, -4.0, 4.0), (-3.0, 1.0, 5.0))
BALLS_FLOOR = np.array([[12, 12, -0.5], [-12, 12, -0.5], [-12, -12, -0.5], [12, -12, -0.5]], float)
BALLS_MATERIALS = (
    ((1.0, 0.75, 0.33), 0.8, 0.0, 100000.0, 0.0, 1.0),  # floor
    ((1.0, 0.9, 0.7), 0.5, 0.5, 3.0827, 0.0, 1.0),
)  # spheres


def tetra_count(n: int) -> int:
    """Triangles of `tetra(n)`."""
    return 4**n


def balls_count(n: int) -> int:
    """Spheres of `balls(n)` (the floor polygon not counted)."""
    return (9 ** (n + 1) - 1) // 8


def tetra_triangles(n: int) -> np.ndarray:
    """(4^n, 3, 3) triangles of the SPD recursive tetrahedron of size factor n >= 1: each
    level replaces a tetrahedron by the four half-size ones at its corners (depth first, as
    the SPD generator writes them); a leaf writes its four faces."""
    if n < 1:
        raise ValueError(f"tetra: size factor must be >= 1, got {n}")
    centres, half = np.zeros((1, 3)), 1.0
    for _ in range(n - 1):
        half /= 2
        centres = (centres[:, None, :] + half * TETRA_CORNERS).reshape(-1, 3)
    corners = centres[:, None, :] + half * TETRA_CORNERS  # (T, 4, 3)
    return corners[:, TETRA_FACES, :].reshape(-1, 3, 3)


def _child_directions() -> np.ndarray:
    """The sphereflake's nine child directions about +z: three groups 120 degrees apart of
    one direction 45 degrees round at elevation asin(sqrt(2/3)) and two on the equator at 15
    and 75 degrees (SPD balls' `objset`)."""
    azimuth = np.radians([45.0, 15.0, 75.0])[None, :] + np.radians([0.0, 120.0, 240.0])[:, None]
    cos_elev = np.array([1 / np.sqrt(3), 1.0, 1.0])[None, :]
    z = np.broadcast_to(np.array([np.sqrt(2 / 3), 0.0, 0.0]), azimuth.shape)
    dirs = np.stack([cos_elev * np.cos(azimuth), cos_elev * np.sin(azimuth), z], axis=-1)
    return dirs.reshape(9, 3)


def _z_to(d: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations taking +z to the unit directions `d` about the axis z x d: the
    frame SPD turns the child directions into at each sphere."""
    axis = np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1)
    sin = np.linalg.norm(axis, axis=1)
    cos = d[:, 2]
    # Along -z SPD turns half a turn about y (balls_s3.nff shows it); along +z any axis does.
    k = np.where(sin[:, None] > 1e-12, axis / np.maximum(sin, 1e-300)[:, None], (0.0, 1.0, 0.0))
    cross = np.zeros((len(d), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    cross -= cross.transpose(0, 2, 1)
    outer = k[:, :, None] * k[:, None, :]
    return (
        cos[:, None, None] * np.eye(3)
        + sin[:, None, None] * cross
        + (1 - cos)[:, None, None] * outer
    )


def sphereflake(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(centres (N, 3), radii (N,)) of the SPD sphereflake of size factor n >= 0, in the SPD
    file's order (each sphere, then its nine children's subtrees). Built a level at a time:
    a child of radius r/3 touches its parent of radius r along the parent's frame's direction;
    its place in the file is its parent's + 1 + child index x the size of a child's subtree."""
    if n < 0:
        raise ValueError(f"balls: size factor must be >= 0, got {n}")
    objset = _child_directions()
    centres, radii = np.zeros((balls_count(n), 3)), np.zeros(balls_count(n))
    c, d, r, pos = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), 0.5, np.zeros(1, np.int64)
    centres[0], radii[0] = c[0], r
    for level in range(1, n + 1):
        d = np.einsum("pij,kj->pki", _z_to(d), objset).reshape(-1, 3)  # (P * 9, 3)
        c = np.repeat(c, 9, axis=0) + d * (r + r / 3)
        r /= 3
        pos = np.repeat(pos, 9) + 1 + np.tile(np.arange(9), len(pos)) * balls_count(n - level)
        centres[pos], radii[pos] = c, r
    return centres, radii


def _records(view, lights, materials, source: str) -> SceneData:
    """A scene with the SPD background, white lights at `lights` and `materials`."""
    light = np.zeros(len(lights), dtypes.LIGHT)
    light["pos"], light["rgb"] = lights, 1.0
    mats = np.array(list(materials), dtypes.MATERIAL)
    return SceneData(
        view=view, background=SPD_BACKGROUND, lights=light, materials=mats, source=source
    )


def _polygon_records(pts: np.ndarray, counts: np.ndarray, first_gid: int, mat: int):
    """(triangles, polygons, vertices) of flat polygons as the NFF reader makes them."""
    ids = np.stack([first_gid + np.arange(len(counts)), np.full(len(counts), mat)], axis=1)
    return polygons.flat_records(pts, counts, ids, polygons.planes(pts, counts).unit)


def tetra(n: int) -> SceneData:
    """SPD `tetra` at size factor n: 4^n matte triangles, one light."""
    tris = tetra_triangles(n)
    scene = _records(TETRA_VIEW, TETRA_LIGHTS, [TETRA_MATERIAL], f"<generated tetra {n}>")
    counts = np.full(len(tris), 3)
    scene.triangles, scene.polygons, scene.vertices = _polygon_records(
        tris.reshape(-1, 3), counts, 0, 0
    )
    return scene


def balls(n: int) -> SceneData:
    """SPD `balls` at size factor n: the floor square (gid 0), then the sphereflake."""
    scene = _records(BALLS_VIEW, BALLS_LIGHTS, BALLS_MATERIALS, f"<generated balls {n}>")
    scene.triangles, scene.polygons, scene.vertices = _polygon_records(
        BALLS_FLOOR, np.array([4]), 0, 0
    )
    centres, radii = sphereflake(n)
    s = np.zeros(len(radii), dtypes.SPHERE)
    s["gid"], s["mat"], s["center"], s["radius"] = np.arange(1, len(radii) + 1), 1, centres, radii
    scene.spheres = s
    return scene


GENERATORS = {"tetra": tetra, "balls": balls}
COUNTS = {"tetra": tetra_count, "balls": lambda n: balls_count(n) + 1}  # objects, floor too
