"""What a bare mesh lacks (view, resolution, background, lights, material), from a small TOML
file beside it, in NFF's terms:

    resolution = [512, 512]
    background = [0, 0, 0]
    [view]            # any of: from, at, up, angle (degrees, as NFF), hither
    from = [0, 0, 5]
    [[light]]         # NFF `l x y z r g b`; colour optional (white)
    position = [1, 4, 3]
    [material]        # NFF `f r g b Kd Ks Shine T ior`; every key optional
    colour = [1, 0.5, 0.25]
    kd = 0.8

and defaults for whatever it leaves out: a camera framing the scene's bounding box, one light
above and beside the eye, a grey matte material. The TOML is read by the standard library's
tomllib; errors name the file and line.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from host.scene.errors import SceneError
from protocols.scene import View

DEFAULT_ANGLE = 45.0
DEFAULT_SIZE = 512  # pixels each way, as NFF's view without `resolution`
DEFAULT_MATERIAL = {
    "colour": (0.8, 0.8, 0.8),
    "kd": 1.0,
    "ks": 0.0,
    "shine": 0.0,
    "t": 0.0,
    "ior": 1.0,
}
_TOP = {"resolution", "background", "view", "light", "material"}
_VIEW = {"from": 3, "at": 3, "up": 3, "angle": 1, "hither": 1}
_LIGHT = {"position": 3, "colour": 3, "color": 3}
_MATERIAL = {"colour": 3, "color": 3, "kd": 1, "ks": 1, "shine": 1, "t": 1, "ior": 1}


@dataclass
class Settings:
    """The settings a file gave; None (or empty) where it gave none."""

    source: str | None = None
    resolution: tuple[int, int] | None = None
    background: tuple[float, float, float] | None = None
    view: dict = field(default_factory=dict)  # any of _VIEW's keys
    lights: list = field(default_factory=list)  # (position, rgb) pairs
    material: dict | None = None  # any of _MATERIAL's keys, `color` as `colour`
    view_line: int = 1

    def size(self) -> tuple[int, int]:
        return self.resolution or (DEFAULT_SIZE, DEFAULT_SIZE)


def beside(path: Path) -> Path | None:
    """The settings file that goes with a scene file: same stem, .toml, if it exists."""
    toml = path.with_suffix(".toml")
    return toml if toml.is_file() else None


def read_settings(path, allowed=_TOP) -> Settings:
    """Read and check a settings TOML; `allowed` top-level keys (Inventor takes fewer)."""
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as e:
        raise SceneError(source, 1, f"cannot read settings: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise SceneError(source, 1, f"settings are not UTF-8 text: {e.reason}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        m = re.search(r"\(at line (\d+), column \d+\)", str(e))
        line = int(m.group(1)) if m else 1
        raise SceneError(source, line, f"TOML: {str(e).split(' (at line')[0]}") from None
    return _Check(source, text, allowed).settings(data)


class _Check:
    """Checks the parsed TOML; each error names the line its key is on."""

    def __init__(self, source: str, text: str, allowed):
        self.source, self.lines, self.allowed = source, text.split("\n"), allowed

    def line(self, table: str | None, key: str | None = None, nth: int = 0) -> int:
        """Line of `key` in table `table` (`nth` of an array of tables), or of the table."""
        current, seen = None, -1
        for i, raw in enumerate(self.lines, 1):
            s = raw.split("#")[0].strip()
            head = re.fullmatch(r"\[\[?\s*([A-Za-z_]+)\s*\]?\]", s)
            if head:
                current = head.group(1)
                seen += current == table
                if key is None and current == table and seen == nth:
                    return i
                continue
            if key and re.match(rf"{re.escape(key)}\s*=", s):
                if current == table and (table is None or seen == nth):
                    return i
        if table is None and key is not None:  # a top-level key written as a [table]
            return self.line(key)
        return 1

    def fail(self, table, key, what, nth=0):
        raise SceneError(self.source, self.line(table, key, nth), what)

    def numbers(self, table, key, value, k, nth=0) -> tuple[float, ...]:
        """`k` finite numbers (one number, or a list of k)."""
        vals = value if isinstance(value, list) else [value]
        ok = len(vals) == k and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in vals
        )
        if not ok or not all(math.isfinite(v) for v in vals):
            want = "a number" if k == 1 else f"a list of {k} numbers"
            self.fail(table, key, f"{key} must be {want}, got {value!r}", nth)
        return tuple(float(v) for v in vals)

    def known(self, table, data: dict, keys, nth=0) -> None:
        if not isinstance(data, dict):
            self.fail(None, table, f"{table} must be a table", nth)
        for k in data:
            if k not in keys:
                where = f"[{table}]" if table else "the settings"
                self.fail(
                    table,
                    k,
                    f"unknown key {k!r} in {where} (known: {', '.join(sorted(keys))})",
                    nth,
                )

    def settings(self, data: dict) -> Settings:
        self.known(None, data, self.allowed)
        out = Settings(source=self.source)
        if "resolution" in data:
            res = data["resolution"]
            if not (
                isinstance(res, list)
                and len(res) == 2
                and all(type(v) is int and 0 < v <= 32768 for v in res)
            ):
                self.fail(
                    None,
                    "resolution",
                    f"resolution must be two whole numbers from 1 to 32768, got {res!r}",
                )
            out.resolution = (res[0], res[1])
        if "background" in data:
            out.background = self.numbers(None, "background", data["background"], 3)
        if "view" in data:
            view = data["view"]
            self.known("view", view, _VIEW)
            out.view = {k: self.numbers("view", k, v, _VIEW[k]) for k, v in view.items()}
            out.view_line = self.line("view")
        lights = data.get("light", [])
        if not isinstance(lights, list):
            self.fail(None, "light", "lights are [[light]] tables")
        for n, light in enumerate(lights):
            self.known("light", light, _LIGHT, n)
            if "position" not in light:
                self.fail("light", None, "[[light]] needs a position", n)
            rgb = self.colour("light", light, n) or (1.0, 1.0, 1.0)
            out.lights.append((self.numbers("light", "position", light["position"], 3, n), rgb))
        if "material" in data:
            out.material = self.material(data["material"])
        return out

    def colour(self, table, data: dict, nth=0):
        if "colour" in data and "color" in data:
            self.fail(table, "color", "give colour or color, not both", nth)
        for key in ("colour", "color"):
            if key in data:
                rgb = self.numbers(table, key, data[key], 3, nth)
                if min(rgb) < 0:
                    self.fail(table, key, f"{key} must not be negative", nth)
                return rgb
        return None

    def material(self, mat: dict) -> dict:
        self.known("material", mat, _MATERIAL)
        out = {
            k: self.numbers("material", k, v, 1)[0]
            for k, v in mat.items()
            if k not in ("colour", "color")
        }
        for k, v in out.items():
            if v < 0:
                self.fail("material", k, f"material: negative {k}")
        rgb = self.colour("material", mat)
        if rgb is not None:
            out["colour"] = rgb
        if out.get("t", 0.0) > 0 and out.get("ior", 1.0) == 0:
            self.fail("material", "ior", "material: ior must be positive for a transmitter")
        return out


def material_row(given: dict | None) -> tuple:
    """NFF's eight material numbers: the given keys over the defaults."""
    m = {**DEFAULT_MATERIAL, **(given or {})}
    return (*m["colour"], m["kd"], m["ks"], m["shine"], m["t"], m["ior"])


