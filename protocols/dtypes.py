"""Record dtypes shared by host, engine and wire, defined once.

Every batch that crosses a module or a socket is a NumPy structured array of one of these
dtypes, so kernels, framing and tests agree on layout byte for byte.
"""

import numpy as np

# Ray kinds, in the order SPD statistics list them.
EYE, REFLECTED, REFRACTED, SHADOW = 0, 1, 2, 3
KIND_NAMES = ("eye", "reflected", "refracted", "shadow")

# A ray a node can continue without knowing where it came from (DESIGN.md section 4):
# origin and direction never change across nodes; t_min is where to resume.
RAY = np.dtype(
    [
        ("o", "<f8", 3),  # origin (world)
        ("d", "<f8", 3),  # unit direction (world)
        ("t_min", "<f8"),  # resume from this t (hither for eye rays)
        ("t_max", "<f8"),  # end of the segment (distance to the light for shadow rays)
        ("w", "<f8", 3),  # colour weight carried to the pixel
        ("pixel", "<i8"),  # sample index in the framebuffer
        ("origin", "<i4"),  # gid of the surface the ray leaves (-1 for eye rays)
        ("depth", "u1"),  # tree depth, eye ray = 1
        ("kind", "u1"),  # EYE / REFLECTED / REFRACTED / SHADOW
        ("light", "<u2"),  # light index of a shadow ray
    ]
)

# Material of NFF `f r g b Kd Ks Shine T ior`.
MATERIAL = np.dtype(
    [
        ("rgb", "<f8", 3),
        ("kd", "<f8"),
        ("ks", "<f8"),
        ("shine", "<f8"),
        ("t", "<f8"),
        ("ior", "<f8"),
    ]
)

# Positional light `l x y z [r g b]` (rgb defaults to white; SPD intensity applied by the engine).
LIGHT = np.dtype([("pos", "<f8", 3), ("rgb", "<f8", 3)])

# One table per primitive kind; `gid` is the object's index in the scene file order (unique per
# NFF primitive; the triangles of one fanned patch share it), `mat` indexes the material table.
SPHERE = np.dtype([("gid", "<i4"), ("mat", "<i4"), ("center", "<f8", 3), ("radius", "<f8")])

# Triangles from `p 3`, `pp 3` and fanned `pp n`; `n` holds vertex normals when `smooth`.
TRIANGLE = np.dtype(
    [
        ("gid", "<i4"),
        ("mat", "<i4"),
        ("v", "<f8", (3, 3)),
        ("n", "<f8", (3, 3)),
        ("smooth", "u1"),
    ]
)

# Polygons with more than three vertices: a slice of the scene's vertex table.
POLYGON = np.dtype([("gid", "<i4"), ("mat", "<i4"), ("start", "<i4"), ("count", "<i4")])

# Open cone or cylinder `c bx by bz br ax ay az ar`; negative radii mean inside visible.
CONE = np.dtype(
    [
        ("gid", "<i4"),
        ("mat", "<i4"),
        ("base", "<f8", 3),
        ("base_r", "<f8"),
        ("apex", "<f8", 3),
        ("apex_r", "<f8"),
    ]
)

# One pixel deposit: colour to add to a framebuffer sample (pixel packets carry arrays of these).
DEPOSIT = np.dtype([("pixel", "<i8"), ("rgb", "<f8", 3)])

# One neighbour link's traffic so far, as a node reports it to the host in PROGRESS: rays
# sent to that neighbour and bytes sent on the link (a node has at most four links).
LINK_TRAFFIC = np.dtype([("peer", "<i4"), ("rays", "<i8"), ("bytes", "<i8")])

# Camera elements along the optical axis z (camera frame, metres), listed from the film outward.
CAP, PLANE, THIN_LENS, DIAPHRAGM, ELLIPSOID = 0, 1, 2, 3, 4
ELLIPSE, RECTANGLE, POLYGON_RIM = 0, 1, 2
ELEMENT = np.dtype(
    [
        ("kind", "u1"),  # CAP, PLANE, THIN_LENS, DIAPHRAGM or ELLIPSOID
        ("z", "<f8"),  # vertex (or plane) position on the axis
        ("radius", "<f8"),  # CAP: curvature radius; ELLIPSOID: semi-axis along z; > 0 when
        # the centre lies toward +z
        ("cap_x", "<f8"),  # ELLIPSOID: semi-axis along x
        ("cap_y", "<f8"),  # ELLIPSOID: semi-axis along y
        ("n_after", "<f8"),  # index of refraction on the +z side (CAP, PLANE)
        ("focal", "<f8"),  # THIN_LENS: focal length (negative: diverging)
        ("ax", "<f8"),  # rim / diaphragm half-size along x (ellipse semi-axis, half-width)
        ("ay", "<f8"),  # ... along y
        ("shape", "u1"),  # ELLIPSE, RECTANGLE or POLYGON_RIM (regular N-gon of radius ax)
        ("sides", "<u2"),  # POLYGON_RIM: N
        ("rotation", "<f8"),  # POLYGON_RIM: angle of the first corner, radians
    ]
)

# Every array dtype that may travel in a frame, by the name frames use for it.
WIRE_DTYPES = {
    "ray": RAY,
    "deposit": DEPOSIT,
    "material": MATERIAL,
    "light": LIGHT,
    "sphere": SPHERE,
    "triangle": TRIANGLE,
    "polygon": POLYGON,
    "cone": CONE,
    "f8": np.dtype("<f8"),
    "i8": np.dtype("<i8"),
    "element": ELEMENT,
    "link_traffic": LINK_TRAFFIC,
}
