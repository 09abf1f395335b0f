"""Where a render's images and statistics go: the paths are checked before any work (a
format this run can write, a folder that exists and can be written), so a render is never
lost to a bad path or a missing library; then each image is written in its suffix's format.
"""

import tempfile
from pathlib import Path

from host.run.framebuffer import exr_missing, write_exr, write_pfm, write_png

WRITERS = {".png": write_png, ".pfm": write_pfm, ".exr": write_exr}


def output_paths(
    scene, output=None, float_path=None, stats=None
) -> tuple[Path, Path | None, Path | None]:
    """The image, float image and statistics paths (-o, --float, --stats), checked. A .png
    output gets a .pfm beside it unless `float_path` says where; an .exr output is the float
    image itself; without `output`, the image is SCENE's name as .png here."""
    out = Path(output or Path(scene).with_suffix(".png").name)
    float_path = Path(float_path) if float_path else None
    if float_path is None and out.suffix.lower() == ".png":
        float_path = out.with_suffix(".pfm")
    stats = Path(stats) if stats else None
    _check_formats(out, float_path)
    for path, flag in ((out, "-o"), (float_path, "--float"), (stats, "--stats")):
        if path is not None:
            _check_writable(path, flag)
    return out, float_path, stats


def _check_formats(out: Path, float_path: Path | None) -> None:
    """Each image names a format it can be written in, and one this run can write."""
    for path, suffixes, flag in (
        (out, (".png", ".exr"), "-o"),
        (float_path, (".pfm", ".exr"), "--float"),
    ):
        if path is not None and path.suffix.lower() not in suffixes:
            raise ValueError(
                f"{flag} {path}: writes {' or '.join(suffixes)} images, not "
                f"{path.suffix or 'a name without a suffix'!r}"
            )
        if path is not None and path.suffix.lower() == ".exr" and exr_missing():
            raise ValueError(f"{flag} {path}: {exr_missing()}")


def _check_writable(path: Path, flag: str) -> None:
    """`path`'s folder exists and a file can be made there: tried, not inferred from
    permission bits (root passes every access check, yet cannot write in /proc)."""
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"{flag} {path}: no folder {folder}")
    if path.is_dir():
        raise ValueError(f"{flag} {path}: a folder, not a file")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".meshtrace-probe-"):
            pass
        if path.exists():
            with open(path, "ab"):
                pass
    except OSError as e:
        raise ValueError(f"{flag} {path}: cannot write there ({e.strerror or e})") from None


def write_images(img, *paths: Path | None) -> None:
    """`img` to each path given, in the format its suffix names."""
    for path in paths:
        if path is not None:
            WRITERS[path.suffix.lower()](path, img)