def framing(lo, hi, settings: Settings) -> View:
    """The settings' view, its missing keys filled so that the camera frames the box [lo, hi]:
    looking at the box centre from in front (+z), a little right and above, far enough that
    the box's bounding sphere fits the field of view."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2 or 1.0
    v = settings.view
    angle = v.get("angle", (DEFAULT_ANGLE,))[0]
    at = np.asarray(v.get("at", centre), float)
    if "from" in v:
        eye = np.asarray(v["from"], float)
    else:
        half = math.radians(min(max(angle, 1.0), 170.0)) / 2
        eye = at + _unit((0.3, 0.4, 1.0)) * (
            radius / math.sin(half) * 1.05 + float(np.linalg.norm(at - centre))
        )
    width, height = settings.size()
    try:
        return View(
            eye=_floats(eye),
            at=_floats(at),
            up=_floats(v.get("up", (0, 1, 0))),
            angle=angle,
            hither=v.get("hither", (0.0,))[0],
            width=width,
            height=height,
        )
    except ValueError as e:
        raise SceneError(settings.source or "<defaults>", settings.view_line, str(e)) from None


def default_light(lo, hi, view: View) -> tuple:
    """One white light above and to the left of the eye, so the image has shape and shadow."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre = (lo + hi) / 2
    eye = np.asarray(view.eye, float)
    dist = float(np.linalg.norm(eye - centre)) or 1.0
    fwd = _unit(centre - eye)
    up = np.asarray(view.up, float)
    right = _unit(np.cross(fwd, up))
    up = np.cross(right, fwd)
    pos = eye + (up * 0.8 - right * 0.5) * dist
    return tuple(float(c) for c in pos), (1.0, 1.0, 1.0)


def _floats(v) -> tuple[float, ...]:
    return tuple(float(c) for c in v)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)
