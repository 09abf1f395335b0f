"""Lens files: a TOML camera file in SI units, or a lens prescription table in the common
text format (the one pbrt and other renderers ship), both read into a `Camera` of ELEMENT
records listed from the film outward. Reading is kept apart from the camera record so a
camera built in code needs no file.

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
from pathlib import Path

import numpy as np

from host.camera.lens import Camera, CameraError, validate
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


def _element(spec: dict, where: str) -> np.void:
    """One [[element]] table as an ELEMENT record; a CameraError at `where` if impossible."""
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
    """The camera of a parsed TOML file: elements in order and finite, film and focus."""
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
    """Whether float() takes `word`: finds the word to name in an error."""
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
