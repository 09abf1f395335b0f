"""Camera descriptions: a TOML camera file in SI units, or a lens prescription table in the
common text format (the one pbrt and other renderers ship), both turned into ELEMENT records
listed from the film outward.

TOML:   [film] width, height (m), z (optional; default: focused at [focus] distance)
        [[element]] type = "cap" | "ellipsoid" | "plane" | "thin_lens" | "diaphragm", z,
                    radius (cap), semi_axes = [x, y, z] (ellipsoid; z > 0: centre toward the
                    scene, as a cap's radius), n_after, focal, diameter (or semi_x, semi_y),
                    shape = "ellipse" | "rectangle" | "polygon", sides, rotation_deg
        [focus] distance = metres or "infinity"
Table:  one row per surface from the scene side to the film, `#` comments and blank lines
        anywhere: curvature radius, thickness to the next surface, index after it (toward the
        film; 1 or 0 mean air), aperture diameter, all in millimetres; radius 0 is the
        aperture stop. The last row's thickness is the distance to the film; 0 (or left out)
        places the film by focusing, at infinity unless a focus distance is asked for.
Errors name the file and the line (table) or the element (TOML).
"""

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from host.camera.focus import cardinal, dof_from_near_far, dof_from_tolerance, film_for_distance
from meshnode.engine.optics import trace
from protocols import dtypes

TYPES = {
    "cap": dtypes.CAP,
    "ellipsoid": dtypes.ELLIPSOID,
    "plane": dtypes.PLANE,
    "thin_lens": dtypes.THIN_LENS,
    "diaphragm": dtypes.DIAPHRAGM,
}
FULL_FRAME = (0.036, 0.024)  # film size of a lens table unless one is asked for (m)
SHAPES = {
    "ellipse": dtypes.ELLIPSE,
    "rectangle": dtypes.RECTANGLE,
    "polygon": dtypes.POLYGON_RIM,
    "hexagon": dtypes.POLYGON_RIM,
}


class CameraError(ValueError):
    """An impossible or malformed camera, named by file and line or element."""


@dataclass
class Camera:
    elements: np.ndarray  # ELEMENT records, film outward (increasing z)
    film_width: float
    film_height: float
    film_z: float | None = None
    focus_distance: float = math.inf
    source: str = "<memory>"
    notes: list = field(default_factory=list)

    def focused_film_z(self) -> float:
        return (
            self.film_z
            if self.film_z is not None
            else film_for_distance(self.elements, self.focus_distance)
        )


def _element(spec: dict, where: str) -> np.void:
    e = np.zeros(1, dtypes.ELEMENT)[0]
    kind = spec.get("type")
    if kind not in TYPES:
        raise CameraError(f"{where}: type must be one of {sorted(TYPES)}, not {kind!r}")
    e["kind"] = TYPES[kind]
    e["z"] = float(spec.get("z", 0.0))
    e["n_after"] = float(spec.get("n_after", 1.0))
    if "diameter" in spec:
        e["ax"] = e["ay"] = float(spec["diameter"]) / 2
    else:
        e["ax"] = float(spec.get("semi_x", 0.0))
        e["ay"] = float(spec.get("semi_y", e["ax"]))
    if e["ax"] <= 0 or e["ay"] <= 0:
        raise CameraError(f"{where}: needs a positive diameter (or semi_x / semi_y)")
    shape = spec.get("shape", "ellipse")
    if shape not in SHAPES:
        raise CameraError(f"{where}: shape must be one of {sorted(SHAPES)}, not {shape!r}")
    e["shape"] = SHAPES[shape]
    e["sides"] = int(spec.get("sides", 6 if shape == "hexagon" else 0))
    if e["shape"] == dtypes.POLYGON_RIM and e["sides"] < 3:
        raise CameraError(f"{where}: a polygon diaphragm needs sides >= 3")
    e["rotation"] = math.radians(float(spec.get("rotation_deg", 0.0)))
    if kind == "cap":
        e["radius"] = float(spec.get("radius", 0.0))
        if e["radius"] == 0 or abs(e["radius"]) < max(e["ax"], e["ay"]):
            raise CameraError(f"{where}: a cap needs |radius| at least its semi-aperture")
    if kind == "ellipsoid":
        _ellipsoid(e, spec.get("semi_axes"), where)
    if kind == "thin_lens":
        e["focal"] = float(spec.get("focal", 0.0))
        if e["focal"] == 0:
            raise CameraError(f"{where}: a thin lens needs a non-zero focal length")
    if e["n_after"] <= 0:
        raise CameraError(f"{where}: n_after must be positive")
    return e


def _ellipsoid(e: np.void, axes, where: str) -> None:
    """Semi-axes [x, y, z] of an ellipsoidal cap; its rim must lie inside the ellipsoid."""
    if not isinstance(axes, list) or len(axes) != 3:
        raise CameraError(
            f"{where}: an ellipsoid needs semi_axes = [x, y, z] (z > 0: centre toward the scene)"
        )
    x, y, z = (float(v) for v in axes)
    if not (x > 0 and y > 0 and z != 0) or not all(map(math.isfinite, (x, y, z))):
        raise CameraError(f"{where}: semi_axes need x > 0, y > 0 and z != 0, all finite")
    if e["ax"] > x or e["ay"] > y:
        raise CameraError(f"{where}: the rim reaches beyond the ellipsoid's semi-axes")
    e["cap_x"], e["cap_y"], e["radius"] = x, y, z


