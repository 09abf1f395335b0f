"""The command line's option helpers: an option bound to one field of a render record (its
default and checks the record's, `FLAGS` naming the option in messages), the fields given,
the value types argparse converts with, and the sampling and camera option groups.
"""

import argparse

from host.camera.setup import Focus
from protocols.camera import ADAPTATIONS, FILM_AREAS, SAMPLINGS, CameraSampling
from protocols.spec import default

FLAGS: dict[str, str] = {}  # "Record.field" -> the option that sets it, for messages
FILM_SIZE_HELP = "film WIDTHxHEIGHT in mm (default: the file's; 36x24 for a lens table)"


def record_option(
    group, flag: str, record: type, name: str, help: str, default_also: str = "", **kw
) -> None:
    """An option that sets `record.name`; unset, the record's own default applies (or what
    `default_also` says, shown after it)."""
    d = default(record, name)
    FLAGS[f"{record.__name__}.{name}"] = flag
    shown = "" if d is None or kw.get("action") == "store_true" else f" (default {d}{default_also})"
    if kw.get("action") is None and "choices" not in kw:
        kw.setdefault("metavar", flag.lstrip("-").replace("-", "_").upper())  # not the field
    group.add_argument(
        flag, dest=f"{record.__name__}.{name}", default=argparse.SUPPRESS, help=help + shown, **kw
    )


def given_fields(args, record: type) -> dict:
    """The fields of `record` set on the command line."""
    prefix = f"{record.__name__}."
    return {k[len(prefix) :]: v for k, v in vars(args).items() if k.startswith(prefix)}


def film_size(text: str) -> tuple[float, float]:
    """'36x24' (mm) -> (0.036, 0.024) metres."""
    try:
        w, h = (float(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT in mm") from None
    if not (0 < w < 1e6 and 0 < h < 1e6):
        raise argparse.ArgumentTypeError(f"{text!r}: both sides must be positive mm")
    return w / 1000, h / 1000


def sampling_options(g) -> None:
    """CameraSampling's placing of a pixel's rays, which the pinhole takes as well."""
    record_option(
        g,
        "--sampling",
        CameraSampling,
        "sampling",
        "how a pixel's rays are placed; "
        "adaptive: two opposite corners first, the rest where they differ by more than "
        "--threshold",
        choices=SAMPLINGS,
    )
    record_option(
        g,
        "--threshold",
        CameraSampling,
        "threshold",
        "adaptive sampling's colour difference",
        type=float,
    )


def camera_options(g) -> None:
    """The rest of CameraSampling, and Focus: options of a camera file only."""
    record_option(
        g,
        "--generation",
        CameraSampling,
        "generation",
        "generation area type 0..7 (2: --spp rays in the first element's ellipse; 0 and 1 "
        "trace one ray per pixel unless with a film area, 4..7 fixed points)",
        type=int,
    )
    record_option(
        g,
        "--film-area",
        CameraSampling,
        "film_area",
        "where on the pixel rays start (anti-aliasing in focus)",
        choices=FILM_AREAS,
    )
    record_option(
        g,
        "--film-area-size",
        CameraSampling,
        "film_area_size",
        "film area, pixels across",
        type=float,
    )
    record_option(
        g,
        "--special-jitter",
        CameraSampling,
        "special",
        "jitter over the film area instead of the lens: no depth of field",
        action="store_true",
    )
    record_option(
        g,
        "--adaptation",
        CameraSampling,
        "adaptation",
        "average over all generated rays or those that left the camera",
        choices=ADAPTATIONS,
    )
    record_option(
        g,
        "--focus",
        Focus,
        "distance",
        "focus distance in metres, 'infinity' or 'auto' "
        "(a probe pass on the image centre); default: the camera file's",
        type=focus_distance,
    )
    record_option(
        g, "--dof-near", Focus, "dof_near", "depth of field: nearest sharp distance (m)", type=float
    )
    record_option(
        g,
        "--dof-far",
        Focus,
        "dof_far",
        "farthest sharp distance (m; default infinity with --dof-near)",
        type=float,
    )
    record_option(
        g,
        "--dof-tolerance",
        Focus,
        "dof_tolerance",
        "keep the focus distance +- this many metres sharp",
        type=float,
    )
    record_option(
        g,
        "--coc",
        Focus,
        "coc",
        "largest circle of confusion on the film, m (default: diagonal/1500)",
        type=float,
    )
    record_option(g, "--f-number", Focus, "f_number", "stop the lens to this f-number", type=float)
    g.add_argument("--film-size", type=film_size, help=FILM_SIZE_HELP)


def overlap(text: str) -> float | str:
    """An overlap in percent, or "auto"."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a percentage nor auto") from None


def share(text: str) -> float:
    """A share of the scene: a number above 0 and at most 1, or a percentage ('25%')."""
    t = text.strip()
    try:
        value = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a share (e.g. 0.25 or 25%)") from None
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"{text!r}: a share must be above 0 and at most 1")
    return value


def focus_distance(text: str):
    """Metres as a number; words as they are (Focus says which words it takes)."""
    try:
        return float(text)
    except ValueError:
        return text
