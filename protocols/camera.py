"""How primary rays leave a simulated camera: the element stack, the film, and the sampling.

The host builds one from a camera file and the render options; it travels to every mesh node
inside CONFIG (`to_wire` / `from_wire`), and each node makes the camera rays of its own pixels.
"""

from dataclasses import asdict, dataclass

import numpy as np

from protocols import dtypes

SAMPLINGS = ("uniform", "jittered", "random", "adaptive")
FILM_AREAS = ("centre", "ellipse", "rectangle")
ADAPTATIONS = ("all", "left")


@dataclass(frozen=True)
class CameraRays:
    """Everything a node needs to make camera rays.

    generation: area type 0..7 on the first element (DESIGN.md 7); rays: rays per pixel for
    types 2 and 3 (and for a film area or special jittering with types 0 and 1); sampling:
    how those rays are placed (regular strata, jittered strata, independent random, or
    adaptive: two opposite-corner rays first, the rest only where their colours differ by more
    than `threshold`); film_area: where on the pixel a ray starts, `film_area_size` pixels
    across; special: jitter over the film area instead of the lens (no depth of field)."""

    elements: np.ndarray  # protocols.dtypes.ELEMENT, film outward
    film_width: float
    film_height: float
    film_z: float
    generation: int = 2
    rays: int = 16
    sampling: str = "jittered"
    threshold: float = 0.05
    film_area: str = "centre"
    film_area_size: float = 1.0
    special: bool = False
    adaptation: str = "all"
    seed: int = 0

    def __post_init__(self):
        if self.elements.dtype != dtypes.ELEMENT or len(self.elements) == 0:
            raise ValueError("camera elements must be a non-empty ELEMENT array")
        if self.generation not in range(8):
            raise ValueError(f"generation area type must be 0..7, not {self.generation}")
        if self.rays < 1:
            raise ValueError("rays per pixel must be at least 1")
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"sampling must be one of {SAMPLINGS}, not {self.sampling!r}")
        if self.film_area not in FILM_AREAS:
            raise ValueError(f"film area must be one of {FILM_AREAS}, not {self.film_area!r}")
        if self.adaptation not in ADAPTATIONS:
            raise ValueError(f"adaptation must be one of {ADAPTATIONS}, not {self.adaptation!r}")
        if self.special and self.film_area == "centre":
            raise ValueError("special jittering needs a film area (ellipse or rectangle)")
        if self.threshold < 0 or self.film_area_size <= 0:
            raise ValueError("threshold must be >= 0 and the film area size positive")

    @property
    def per_pixel(self) -> int:
        """Rays generated for a pixel when every one is traced."""
        if self.generation in (4, 5):
            return 5
        if self.generation in (6, 7):
            return 9
        if self.generation in (0, 1) and not self.special and self.film_area == "centre":
            return 1
        return self.rays

    @property
    def adaptive(self) -> bool:
        return self.sampling == "adaptive" and self.per_pixel > 2

    def to_wire(self) -> dict:
        d = asdict(self)
        d["elements"] = np.ascontiguousarray(self.elements)
        return d

    @classmethod
    def from_wire(cls, d: dict) -> "CameraRays":
        return cls(**{**d, "elements": np.array(d["elements"], dtypes.ELEMENT)})
