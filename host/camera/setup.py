"""A camera set up for one render: the camera file, how it is focused and stopped, and how its
rays are sampled; `spec` turns it into the CameraSpec every node makes rays from. The scene's
pinhole sampled other than by plain jitter is set up the same way (PinholeSetup).

Focusing is the host's alone (it may need a probe pass through the scene), so `Focus` is a
host record; the sampling travels to the nodes inside the CameraSpec. The lens code (optics,
pupil and camera-ray kernels, autofocus) is imported by the methods that use it: a pinhole
render never loads it.
"""

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from meshnode.engine.camera import view_basis
from protocols import dtypes
from protocols.camera import CameraSampling, CameraSpec, Generation
from protocols.render import ImageSpec
from protocols.spec import Spec

if TYPE_CHECKING:
    from host.camera.lens import Camera

FOCUS_WORDS = ("auto", "infinity")


@dataclass(frozen=True)
class Focus(Spec):
    """distance: metres, "infinity" or "auto" (a probe pass on the image centre), None: the
    camera file's; dof_near/dof_far: focus and f-number so everything between is sharp;
    dof_tolerance: the focus distance +- this stays sharp; coc: largest circle of confusion
    on the film (m; None: the film diagonal / 1500); f_number: the stop scaled to it."""

    distance: float | str | None = None
    dof_near: float | None = None
    dof_far: float | None = None
    dof_tolerance: float | None = None
    coc: float | None = None
    f_number: float | None = None

    def check(self) -> None:
        d = self.distance
        if not (
            d is None
            or d in FOCUS_WORDS
            or isinstance(d, int | float)
            and not isinstance(d, bool)
            and 0 < d < math.inf
        ):
            self.fail("distance", "must be metres (> 0), 'infinity' or 'auto'")
        for name in ("dof_near", "dof_far", "dof_tolerance", "coc", "f_number"):
            self.want_number(name, 0.0, math.inf, open_lo=True, optional=True)


@dataclass(frozen=True)
class CameraSetup:
    """The camera of a render before focusing: optics, focus request, sampling."""

    camera: "Camera"
    sampling: CameraSampling = field(default_factory=CameraSampling)
    focus: Focus = field(default_factory=Focus)

    def spec(self, scene, image: ImageSpec, probe_engine) -> tuple[CameraSpec, dict]:
        """The camera focused and stopped as asked, as the spec every node makes rays from,
        and what the statistics say of it; `probe_engine()` gives an engine over the scene if
        autofocus needs a probe pass."""
        from host.camera.autofocus import autofocus_distance
        from host.camera.lens import describe, focused
        from meshnode.engine.pupil import exit_pupil

        w, h = image.size
        probe: dict = {}

        def autofocus():
            distance, seen = autofocus_distance(probe_engine(), scene.view, w, h)
            probe.update(seen)
            return distance

        f = self.focus
        cam = focused(
            self.camera,
            f.distance,
            f.dof_near,
            f.dof_far,
            f.dof_tolerance,
            f.coc,
            autofocus,
            f.f_number,
        )
        film_z = cam.focused_film_z()
        pupil = exit_pupil(cam.elements, film_z, math.hypot(cam.film_width, cam.film_height) / 2)
        spec = CameraSpec(
            cam.elements, cam.film_width, cam.film_height, film_z, self.sampling, *pupil
        )
        s = self.sampling
        return spec, {
            "source": cam.source,
            "notes": cam.notes,
            "f_number": describe(cam)["f_number"],
            "focus_distance_m": cam.focus_distance,
            "film_z_m": spec.film_z,
            "effective_focal_length_m": describe(cam)["effective_focal_length_m"],
            "generation": s.generation,
            "rays_per_pixel": s.per_pixel(image.spp),
            "sampling": s.sampling,
            "threshold": s.threshold if s.adaptive(image.spp) else None,
            "film_area": s.film_area,
            "special_jittering": s.special,
            "adaptation": s.adaptation,
            "autofocus": probe or None,
            "exit_pupil_bands": len(spec.pupil) // 3,
            "centre_rays_leaving_camera": leaving_share(spec, scene.view, w, h, centre=True),
            "rays_leaving_lens": leaving_share(spec, scene.view, w, h),
        }


@dataclass(frozen=True)
class PinholeSetup:
    """The scene's own pinhole eye sampled as a camera, so the pinhole gets every sampler
    (uniform, random, adaptive in two passes, on one node or the mesh) without a second
    implementation: a pinhole at the eye, a film one unit behind it as wide as the view's
    angle spans, the image's spp rays per pixel over the pixel's area, rays starting at the
    scene's hither."""

    sampling: CameraSampling

    def spec(self, scene, image: ImageSpec, probe_engine=None) -> tuple[CameraSpec, dict]:
        w, h = image.size
        step = view_basis(scene.view, w, h)[4]
        pinhole = np.zeros(1, dtypes.ELEMENT)
        pinhole["kind"], pinhole["ax"], pinhole["ay"] = dtypes.DIAPHRAGM, 1.0, 1.0
        spec = CameraSpec(pinhole, w * step, h * step, -1.0, self.sampling)
        s = self.sampling
        return spec, {
            "source": "pinhole (the scene's view)",
            "notes": [],
            "generation": s.generation,
            "rays_per_pixel": s.per_pixel(image.spp),
            "sampling": s.sampling,
            "threshold": s.threshold if s.adaptive(image.spp) else None,
            "film_area": s.film_area,
            "adaptation": s.adaptation,
            "rays_leaving_lens": 1.0,
        }

    @classmethod
    def of(cls, sampling: str, threshold: float | None = None) -> "PinholeSetup":
        """The image's rays per pixel over each pixel's area, placed by `sampling`."""
        given = {} if threshold is None else {"threshold": threshold}
        return cls(
            CameraSampling(
                generation=Generation.PINHOLE,
                sampling=sampling,
                film_area="rectangle",
                **given,
            )
        )


def leaving_share(spec: CameraSpec, view, width: int, height: int, centre=False) -> float:
    """Share of the camera rays that leave the lens, from a probe of 64 rays (sampled as the
    render samples them) at each of up to 32 x 32 pixels spread over the image, or of 256
    uniform rays from the centre pixel: a lens that blocks most rays wastes most of the work
    (the CLI warns)."""
    from meshnode.engine.lenscamera import camera_rays

    s = spec.sampling
    if centre:
        rays = 256
        sampled = replace(s, sampling="uniform", film_area="centre", special=False)
        pixels = np.array([(height // 2) * width + width // 2])
    else:  # 64 asked for (a fixed pattern traces its points); adaptive's rays are jittered
        rays = 64
        sampled = replace(s, sampling="jittered" if s.sampling == "adaptive" else s.sampling)
        xs = np.unique(np.linspace(0, width - 1, min(width, 32)).astype(np.int64))
        ys = np.unique(np.linspace(0, height - 1, min(height, 32)).astype(np.int64))
        pixels = (ys[:, None] * width + xs[None, :]).ravel()
    _, alive = camera_rays(replace(spec, sampling=sampled), rays, view, width, height, pixels)
    return float(alive.mean())
