"""Eric Haines' Standard Procedural Databases (SPD) built in memory, at any size factor.

The SPD files exist only at a few sizes; the scaling benchmark needs larger ones, and arrays
make a million objects in seconds without writing and parsing the ~65 MB of NFF text they would
be. A clone without the scene files generates them for its tests (`spd`, `write_nff`).
Geometry, object order, view, lights, materials and the SPD's own random numbers (mount) follow
the SPD generators, so a generated scene is the scene `read_nff` makes of the SPD file of the
same size; with `printed=True` every number is first rounded as the SPD prints it (`%g`), and
the records then equal the file's (tests/test_generate.py checks every generator against every
file there is). One module per scene:

    balls(n)     sphereflake: 1 + 9 + ... + 9^n spheres and a floor (default n = 4)
    gears(n)     n^3 gears of 146 polygons each and a floor (4)
    jacks(n)     recursive jacks: (8^n - 1) / 7 jacks of 3 cylinders and 6 spheres (1)
    lattice(n)   (n + 1)^3 spheres joined by 3 n (n + 1)^2 cylinders, each its own colour (12)
    mount(n)     fractal mountain of 2 x 4^n triangles under four glass spheres (6)
    rings(n)     pyramid of 1 + 4 + ... + n^2 ring clusters of 30 spheres and cylinders (7)
    shells(n)    a spiral shell of about 180 x 2^n spheres (5)
    sombrero(n)  height field of 2 (32 x 2^(n-1) - 1)^2 triangles (1)
    teapot(n)    Newell's teapot as 64 n^2 - 8 n smooth triangles on an n x n checkerboard (6)
    tetra(n)     recursive tetrahedron: 4^n triangles (6)
    tree(n)      branching tree of 2^(n+1) - 1 cones and spheres on a field (11)
"""

import re

from bench.generate.balls import balls, balls_count, sphereflake
from bench.generate.gears import gears, gears_count
from bench.generate.jacks import jacks, jacks_count
from bench.generate.lattice import lattice, lattice_count
from bench.generate.mount import mount
from bench.generate.nffwrite import write_nff
from bench.generate.records import SPD_BACKGROUND, SpdScene
from bench.generate.rings import rings, rings_count
from bench.generate.shells import shells, shells_count
from bench.generate.sombrero import sombrero, sombrero_count
from bench.generate.teapot import teapot
from bench.generate.tetra import tetra, tetra_count, tetra_triangles
from bench.generate.tree import tree, tree_count
from protocols.scene import SceneData

__all__ = [
    "COUNTS",
    "DEFAULT_SIZES",
    "GENERATORS",
    "SPD_BACKGROUND",
    "SpdScene",
    "balls",
    "balls_count",
    "gears",
    "gears_count",
    "jacks",
    "lattice",
    "mount",
    "rings",
    "shells",
    "sombrero",
    "spd",
    "sphereflake",
    "teapot",
    "tetra",
    "tetra_count",
    "tetra_triangles",
    "tree",
    "write_nff",
]

GENERATORS = {
    "tetra": tetra,
    "balls": balls,
    "gears": gears,
    "jacks": jacks,
    "lattice": lattice,
    "mount": mount,
    "rings": rings,
    "shells": shells,
    "sombrero": sombrero,
    "teapot": teapot,
    "tree": tree,
}
# The size factor of each SPD program when given none: the plain NAME.nff of the literature.
DEFAULT_SIZES = {
    "balls": 4,
    "gears": 4,
    "jacks": 1,
    "lattice": 12,
    "mount": 6,
    "rings": 7,
    "shells": 5,
    "sombrero": 1,
    "teapot": 6,
    "tetra": 6,
    "tree": 11,
}
# Objects (primitives, floors and walls too) at size factor n; teapot's depend on its cusps.
COUNTS = {
    "tetra": tetra_count,
    "balls": lambda n: balls_count(n) + 1,
    "gears": gears_count,
    "jacks": jacks_count,
    "lattice": lattice_count,
    "mount": lambda n: 4 + 2 * 4**n,
    "rings": rings_count,
    "shells": shells_count,
    "sombrero": sombrero_count,
    "tree": tree_count,
}


def spd(name: str, printed: bool = False) -> SceneData:
    """The SPD scene of a file name's stem: `NAME` at the SPD's default size factor or
    `NAME_sK` at size factor K (e.g. "tetra", "balls_s2"), as `GENERATORS` make it."""
    m = re.fullmatch(r"([a-z]+)(?:_s(\d+))?", name.removesuffix(".nff"))
    if m is None or m[1] not in GENERATORS:
        raise ValueError(f"no SPD generator for {name!r} (have {', '.join(GENERATORS)})")
    size = int(m[2]) if m[2] else DEFAULT_SIZES[m[1]]
    return GENERATORS[m[1]](size, printed=printed)
