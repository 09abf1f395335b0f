"""The camera policy of one render: which camera its options ask for (the scene's pinhole,
plain or set up as a camera, or a camera file) and the film fitted to the image's shape.
Decided here, not in the command line, so the command line only parses and wires; `warn`
tells the user once, by option name, what is changed or changes nothing.
"""

from collections.abc import Callable
from dataclasses import replace

from host.camera.lensfile import read_camera
from host.camera.setup import CameraSetup, Focus, PinholeSetup
from protocols.camera import CameraSampling
from protocols.render import ImageSpec

Warn = Callable[[str], None]


def pinhole(image: ImageSpec, sampling: dict, warn: Warn):
    """The image and the scene's pinhole: plain jittered samples (the eye-ray kernel; None),
    or, for another --sampling, the pinhole set up as a camera (PinholeSetup; the image then
    takes its rays per pixel from it, so its own spp becomes 1)."""
    how = sampling.get("sampling", "jittered")
    if how == "jittered":
        return image, None
    if image.spd:
        raise ValueError(f"--sampling {how}: the SPD rules fix the eye rays at pixel corners")
    if image.spp == 1 and how == "adaptive":
        warn("--sampling adaptive with --spp 1 traces one ray per pixel; give --spp N")
    return replace(image, spp=1), PinholeSetup.of(how, image.spp, sampling.get("threshold"))


def lens_camera(
    image: ImageSpec, sampling: dict, focus: dict, path, film_size, warn: Warn
) -> CameraSetup:
    """The camera of a camera file or lens table, sampled and focused as the given fields
    of CameraSampling and Focus ask; rays per pixel are the camera's, not the image's."""
    if image.spp != 1:
        raise ValueError(
            "--spp is for the pinhole; through a camera, rays per pixel are --lens-rays N"
        )
    sampled = CameraSampling(**sampling)
    warn_unused(sampled, sampling, warn)
    return CameraSetup(read_camera(path, film_size), sampled, Focus(**focus))


def fit_aspect(image: ImageSpec, camera, view, size_given: bool, warn: Warn):
    """A film of another shape than the image would stretch the picture: the image takes the
    film's shape (its width kept) unless its width and height are both given (`size_given`,
    or the SPD rules), and then the film is cropped to the image's shape; either way `warn`
    says so."""
    if not isinstance(camera, CameraSetup):
        return image, camera
    w, h = image.sized(view).size
    cam = camera.camera
    film, picture = cam.film_width / cam.film_height, w / h
    if abs(film / picture - 1) < 0.5 / min(w, h):  # within half a pixel
        return image, camera
    mm = f"{cam.film_width * 1000:g} x {cam.film_height * 1000:g} mm film"
    if not (image.spd or size_given):
        height = max(1, round(w / film))
        warn(
            f"the {mm} is {film:.3g}:1 and the image {w}x{h}: rendering {w}x{height} so "
            "nothing is stretched (give --width and --height to keep a size; the film is "
            "then cropped)"
        )
        return replace(image, width=w, height=height), camera
    if film > picture:
        fw, fh = cam.film_height * picture, cam.film_height
    else:
        fw, fh = cam.film_width, cam.film_width / picture
    warn(
        f"the {mm} is {film:.3g}:1 and the image {w}x{h} {picture:.3g}:1: cropping the film "
        f"to {fw * 1000:.3g} x {fh * 1000:.3g} mm so nothing is stretched"
    )
    return image, replace(camera, camera=replace(cam, film_width=fw, film_height=fh))


def warn_unused(s: CameraSampling, given: dict, warn: Warn) -> None:
    """Options that change nothing with this generation area and film area, by name: a
    setting the user believes in but that has no effect is worth one line."""
    if "rays" in given and s.per_pixel != s.rays:
        why = (
            f"generation {s.generation} traces its fixed {s.kind.points} points"
            if s.kind.points
            else f"generation {s.generation} traces one ray per pixel without --film-area"
        )
        warn(f"--lens-rays {s.rays} changes nothing: {why}")
    if "sampling" in given and s.per_pixel == 1:
        warn(f"--sampling {s.sampling} changes nothing: one ray per pixel")
    if "film_area_size" in given and s.film_area == "centre":
        warn("--film-area-size changes nothing without --film-area ellipse|rectangle")
