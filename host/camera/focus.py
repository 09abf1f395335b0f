"""What a photographer asks of a lens, computed by tracing paraxial rays through its elements:
effective focal length, principal planes, back focal distance, and the film position that
focuses a given distance (bisection on the film position, DESIGN.md 7).
"""

import math

import numpy as np

from meshnode.engine.optics import paraxial_height, trace


def cardinal(elements: np.ndarray) -> dict:
    """EFL and the focal and principal points on both sides, from rays parallel to the axis
    at a paraxial height: one coming from the scene, one from the film."""
    h = paraxial_height(elements)
    last = float(elements["z"].max())
    front = last + 1.0
    o, d, alive = trace(elements, [(h, 0.0, front)], [(0.0, 0.0, -1.0)], backward=True)
    if not alive[0]:
        raise ValueError("a paraxial ray from the scene does not reach the film")
    slope = d[0, 0] / abs(d[0, 2])  # change of height per unit distance toward the film
    if slope == 0.0:
        raise ValueError("the element stack has no power (afocal)")
    focal_z = o[0, 2] + o[0, 0] / slope  # where the ray meets the axis, film side
    efl = -h / slope
    first = float(elements["z"].min())
    # The same from the film side: a ray parallel to the axis leaving toward the scene.
    o, d, alive = trace(elements, [(h, 0.0, first - 1.0)], [(0.0, 0.0, 1.0)])
    if not alive[0]:
        raise ValueError("a paraxial ray from the film does not reach the scene")
    front_focal_z = o[0, 2] - o[0, 0] * d[0, 2] / d[0, 0]
    return {
        "effective_focal_length": efl,
        "back_focal_point_z": focal_z,
        "rear_principal_plane_z": focal_z + efl,
        "back_focal_distance": first - focal_z,
        "front_focal_point_z": front_focal_z,
        "front_principal_plane_z": front_focal_z - efl,
        "front_focal_distance": front_focal_z - last,
    }


def _miss(elements, film_z: float, object_z: float, h: float) -> float:
    """Height at the object plane of a ray from the film's centre through the lens at height
    h: zero when the film is in focus for that plane; its sign says which side we are on."""
    first = float(elements["z"].min())
    o, d, alive = trace(elements, [(0.0, 0.0, film_z)], [(h, 0.0, first - film_z)])
    if not alive[0]:
        raise ValueError("the focusing ray is blocked")
    return o[0, 0] + (object_z - o[0, 2]) * d[0, 0] / d[0, 2]


def film_for_distance(elements: np.ndarray, distance: float) -> float:
    """Film z that focuses points `distance` in front of the last element (inf: infinity)."""
    if math.isinf(distance):
        return cardinal(elements)["back_focal_point_z"]
    last, first = float(elements["z"].max()), float(elements["z"].min())
    if distance <= 0 or math.isnan(distance):
        raise ValueError(f"focus distance {distance} m is not in front of the lens")
    card = cardinal(elements)
    efl = abs(card["effective_focal_length"])
    h = paraxial_height(elements)
    object_z = last + distance
    # A near object images beyond the focal point: between it and far behind.
    hi = min(card["back_focal_point_z"], first - 1e-9 * efl)
    lo = hi - 1e4 * efl
    g_lo, g_hi = _miss(elements, lo, object_z, h), _miss(elements, hi, object_z, h)
    if g_lo * g_hi > 0:
        raise ValueError(f"no film position focuses {distance} m (inside the focal length?)")
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        g = _miss(elements, mid, object_z, h)
        if g == 0.0 or hi - lo <= 1e-15 * max(1.0, abs(mid)):
            return mid
        if (g < 0) == (g_lo < 0):
            lo, g_lo = mid, g
        else:
            hi = mid
    return 0.5 * (lo + hi)


def dof_from_near_far(efl: float, coc: float, near: float, far: float) -> tuple[float, float]:
    """Focus distance and f-number that keep [near, far] within a circle of confusion `coc`
    (thin-lens law): 1/near + 1/far = 2/s, and N from near = s f^2 / (f^2 + N c (s - f))."""
    if not 0 < near < far:
        raise ValueError(f"depth of field needs 0 < near < far, got near={near} far={far}")
    s = 2.0 / (1.0 / near + (0.0 if math.isinf(far) else 1.0 / far))
    if s <= efl or near <= efl:
        raise ValueError(f"near distance {near} m is inside the focal length {efl} m")
    inv_far = 0.0 if math.isinf(far) else 1.0 / far
    n = s * efl * efl * (1.0 / near - inv_far) / (2.0 * coc * (s - efl))
    return s, n


def dof_from_tolerance(efl: float, coc: float, distance: float, tolerance: float) -> float:
    """f-number that keeps distance +- tolerance sharp when focused at `distance`; the near
    side is the binding one (depth of field is deeper behind the focus than in front)."""
    if not 0 < tolerance < distance or distance <= efl:
        raise ValueError(
            f"depth of field needs 0 < tolerance < distance and a distance beyond "
            f"the focal length; got {distance} m +- {tolerance} m"
        )
    return efl * efl * tolerance / (coc * (distance - efl) * (distance - tolerance))


def circle_of_confusion(efl: float, n: float, focus: float, distance: float) -> float:
    """Blur diameter on the film of a point at `distance` when focused at `focus` (DESIGN 7)."""
    return abs(efl * efl * (focus / distance - 1.0) / (n * (focus - efl)))
