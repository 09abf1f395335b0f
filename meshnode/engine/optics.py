"""Rays through a camera's elements (DESIGN.md 7), batched: refracting spherical and
ellipsoidal caps and planes with rims, ideal thin lenses, diaphragms of ellipse, rectangle or
regular N-gon shape.

Camera frame: optical axis z, film on the -z side, elements listed from the film outward (the
ELEMENT dtype in `protocols`). `through` moves rays in place element by element, forward
(+z, film to scene) or backward (scene to film), and reports which survive: a ray outside a
rim or diaphragm, or totally reflected inside glass, is lost (vignetting), not an error.
"""

import math

import numpy as np

from meshnode.engine.jit import kernel
from meshnode.engine.shade import refract
from protocols.dtypes import CAP, ELLIPSE, ELLIPSOID, PLANE, RECTANGLE, THIN_LENS


@kernel
def inside_rim(x, y, ax, ay, shape, sides, rotation):
    """Is (x, y) within the element's rim or diaphragm opening?"""
    if shape == ELLIPSE:
        return (x / ax) ** 2 + (y / ay) ** 2 <= 1.0
    if shape == RECTANGLE:
        return abs(x) <= ax and abs(y) <= ay
    # Regular N-gon of circumradius ax: inside every edge's half-plane.
    apothem = ax * math.cos(math.pi / sides)
    for k in range(sides):
        a = rotation + (2 * k + 1) * math.pi / sides  # direction of edge k's normal
        if x * math.cos(a) + y * math.sin(a) > apothem:
            return False
    return True


@kernel
def through(o, d, elements, backward, alive):
    """Carry rays (o, d: (n, 3), unit d) through every element; clears alive[i] when lost."""
    m = elements.shape[0]
    for i in range(o.shape[0]):
        if not alive[i]:
            continue
        ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        for step in range(m):
            j = m - 1 - step if backward else step
            e = elements[j]
            # Media on either side along the direction of travel.
            n_fwd_before = 1.0 if j == 0 else elements[j - 1].n_after
            n1 = n2 = 1.0
            refracting = e.kind == CAP or e.kind == PLANE or e.kind == ELLIPSOID
            if refracting:
                n_after = e.n_after
                n1, n2 = (n_after, n_fwd_before) if backward else (n_fwd_before, n_after)
            if e.kind == CAP:
                cz = e.z + e.radius
                wz = oz - cz
                b = ox * dx + oy * dy + wz * dz
                c = ox * ox + oy * oy + wz * wz - e.radius * e.radius
                disc = b * b - c
                if disc < 0.0:
                    alive[i] = False
                    break
                h = math.sqrt(disc)
                # The cap is the half of the sphere on the vertex side of its centre.
                t = -b - h
                if (oz + t * dz - cz) * e.radius > 0.0:
                    t = -b + h
            elif e.kind == ELLIPSOID:
                # In coordinates scaled by the semi-axes the ellipsoid is the unit sphere.
                cz = e.z + e.radius
                sz = abs(e.radius)
                ux, uy, uz = ox / e.cap_x, oy / e.cap_y, (oz - cz) / sz
                vx, vy, vz = dx / e.cap_x, dy / e.cap_y, dz / sz
                a = vx * vx + vy * vy + vz * vz
                b = ux * vx + uy * vy + uz * vz
                c = ux * ux + uy * uy + uz * uz - 1.0
                disc = b * b - a * c
                if disc < 0.0:
                    alive[i] = False
                    break
                h = math.sqrt(disc)
                # The cap is the half on the vertex side of the centre, as for a sphere.
                t = (-b - h) / a
                if (oz + t * dz - cz) * e.radius > 0.0:
                    t = (-b + h) / a
            else:
                if dz == 0.0:
                    alive[i] = False
                    break
                t = (e.z - oz) / dz
            px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
            if not inside_rim(px, py, e.ax, e.ay, e.shape, e.sides, e.rotation):
                alive[i] = False
                break
            if refracting:
                if e.kind == CAP:
                    nx, ny, nz = px / e.radius, py / e.radius, (pz - e.z - e.radius) / e.radius
                elif e.kind == ELLIPSOID:  # the gradient of the implicit form, normalised
                    nx = px / (e.cap_x * e.cap_x)
                    ny = py / (e.cap_y * e.cap_y)
                    nz = (pz - e.z - e.radius) / (e.radius * e.radius)
                    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
                    nx, ny, nz = nx / ln, ny / ln, nz / ln
                else:
                    nx, ny, nz = 0.0, 0.0, 1.0
                if nx * dx + ny * dy + nz * dz > 0.0:  # face the incoming ray
                    nx, ny, nz = -nx, -ny, -nz
                ok, dx, dy, dz = refract(dx, dy, dz, nx, ny, nz, n1 / n2)
                if not ok:
                    alive[i] = False
                    break
            elif e.kind == THIN_LENS:
                # Slopes change by -h / f in the direction of travel.
                s = 1.0 if dz > 0.0 else -1.0
                u = dx / abs(dz) - px / e.focal
                v = dy / abs(dz) - py / e.focal
                ln = math.sqrt(u * u + v * v + 1.0)
                dx, dy, dz = u / ln, v / ln, s / ln
            ox, oy, oz = px, py, pz
        o[i, 0], o[i, 1], o[i, 2] = ox, oy, oz
        d[i, 0], d[i, 1], d[i, 2] = dx, dy, dz


def trace(elements: np.ndarray, o, d, backward: bool = False):
    """Copies of (o, d) after the elements, and the survivors' mask."""
    o = np.array(o, dtype=np.float64, ndmin=2)
    d = np.array(d, dtype=np.float64, ndmin=2)
    d /= np.linalg.norm(d, axis=1)[:, None]
    alive = np.ones(len(o), dtype=np.bool_)
    through(o, d, elements, backward, alive)
    return o, d, alive


def paraxial_height(elements: np.ndarray) -> float:
    """A ray height small against every aperture: paraxial, yet far from round-off."""
    return 1e-4 * float(np.min(np.minimum(elements["ax"], elements["ay"])))
