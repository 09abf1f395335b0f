"""How primary rays leave a simulated camera: the element stack, the film, and the sampling.

The command line builds a CameraSampling from its options; the host focuses the camera file
and makes the CameraSpec every mesh node receives inside CONFIG, and each node makes the camera
rays of its own pixels from it (with the image's seed and rays per pixel, ImageSpec.spp).
"""

from dataclasses import dataclass, field
from enum import IntEnum
from typing import ClassVar

import numpy as np

from protocols import dtypes
from protocols.spec import Spec, SpecError

SAMPLINGS = ("uniform", "jittered", "random", "adaptive")
FILM_AREAS = ("centre", "ellipse", "rectangle")
ADAPTATIONS = ("all", "left")
MAX_PUPIL_BANDS = 1024


class Generation(IntEnum):
    """Generation area types on the first element (DESIGN.md 7)."""

    PINHOLE = 0  # straight through the centre of the first element, no refraction
    CENTRE = 1  # one ray through the centre of the first element, through the elements
    ELLIPSE = 2  # N rays in the first element's ellipse
    RECTANGLE = 3  # N rays in its bounding rectangle
    FIVE = 4  # five fixed points
    FIVE_JITTERED = 5
    NINE = 6  # nine fixed points
    NINE_JITTERED = 7

    @property
    def points(self) -> int:
        """Rays of a fixed pattern (0: the count is the image's rays per pixel)."""
        return {4: 5, 5: 5, 6: 9, 7: 9}.get(int(self), 0)

    @property
    def jittered(self) -> bool:
        return self in (Generation.FIVE_JITTERED, Generation.NINE_JITTERED)

    @property
    def through_centre(self) -> bool:
        """One ray through the centre: no lens sampling, no depth of field."""
        return self in (Generation.PINHOLE, Generation.CENTRE)


@dataclass(frozen=True)
class CameraSampling(Spec):
    """Where a pixel's camera rays go.

    generation: area type on the first element (how many of the image's rays per pixel,
    ImageSpec.spp, it traces: `per_pixel`); sampling: how they are placed
    (regular strata, jittered strata, independent random, or adaptive: two opposite-corner
    rays first, the rest only where their colours differ by more than `threshold`);
    film_area: where on the pixel a ray starts, `film_area_size` pixels across; special:
    jitter over the film area instead of the lens (no depth of field); adaptation: divide by
    all generated rays or by those that left the camera."""

    generation: int = Generation.ELLIPSE
    sampling: str = "jittered"
    threshold: float = 0.05
    film_area: str = "centre"
    film_area_size: float = 1.0
    special: bool = False
    adaptation: str = "all"

    def check(self) -> None:
        self.want_int("generation", 0, 7)
        self.want_choice("sampling", SAMPLINGS)
        self.want_number("threshold", 0.0, 1e30)
        self.want_choice("film_area", FILM_AREAS)
        self.want_number("film_area_size", 0.0, 1e6, open_lo=True)
        self.want_bool("special")
        self.want_choice("adaptation", ADAPTATIONS)
        if self.special and self.film_area == "centre":
            self.fail("special", "special jittering needs a film area (ellipse or rectangle)")

    @property
    def kind(self) -> Generation:
        return Generation(self.generation)

    def per_pixel(self, rays: int) -> int:
        """Rays generated for a pixel when every one is traced, `rays` (the image's spp)
        asked for: all of them with types 2 and 3 (and with a film area or special jittering
        with types 0 and 1), a fixed pattern's points, else one."""
        if self.kind.points:
            return self.kind.points
        if self.kind.through_centre and not self.special and self.film_area == "centre":
            return 1
        return rays

    def adaptive(self, rays: int) -> bool:
        """Adaptive sampling at `rays` asked for per pixel (two passes need three or more)."""
        return self.sampling == "adaptive" and self.per_pixel(rays) > 2


