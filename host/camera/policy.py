"""The camera policy of one render: which camera its options ask for (the scene's pinhole,
plain or set up as a camera, or a camera file), its rays per pixel (ImageSpec.spp, whatever
the camera: LENS_SPP through a camera file unless given) and the film fitted to the image's
shape.
Decided here, not in the command line, so the command line only parses and wires; `warn`
tells the user once, by option name, what is changed or changes nothing.
"""

from collections.abc import Callable
from dataclasses import replace

from host.camera.setup import CameraSetup, Focus, PinholeSetup
from protocols.camera import CameraSampling
from protocols.render import ImageSpec

Warn = Callable[[str], None]
LENS_SPP = 16  # rays per pixel through a camera file when --spp is not given


def pinhole(image: ImageSpec, sampling: dict, warn: Warn):
    """The image and the scene's pinhole: plain jittered samples (the eye-ray kernel; None),
    or, for another --sampling, the pinhole set up as a camera (PinholeSetup), either way at
    the image's spp rays per pixel."""
    image.check_corners()
    how = sampling.get("sampling", "jittered")
    if how == "jittered":
        return image, None
    if image.spd:
        raise ValueError(f"--sampling {how}: the SPD rules fix the eye rays at pixel corners")
    if image.spp == 1 and how == "adaptive":
        warn("--sampling adaptive with --spp 1 traces one ray per pixel; give --spp N")
    return image, PinholeSetup.of(how, sampling.get("threshold"))


def lens_camera(
    image: dict, sampling: dict, focus: dict, path, film_size, warn: Warn
) -> tuple[ImageSpec, CameraSetup]:
    """The image, and the camera of a camera file or lens table, made from the given fields
    of ImageSpec, CameraSampling and Focus: rays per pixel are the image's spp, LENS_SPP
    unless given."""
    from host.camera.lensfile import read_camera  # the lens code: a pinhole never loads it

    pictured = ImageSpec(**{"spp": LENS_SPP, **image})
    sampled = CameraSampling(**sampling)
    warn_unused(sampled, pictured.spp, {**image, **sampling}, warn)
    return pictured, CameraSetup(read_camera(path, film_size), sampled, Focus(**focus))


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


def warn_unused(s: CameraSampling, spp: int, given: dict, warn: Warn) -> None:
    """Options that change nothing with this generation area and film area at `spp` rays
    per pixel asked for, by name (`given`: the fields given, of the image and the sampling):
    a setting the user believes in but that has no effect is worth one line."""
    if "spp" in given and s.per_pixel(spp) != spp:
        why = (
            f"generation {s.generation} traces its fixed {s.kind.points} points"
            if s.kind.points
            else f"generation {s.generation} traces one ray per pixel without --film-area"
        )
        warn(f"--spp {spp} changes nothing: {why}")
    if "sampling" in given and s.per_pixel(spp) == 1:
        warn(f"--sampling {s.sampling} changes nothing: one ray per pixel")
    if "film_area_size" in given and s.film_area == "centre":
        warn("--film-area-size changes nothing without --film-area ellipse|rectangle")
