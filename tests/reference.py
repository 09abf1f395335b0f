"""An independent brute-force first-hit tracer in NumPy, for checking the engine.

Written from the geometry, not from the engine's code: each object kind is solved in its own
frame (spheres by the quadratic, triangles by barycentrics from a linear solve, polygons by a
winding number in an in-plane orthonormal basis, cones in a local frame), vectorised over rays,
looping over objects. Slow, obvious and separate.
"""

import numpy as np

from protocols.scene import SceneData


def _transmits(scene: SceneData, mats: np.ndarray) -> np.ndarray:
    return scene.materials["t"][mats] > 0


def _sphere(o, d, c, r, two_sided, t_min):
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    disc = b * b - (np.einsum("ij,ij->i", oc, oc) - r * r)
    ok = disc >= 0
    h = np.sqrt(np.where(ok, disc, 0))
    near, far = -b - h, -b + h
    t = np.full(len(o), np.inf)
    if r > 0 or two_sided:  # the outside is visible: the entering root
        t = np.where(ok & (near > t_min), near, t)
    if r < 0 or two_sided:  # the inside is visible: the leaving root
        t = np.where(ok & ~(t < np.inf) & (far > t_min), far, t)
    return t


def _triangle(o, d, v, t_min):
    e1, e2 = v[1] - v[0], v[2] - v[0]
    t = np.full(len(o), np.inf)
    for i in range(len(o)):
        m = np.column_stack([e1, e2, -d[i]])
        if abs(np.linalg.det(m)) < 1e-300:
            continue
        a, b, tt = np.linalg.solve(m, o[i] - v[0])
        if a >= 0 and b >= 0 and a + b <= 1 and tt > t_min:
            t[i] = tt
    return t


def _polygon(o, d, v, t_min):
    n = np.zeros(3)
    for k in range(len(v)):  # Newell normal
        a, b = v[k], v[(k + 1) % len(v)]
        n += np.cross(a, b)
    n /= np.linalg.norm(n)
    u = v[1] - v[0]
    u -= n * (u @ n)
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    q = np.column_stack([(v - v[0]) @ u, (v - v[0]) @ w])
    dn = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((v[0] - o) @ n) / dn
    t = np.where((dn != 0) & (t > t_min), t, np.inf)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d - v[0]
    px, py = p @ u, p @ w
    # Winding number of the polygon around each point (non-zero = inside for simple polygons).
    ang = np.zeros(len(o))
    for k in range(len(q)):
        ax, ay = q[k, 0] - px, q[k, 1] - py
        bx, by = q[(k + 1) % len(q), 0] - px, q[(k + 1) % len(q), 1] - py
        ang += np.arctan2(ax * by - ay * bx, ax * bx + ay * by)
    inside = np.abs(ang) > np.pi
    return np.where(inside, t, np.inf)


def _cone(o, d, base, br, apex, ar, two_sided, t_min):
    axis = apex - base
    length = np.linalg.norm(axis)
    z = axis / length
    x = np.cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z])  # rows: local axes
    lo = (o - base) @ rot.T
    ld = d @ rot.T
    r0, r1 = abs(br), abs(ar)
    k = (r1 - r0) / length
    # x^2 + y^2 = (r0 + k z)^2
    a = ld[:, 0] ** 2 + ld[:, 1] ** 2 - (k * ld[:, 2]) ** 2
    b = 2 * (lo[:, 0] * ld[:, 0] + lo[:, 1] * ld[:, 1] - k * ld[:, 2] * (r0 + k * lo[:, 2]))
    c = lo[:, 0] ** 2 + lo[:, 1] ** 2 - (r0 + k * lo[:, 2]) ** 2
    t = np.full(len(o), np.inf)
    for i in range(len(o)):
        roots = np.roots([a[i], b[i], c[i]]) if abs(a[i]) > 1e-14 else [-c[i] / b[i]]
        for rt in sorted(float(np.real(x)) for x in roots if abs(np.imag(x)) < 1e-12):
            if rt <= t_min:
                continue
            p = lo[i] + rt * ld[i]
            if not 0 <= p[2] <= length:
                continue
            grad = np.array([p[0], p[1], -k * (r0 + k * p[2])])
            outside = grad @ ld[i] < 0
            if two_sided or outside == (br >= 0 and ar >= 0):
                t[i] = rt
                break
    return t


def first_hits(scene: SceneData, o, d, t_min=0.0):
    """Nearest hit distance and gid per ray, testing every object."""
    o = np.asarray(o, float).reshape(-1, 3)
    d = np.asarray(d, float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1)[:, None]
    best = np.full(len(o), np.inf)
    gid = np.full(len(o), -1)

    def keep(t, g):
        nonlocal best, gid
        closer = t < best
        best = np.where(closer, t, best)
        gid = np.where(closer, g, gid)

    for s in scene.spheres:
        two = bool(_transmits(scene, s["mat"]))
        keep(_sphere(o, d, s["center"], s["radius"], two, t_min), s["gid"])
    for tr in scene.triangles:
        keep(_triangle(o, d, tr["v"], t_min), tr["gid"])
    for p in scene.polygons:
        v = scene.vertices[p["start"] : p["start"] + p["count"]]
        keep(_polygon(o, d, v, t_min), p["gid"])
    for c in scene.cones:
        two = bool(_transmits(scene, c["mat"]))
        keep(_cone(o, d, c["base"], c["base_r"], c["apex"], c["apex_r"], two, t_min), c["gid"])
    return best, gid