def read_toml(path, film_size=None) -> Camera:
    """A camera file in SI units; any value of the wrong kind is a CameraError naming it."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CameraError(f"{path}: {e}") from e
    try:
        return _camera_from_toml(path, data, film_size)
    except CameraError:
        raise
    except (AttributeError, TypeError, ValueError, OverflowError) as e:
        raise CameraError(f"{path}: a value of the wrong kind or size ({e})") from e


def _camera_from_toml(path: Path, data: dict, film_size=None) -> Camera:
    specs = data.get("element", [])
    if not specs:
        raise CameraError(f"{path}: no [[element]] tables")
    elements = np.array(
        [_element(s, f"{path}: element {i + 1}") for i, s in enumerate(specs)], dtype=dtypes.ELEMENT
    )
    for i, e in enumerate(elements):
        bad = [
            name
            for name in dtypes.ELEMENT.names
            if dtypes.ELEMENT[name].kind == "f" and not math.isfinite(float(e[name]))
        ]
        if bad:
            raise CameraError(f"{path}: element {i + 1}: {', '.join(bad)} must be finite")
    if np.any(np.diff(elements["z"]) < 0):
        raise CameraError(f"{path}: elements must be listed from the film outward (z increasing)")
    film = data.get("film", {})
    focus = data.get("focus", {}).get("distance", "infinity")
    distance = math.inf if focus == "infinity" else float(focus)
    if not distance > 0:
        raise CameraError(f"{path}: [focus] distance must be positive metres or 'infinity'")
    width, height = film_size or (
        float(film.get("width", FULL_FRAME[0])),
        float(film.get("height", FULL_FRAME[1])),
    )
    if not (0 < width < math.inf and 0 < height < math.inf):
        raise CameraError(f"{path}: [film] width and height must be positive and finite")
    film_z = film.get("z")
    if film_z is not None and not math.isfinite(float(film_z)):
        raise CameraError(f"{path}: [film] z must be finite")
    cam = Camera(elements, width, height, film_z, distance, str(path))
    return validate(cam)


def read_table(path, film_size=None) -> Camera:
    """A lens prescription table (millimetres, scene side first), as the common format ships
    it; `film_size` (width, height) in metres, full frame by default."""
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError as e:
        raise CameraError(f"{path}: not a text file ({e})") from e
    rows = [
        row
        for number, line in enumerate(text.splitlines(), 1)
        if (row := _table_row(path, number, line)) is not None
    ]
    if not rows:
        raise CameraError(f"{path}: no lens rows")
    for number, _, thick, *_ in rows[:-1]:
        if thick is None:
            raise CameraError(
                f"{path}:{number}: expected radius thickness index aperture "
                "(only the last row may leave out its thickness)"
            )
    # Positions from the front vertex (z = 0) toward the film (negative z), in metres.
    z, out = 0.0, []
    for i, (number, radius, thick, _, aperture) in enumerate(rows):
        before = 1.0 if i == 0 else (rows[i - 1][3] or 1.0)  # medium on the scene side
        e = np.zeros(1, dtypes.ELEMENT)[0]
        e["z"], e["ax"] = z, aperture / 2000
        e["ay"], e["n_after"] = e["ax"], before
        if radius == 0:
            e["kind"] = dtypes.DIAPHRAGM
        else:
            e["kind"] = dtypes.CAP
            e["radius"] = -radius / 1000  # the table's +z points at the film, ours at the scene
            if abs(e["radius"]) < e["ax"]:
                raise CameraError(f"{path}:{number}: |radius| is smaller than half the aperture")
        out.append(e)
        z -= (thick or 0.0) / 1000
    elements = np.array(out[::-1], dtype=dtypes.ELEMENT)
    # The medium on the film side of the film-most surface must be air.
    if rows[-1][3] not in (0.0, 1.0):
        raise CameraError(f"{path}:{rows[-1][0]}: the last surface must leave the light in air")
    film_z = z if rows[-1][2] else None  # thickness 0 or left out: focus places the film
    width, height = film_size or FULL_FRAME
    notes = [] if film_z is not None else ["film placed by focusing (last thickness 0)"]
    cam = Camera(elements, width, height, film_z, math.inf, str(path), notes)
    return validate(cam)


def _table_row(path: Path, number: int, line: str):
    """(line, radius, thickness or None, index, aperture) of one table line; None for a
    comment or blank line; a CameraError naming the line for anything else."""
    words = line.split("#", 1)[0].split()
    if not words:
        return None
    try:
        values = [float(w) for w in words]
    except ValueError:
        bad = next(w for w in words if not _is_number(w))
        raise CameraError(
            f"{path}:{number}: {bad!r} is not a number (expected radius "
            "thickness index aperture, in mm)"
        ) from None
    if len(values) == 3:  # the last row may leave out its thickness
        values.insert(1, None)
    if len(values) != 4:
        raise CameraError(
            f"{path}:{number}: expected 4 numbers (radius thickness index "
            f"aperture, in mm), got {len(values)}"
        )
    radius, thick, index, aperture = values
    if not all(math.isfinite(v) for v in values if v is not None):
        raise CameraError(f"{path}:{number}: every value must be finite")
    if aperture <= 0:
        raise CameraError(f"{path}:{number}: the aperture diameter must be positive")
    if thick is not None and thick < 0:
        raise CameraError(f"{path}:{number}: the thickness must be >= 0")
    if index != 0 and index < 1:
        raise CameraError(
            f"{path}:{number}: index {index:g} is neither air (1 or 0) nor a glass (> 1)"
        )
    return number, radius, thick, index, aperture


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def read_camera(path, film_size=None) -> Camera:
    """A TOML camera file or a lens table, on a film of `film_size` (width, height) metres
    if given (else the file's, or full frame for a table)."""
    if film_size is not None and not all(0 < v < 1e3 for v in film_size):
        raise CameraError(f"{path}: the film size must be positive, got {film_size}")
    if str(path).endswith(".toml"):
        return read_toml(path, film_size)
    return read_table(path, film_size)


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
