"""The camera as the host holds it: ELEMENT records listed from the film outward, its film
and focus (`Camera`); the checks an impossible camera fails before any tracing (`validate`),
the figures a photographer asks of it (`describe`), and the camera stopped and focused as
asked (`with_f_number`, `focused`). Lens files are read into it by `host.camera.lensfile`.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from host.camera.focus import cardinal, dof_from_near_far, dof_from_tolerance, film_for_distance
from meshnode.engine.optics import trace
from protocols import dtypes


class CameraError(ValueError):
    """An impossible or malformed camera, named by file and line or element."""


@dataclass
class Camera:
    """A camera of real optics: its elements, film and focus; `source` names it in errors."""

    elements: np.ndarray  # ELEMENT records, film outward (increasing z)
    film_width: float
    film_height: float
    film_z: float | None = None
    focus_distance: float = math.inf
    source: str = "<memory>"
    notes: list = field(default_factory=list)

    def focused_film_z(self) -> float:
        """Where the film sits: the file's place, else where the focus distance puts it."""
        return (
            self.film_z
            if self.film_z is not None
            else film_for_distance(self.elements, self.focus_distance)
        )


def validate(cam: Camera) -> Camera:
    """Impossible cameras fail before any tracing: film beyond the first element, no paraxial
    ray through the stack, a focus distance inside the lens."""
    first = float(cam.elements["z"].min())
    try:
        card = cardinal(cam.elements)
    except ValueError as e:
        raise CameraError(f"{cam.source}: {e}") from e
    if cam.film_z is not None and cam.film_z >= first:
        raise CameraError(
            f"{cam.source}: the film (z={cam.film_z}) is not behind the first element (z={first})"
        )
    if card["effective_focal_length"] <= 0:
        raise CameraError(f"{cam.source}: the lens does not form a real image (EFL <= 0)")
    if cam.focus_distance <= 0:
        raise CameraError(f"{cam.source}: focus distance must be in front of the lens")
    try:
        film_z = cam.focused_film_z()
    except ValueError as e:
        raise CameraError(f"{cam.source}: {e}") from e
    if film_z >= first:
        raise CameraError(
            f"{cam.source}: focused at {cam.focus_distance:g} m, the film "
            f"(z={film_z:.6g}) would not be behind the first element "
            f"(z={first})"
        )
    return cam


def entrance_pupil_radius(elements: np.ndarray) -> float:
    """Largest height of a scene-side ray parallel to the axis that reaches the film side
    (bisection): the entrance pupil seen from infinity."""
    front = float(elements["z"].max()) + 1.0
    lo, hi = 0.0, float(elements["ax"].max()) * 4
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        _, _, alive = trace(elements, [(mid, 0.0, front)], [(0.0, 0.0, -1.0)], backward=True)
        lo, hi = (mid, hi) if alive[0] else (lo, mid)
    return lo


def describe(cam: Camera, focus: float | None = None, coc: float | None = None) -> dict:
    """The figures a photographer asks of a lens."""
    card = cardinal(cam.elements)
    efl = card["effective_focal_length"]
    pupil = entrance_pupil_radius(cam.elements)
    n = efl / (2 * pupil)
    distance = cam.focus_distance if focus is None else focus
    film_z = (
        cam.film_z
        if (cam.film_z is not None and focus is None)
        else film_for_distance(cam.elements, distance)
    )
    image = card["rear_principal_plane_z"] - film_z
    diag = math.hypot(cam.film_width, cam.film_height)
    c = coc if coc is not None else diag / 1500
    return {
        "effective_focal_length_m": efl,
        "front_principal_plane_z_m": card["front_principal_plane_z"],
        "rear_principal_plane_z_m": card["rear_principal_plane_z"],
        "front_focal_distance_m": card["front_focal_distance"],
        "back_focal_distance_m": card["back_focal_distance"],
        "entrance_pupil_diameter_m": 2 * pupil,
        "f_number": n,
        "focus_distance_m": distance,
        "film_z_m": film_z,
        "field_of_view_deg": {
            "horizontal": 2 * math.degrees(math.atan(cam.film_width / (2 * image))),
            "vertical": 2 * math.degrees(math.atan(cam.film_height / (2 * image))),
            "diagonal": 2 * math.degrees(math.atan(diag / (2 * image))),
        },
        "circle_of_confusion_m": c,
        "hyperfocal_distance_m": efl * efl / (n * c),
    }


