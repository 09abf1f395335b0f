"""SPD `mount`: a fractal mountain (midpoint displacement, seeded by position through the SPD's
own hash and Gaussian generator, so every size factor is one deterministic landscape) under a
pyramid of four glass spheres; one light."""

import numpy as np

from bench.generate.records import SpdScene, rotation
from protocols.scene import SceneData, View

DEFAULT = 6  # the SPD's default size factor: 8,192 triangles
VIEW = View(eye=(-1.6, 1.6, 1.7), at=(0, 0, 0), up=(0, 0, 1), angle=45.0, hither=0.01)
MOUNTAIN_NO = 21  # the SPD's choice of landscape
FRACTAL_DIMENSION = 2.2
RATIO = 2.0 / np.exp(np.log(2.0) / (FRACTAL_DIMENSION - 1.0))
ROUGHNESS = np.sqrt(RATIO**2 - 1.0)
M1, IA1, IC1 = 134456, 8121, 28411  # the SPD's linear congruential generator
# The corners of a square and of its four quarters, in the SPD's order, as (x, y) steps of
# half its width: quarter q's corners lower left, lower right, upper right, upper left.
QUARTERS = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])


def gauss_table() -> np.ndarray:
    """The SPD's `lib_gauss_rand(seed)` for every seed the mountain uses (21 to 21 + 0xffff): a
    Gaussian deviate by the polar method from its generator, rejecting points off the disc."""
    seed = MOUNTAIN_NO + np.arange(0x10000, dtype=np.int64)
    todo, ix2 = np.ones(len(seed), bool), seed.copy()
    v1, r = np.zeros(len(seed)), np.zeros(len(seed))
    while todo.any():
        ix1 = (IC1 + ix2[todo] * IA1) % M1
        ix2[todo] = (IC1 + ix1 * IA1) % M1
        v1[todo] = ix1 * 2.0 / M1 - 1.0  # the SPD's macro makes `* 2.0 * RM1` this
        v2 = ix2[todo] * 2.0 / M1 - 1.0
        r[todo] = v1[todo] ** 2 + v2**2
        todo[todo] = r[todo] >= 1.0
    return v1 * np.sqrt(-2.0 * np.log(r) / r)


def hash_seed(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """The SPD's (original, 1987) position hash of grid point (a, b) at size factor n, as
    64-bit unsigned arithmetic does it (a shift count past 63 wraps as on x86)."""
    a, b = a.astype(np.uint64), b.astype(np.uint64)

    def shift(x, k):
        return x << np.uint64(k % 64)

    return ((shift(a, 23 - n) + shift(b, 15 - n) + shift(a, 7 - n)) & np.uint64(0xFFFF)).astype(
        np.int64
    )


def _subdivide(ll, z, width: int, n: int, gauss):
    """One level: each square (lower-left grid corner `ll`, corner heights `z` ll, lr, ur, ul)
    into its four quarters, the edge midpoints and centre raised by Gaussian amounts seeded by
    their grid points and scaled by ROUGHNESS x half the width."""
    half = width >> 1
    rise = (half * 2.0 / (1 << n)) * ROUGHNESS

    def g(dx, dy, scale=rise):
        return scale * gauss[hash_seed(ll[:, 0] + dx, ll[:, 1] + dy, n)]

    lower = (z[:, 0] + z[:, 1]) / 2.0 + g(half, 0)
    right = (z[:, 1] + z[:, 2]) / 2.0 + g(width, half)
    upper = (z[:, 2] + z[:, 3]) / 2.0 + g(half, width)
    left = (z[:, 3] + z[:, 0]) / 2.0 + g(0, half)
    middle = (z[:, 0] + z[:, 1] + z[:, 2] + z[:, 3]) / 4.0 + g(half, half, 1.4142136 * rise)
    quarters = [
        (z[:, 0], lower, middle, left),
        (lower, z[:, 1], right, middle),
        (middle, right, z[:, 2], upper),
        (left, middle, upper, z[:, 3]),
    ]
    z = np.stack([np.stack(q, 1) for q in quarters], axis=1).reshape(-1, 4)
    return (ll[:, None, :] + half * QUARTERS).reshape(-1, 2), z


def mountain(n: int) -> np.ndarray:
    """(2 x 4^n, 3, 3) triangles of the mountain on [-1, 1]^2, in the SPD's recursive order
    (quarters lower left, lower right, upper right, upper left); a unit square is two
    triangles."""
    gauss = gauss_table()
    size = 1 << n
    ll, z = np.zeros((1, 2), np.int64), np.zeros((1, 4))
    for level in range(n):
        ll, z = _subdivide(ll, z, size >> level, n, gauss)
    lo, hi = -1.0 + ll * 2.0 / size, -1.0 + (ll + 1) * 2.0 / size
    x = np.stack([lo[:, 0], hi[:, 0], hi[:, 0], lo[:, 0]], 1)
    y = np.stack([lo[:, 1], lo[:, 1], hi[:, 1], hi[:, 1]], 1)
    corners = np.stack([x, y, z], axis=-1)  # (squares, 4, 3): ll, lr, ur, ul
    return corners[:, [[0, 1, 2], [2, 3, 0]]].reshape(-1, 3, 3)


def crystal_spheres(centre=(-0.8, 0.8, 1.0), radius: float = 0.17) -> np.ndarray:
    """(4, 3) centres of the pyramid of touching spheres: the top one above `centre`, then
    three below it turned 120 degrees apart."""
    top = np.array([0.0, 0.0, radius * np.sqrt(3.0 / 2.0)])
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    a = np.arccos(-1.0 / 3.0)
    c, s = np.cos(a), np.sin(a)
    cross = np.array([[0, axis[2], -axis[1]], [-axis[2], 0, axis[0]], [axis[1], -axis[0], 0]])
    tilt = np.outer(axis, axis) * (1 - c) + np.eye(3) * c + cross * s  # the SPD's axis rotation
    low = top @ tilt
    turns = rotation("z", np.arange(3) * 2.0 * np.pi / 3.0)
    return np.asarray(centre) + np.concatenate([top[None], low @ turns])


def mount(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `mount` at size factor n: four glass spheres, then the mountain's triangles."""
    scene = SpdScene(VIEW, ((-100.0, -100.0, 100.0),))
    glass = scene.material((1.0, 1.0, 1.0), 0.1, 0.1, 6.7, 0.9, 1.5)
    scene.spheres(crystal_spheres(), np.full(4, 0.17), glass)
    rock = scene.material((0.5, 0.45, 0.35), 1.0, 0.0, 0.0, 0.0, 0.0)
    tris = mountain(n)
    scene.polygons(tris.reshape(-1, 3), np.full(len(tris), 3), rock)
    return scene.build(f"<generated mount {n}>", printed)