@dataclass(frozen=True)
class CameraSpec(Spec):
    """Everything a node needs to make camera rays: the elements (ELEMENT records, film
    outward), the film's size and position (m), the sampling, and the exit pupil: for bands
    of distance from the film's centre out to `pupil_radius`, the ellipse (centre x, semi-axes
    x and y; flattened) in the first element's plane through which light from a film point on
    the +x axis leaves the lens (empty: rays are aimed at the whole first element), and
    `pupil_area`, the area of that plane passing from the film's centre, which a lens-sampled
    ray's weight is relative to (0: every ray weighs alike)."""

    elements: np.ndarray
    film_width: float
    film_height: float
    film_z: float
    sampling: CameraSampling = field(default_factory=CameraSampling)
    pupil: tuple = ()
    pupil_radius: float = 0.0
    pupil_area: float = 0.0

    NESTED: ClassVar[dict] = {"sampling": CameraSampling}

    def check(self) -> None:
        e = self.elements
        if not isinstance(e, np.ndarray) or e.dtype != dtypes.ELEMENT or e.ndim != 1:
            self.fail("elements", "must be a one-dimensional ELEMENT array")
        if not 1 <= len(e) <= 256:
            self.fail("elements", "a camera has 1 to 256 elements")
        numbers = np.concatenate([e[n].astype(float).ravel() for n in e.dtype.names])
        if not np.all(np.isfinite(numbers)):
            self.fail("elements", "every element value must be finite")
        if np.any(e["kind"] > dtypes.ELLIPSOID):
            self.fail("elements", f"kinds are {dtypes.CAP} to {dtypes.ELLIPSOID}")
        ell = e[e["kind"] == dtypes.ELLIPSOID]
        if np.any(ell["cap_x"] <= 0) or np.any(ell["cap_y"] <= 0) or np.any(ell["radius"] == 0):
            self.fail("elements", "an ellipsoid needs semi-axes x, y > 0 and z != 0")
        self.want_number("film_width", 0.0, 1e3, open_lo=True)
        self.want_number("film_height", 0.0, 1e3, open_lo=True)
        self.want_number("film_z", -1e3, 1e3)
        if not isinstance(self.sampling, CameraSampling):
            self.fail("sampling", "must be a CameraSampling")
        self._check_pupil()

    def _check_pupil(self) -> None:
        p = self.pupil
        if not isinstance(p, tuple) or len(p) % 3 or len(p) > 3 * MAX_PUPIL_BANDS:
            self.fail("pupil", f"must be a tuple of up to {MAX_PUPIL_BANDS} (x, a, b) triples")
        try:
            bands = np.array(p, dtype=float).reshape(-1, 3)
        except (TypeError, ValueError):
            self.fail("pupil", "must hold numbers")
        if not np.all(np.isfinite(bands)) or np.any(bands[:, 1:] < 0):
            self.fail("pupil", "must be finite, with semi-axes >= 0")
        self.want_number("pupil_area", 0.0, 1e6)
        if p:
            self.want_number("pupil_radius", 0.0, 1e3, open_lo=True)
            self.want_number("pupil_area", 0.0, 1e6, open_lo=True)

    def __eq__(self, other) -> bool:
        if not isinstance(other, CameraSpec):
            return NotImplemented
        same = (
            self.film_width,
            self.film_height,
            self.film_z,
            self.sampling,
            self.pupil,
            self.pupil_radius,
            self.pupil_area,
        ) == (
            other.film_width,
            other.film_height,
            other.film_z,
            other.sampling,
            other.pupil,
            other.pupil_radius,
            other.pupil_area,
        )
        return same and np.array_equal(self.elements, other.elements)

    def per_pixel(self, rays: int) -> int:
        return self.sampling.per_pixel(rays)

    def adaptive(self, rays: int) -> bool:
        return self.sampling.adaptive(rays)

    @classmethod
    def decode(cls, values: dict) -> dict:
        elements = values["elements"]
        if not isinstance(elements, np.ndarray) or elements.dtype != dtypes.ELEMENT:
            got = getattr(elements, "dtype", type(elements).__name__)
            raise SpecError(f"CameraSpec.elements must be an ELEMENT array, got {got}")
        pupil = values.get("pupil")
        pupil = tuple(pupil) if isinstance(pupil, list | tuple) else pupil
        return {**values, "elements": np.array(elements), "pupil": pupil}