def with_f_number(cam: Camera, n: float) -> Camera:
    """The camera stopped to f-number `n`: its diaphragms scaled (a circular one added in the
    front element's plane if it has none) so the entrance pupil is EFL / n across."""
    efl = cardinal(cam.elements)["effective_focal_length"]
    want = efl / (2.0 * n)
    elements = cam.elements.copy()
    stops = np.flatnonzero(elements["kind"] == dtypes.DIAPHRAGM)
    if len(stops) == 0:
        stop = np.zeros(1, dtypes.ELEMENT)
        stop["kind"], stop["shape"] = dtypes.DIAPHRAGM, dtypes.ELLIPSE
        front = int(np.argmax(elements["z"]))
        stop["z"] = elements["z"][front]
        stop["ax"] = stop["ay"] = elements["ax"][front]
        elements = np.concatenate([elements[:front], stop, elements[front:]])
        stops = np.array([front])
    for _ in range(3):  # the pupil is linear in the stop's size while the stop limits it
        scale = want / entrance_pupil_radius(elements)
        elements["ax"][stops] *= scale
        elements["ay"][stops] *= scale
    got = entrance_pupil_radius(elements)
    if abs(got - want) > 1e-3 * want:
        raise CameraError(
            f"{cam.source}: the lens opens only to f/{efl / (2 * got):.2f}, not f/{n:.2f}"
        )
    out = Camera(
        elements,
        cam.film_width,
        cam.film_height,
        cam.film_z,
        cam.focus_distance,
        cam.source,
        [*cam.notes, f"stopped to f/{n:.3g}"],
    )
    return out


def default_coc(cam: Camera) -> float:
    """The usual largest circle of confusion: the film diagonal / 1500."""
    return math.hypot(cam.film_width, cam.film_height) / 1500


def focused(
    cam: Camera,
    focus=None,
    near=None,
    far=None,
    tolerance=None,
    coc=None,
    autofocus=None,
    f_number=None,
) -> Camera:
    """The camera focused and stopped as asked: `focus` in metres, "infinity" or "auto"
    (`autofocus()` gives the distance: a probe pass through the scene); `near`/`far`: the
    depth of field, focus and f-number chosen for it; `tolerance`: focus +- tolerance sharp;
    `f_number`: the stop scaled to it (not with near/far or tolerance, which choose it)."""
    efl = cardinal(cam.elements)["effective_focal_length"]
    c = coc or default_coc(cam)
    out = cam
    if f_number is not None:
        if near is not None or far is not None or tolerance is not None:
            raise CameraError(
                f"{cam.source}: an f-number is chosen by the depth of field "
                "(near/far or tolerance); give one or the other"
            )
        out = cam = with_f_number(cam, f_number)
    try:
        if near is not None or far is not None:
            if near is None or focus is not None or tolerance is not None:
                raise ValueError("depth of field from near/far takes no focus or tolerance")
            distance, n = dof_from_near_far(efl, c, near, math.inf if far is None else far)
            out = with_f_number(cam, n)
        else:
            if focus == "auto":
                distance = autofocus()
            elif focus == "infinity":
                distance = math.inf
            else:
                distance = cam.focus_distance if focus is None else float(focus)
            if tolerance is not None:
                if math.isinf(distance):
                    raise ValueError("a focus tolerance needs a finite focus distance")
                out = with_f_number(cam, dof_from_tolerance(efl, c, distance, tolerance))
    except ValueError as e:
        raise CameraError(f"{cam.source}: {e}") from e
    if focus is None and near is None and far is None and cam.film_z is not None:
        return out  # the file fixes the film
    out = Camera(
        out.elements,
        out.film_width,
        out.film_height,
        None,
        distance,
        out.source,
        [*out.notes, f"focused at {distance:.4g} m"],
    )
    return validate(out)
