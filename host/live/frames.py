"""The live view's frames as image bytes: previews as JPEG of an sRGB read from a table, the
final image (and /frame.png) as PNG.

Kept apart from `monitor`, which decides when the framebuffer is copied and caches what these
return: encoding is the costly step (run on the server's threads, never the render's), with
its own trade-offs of speed against exactness (LEVELS, QUALITY, PNG's compression level).
"""

import io

import numpy as np

from host.run.framebuffer import Framebuffer

LEVELS = 4096  # steps of the preview's linear-to-sRGB table
QUALITY = 90  # the preview JPEG's


def _srgb_table() -> np.ndarray:
    x = np.linspace(0.0, 1.0, LEVELS + 1)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


SRGB = _srgb_table()


def preview_srgb8(fb: Framebuffer) -> np.ndarray:
    """8-bit sRGB of a framebuffer by table (within a level of `to_srgb8`, a fifth of its
    time): the previews only; the final image is converted exactly."""
    linear = fb.image().astype(np.float32)
    np.multiply(linear, LEVELS, out=linear)
    np.clip(linear, 0, LEVELS, out=linear)
    return SRGB[(linear + 0.5).astype(np.int32)]


def encode_jpeg(rgb: np.ndarray) -> bytes:
    """A preview frame: JPEG encodes a megapixel in milliseconds, PNG in a fifth of a second."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(out, format="JPEG", quality=QUALITY)
    return out.getvalue()


def encode_png(rgb: np.ndarray) -> bytes:
    """8-bit RGB as PNG bytes, fast compression: frames go out several times a second."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(out, format="PNG", compress_level=1)
    return out.getvalue()
