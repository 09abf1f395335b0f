"""SPD `shells`: a logarithmic spiral of shiny spheres growing along it; one light."""

import numpy as np

from bench.generate.records import SpdScene
from protocols.scene import SceneData, View

DEFAULT = 5  # shells.nff: 5,761 spheres
VIEW = View(eye=(-6.0, -60.0, 35.0), at=(0, 8, -15), up=(0, 0, 1), angle=45.0, hither=0.5)
A, BETA = 0.15, -2.0  # the spiral's growth exponent and its height over its radius


def shells_count(n: int) -> int:
    """Spheres of `shells(n)`."""
    steps = int(180.0 * 2.0**n)
    return steps // 3 + (2 * steps) // 3 + 1


def shells(n: int = DEFAULT, printed: bool = False) -> SceneData:
    """SPD `shells` at size factor n: spheres at angles 18 pi i / steps for i from -2/3 to 1/3
    of steps = 180 x 2^n, radius exp(0.15 angle), their centres that far from the axis."""
    scene = SpdScene(VIEW, ((-100.0, -100.0, 100.0),))
    mat = scene.material((1.0, 0.8, 0.4), 0.8, 0.2, 10.0, 0.0, 1.0)
    steps = int(180.0 * 2.0**n)
    i = np.arange(-((steps * 2) // 3), steps // 3 + 1)  # C's division truncates towards zero
    angle = 3.0 * 6.0 * np.pi * i / steps
    r = np.exp(A * angle)
    scene.spheres(np.stack([r * np.sin(angle), r * np.cos(angle), BETA * r], axis=1), r, mat)
    return scene.build(f"<generated shells {n}>", printed)
