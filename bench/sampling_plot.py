"""The sampling benchmark's log-log plot of RMS error against CPU seconds (PNG, drawn with
Pillow, no plotting library needed): one line per method through the median seconds, a bar
through each point from the least to the most, so trade-offs and noise read at a glance."""

import math
from pathlib import Path

PLOT_SIZE = (900, 620)
MARGIN = (90, 50, 30, 70)  # left, top, right, bottom
COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14)]


def _font(size: int):
    """The default font at `size`, or the fixed bitmap one where Pillow has no FreeType."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def log_ticks(lo: float, hi: float) -> list[float]:
    """Tick values between lo and hi: 1-2-5 per decade over short ranges, decades otherwise."""
    mantissas = (1, 2, 5) if math.log10(hi / lo) <= 3 else (1,)
    first, last = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    ticks = [m * 10.0**e for e in range(first, last + 1) for m in mantissas]
    return [t for t in ticks if lo <= t <= hi]


def _log_range(values, pad: float = 0.08) -> tuple[float, float]:
    """Bounds padded by `pad` of the span, in log space (at least a factor 2 wide)."""
    lo, hi = math.log10(min(values)), math.log10(max(values))
    mid, half = 0.5 * (lo + hi), max(0.5 * (hi - lo), math.log10(2) / 2)
    half *= 1 + 2 * pad
    return 10 ** (mid - half), 10 ** (mid + half)


class LogAxes:
    """Maps (seconds, error) onto pixel positions of the plot area, both axes logarithmic."""

    def __init__(self, xs, ys):
        self.x0, self.x1 = _log_range(xs)
        self.y0, self.y1 = _log_range(ys)
        w, h = PLOT_SIZE
        left, top, right, bottom = MARGIN
        self.box = (left, top, w - right, h - bottom)

    def __call__(self, x: float, y: float) -> tuple[float, float]:
        """The pixel position of (seconds, error)."""
        left, top, right, bottom = self.box
        fx = math.log10(x / self.x0) / math.log10(self.x1 / self.x0)
        fy = math.log10(y / self.y0) / math.log10(self.y1 / self.y0)
        return left + fx * (right - left), bottom - fy * (bottom - top)


def _draw_axes(draw, image, ax: LogAxes, title: str) -> None:
    """Frame, grid lines, tick labels, axis titles and the plot title."""
    from PIL import Image, ImageDraw

    font, small = _font(16), _font(13)
    left, top, right, bottom = ax.box
    for x in log_ticks(ax.x0, ax.x1):
        px, _ = ax(x, ax.y0)
        draw.line([(px, top), (px, bottom)], fill=(225, 225, 225))
        draw.text((px, bottom + 6), f"{x:g}", fill="black", font=small, anchor="mt")
    for y in log_ticks(ax.y0, ax.y1):
        _, py = ax(ax.x0, y)
        draw.line([(left, py), (right, py)], fill=(225, 225, 225))
        draw.text((left - 6, py), f"{y:g}", fill="black", font=small, anchor="rm")
    draw.rectangle(ax.box, outline="black")
    draw.text(
        ((left + right) / 2, PLOT_SIZE[1] - 22),
        "CPU seconds of the frame (log; median, bar: least-most)",
        fill="black",
        font=font,
        anchor="mm",
    )
    draw.text(((left + right) / 2, top / 2), title, fill="black", font=font, anchor="mm")
    label = "RMS error vs reference (log)"
    size = (int(draw.textlength(label, font=font)) + 4, 22)
    text = Image.new("RGBA", size, (255, 255, 255, 0))
    ImageDraw.Draw(text).text((2, 2), label, fill="black", font=font)
    text = text.rotate(90, expand=True)
    image.paste(text, (8, int((top + bottom - text.height) / 2)), text)


def _marker(draw, xy, shape: int, colour) -> None:
    """A filled circle, square or triangle (by index) centred on xy."""
    x, y, r = xy[0], xy[1], 5
    if shape % 3 == 0:
        draw.ellipse([x - r, y - r, x + r, y + r], fill=colour, outline="black")
    elif shape % 3 == 1:
        draw.rectangle([x - r, y - r, x + r, y + r], fill=colour, outline="black")
    else:
        draw.polygon(
            [(x, y - r - 1), (x + r + 1, y + r), (x - r - 1, y + r)], fill=colour, outline="black"
        )


def plot(rows: list[dict], path: Path, title: str) -> None:
    """Log-log PNG of RMS error against CPU seconds: one line per method through the medians,
    each point's least-most bar, points labelled with their rays per pixel, and a legend."""
    from PIL import Image, ImageDraw

    image = Image.new("RGB", PLOT_SIZE, "white")
    draw = ImageDraw.Draw(image)
    spread = [r.get(k, r["seconds"]) for r in rows for k in ("seconds_low", "seconds_high")]
    ax = LogAxes([r["seconds"] for r in rows] + spread, [r["rms"] for r in rows])
    _draw_axes(draw, image, ax, title)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    small = _font(12)
    for i, method in enumerate(methods):
        colour = COLOURS[i % len(COLOURS)]
        mine = [r for r in rows if r["method"] == method]
        for r in mine:  # the spread of its CPU seconds over the rounds
            lo = ax(r.get("seconds_low", r["seconds"]), r["rms"])
            hi = ax(r.get("seconds_high", r["seconds"]), r["rms"])
            draw.line([lo, hi], fill=colour, width=1)
            draw.line([(lo[0], lo[1] - 3), (lo[0], lo[1] + 3)], fill=colour, width=1)
            draw.line([(hi[0], hi[1] - 3), (hi[0], hi[1] + 3)], fill=colour, width=1)
        points = sorted(((ax(r["seconds"], r["rms"]), r["spp"]) for r in mine), key=lambda p: p[1])
        draw.line([p for p, _ in points], fill=colour, width=2)
        for xy, spp in points:
            _marker(draw, xy, i, colour)
            draw.text((xy[0] + 7, xy[1] - 7), str(spp), fill=colour, font=small, anchor="lb")
    _legend(draw, ax, methods)
    image.save(path)


def _legend(draw, ax: LogAxes, methods: list[str]) -> None:
    """Method names with their colour and marker, in the top right corner of the plot area."""
    font = _font(14)
    width = max(draw.textlength(m, font=font) for m in methods) + 50
    _, top, right, _ = ax.box
    x0, y0 = right - width - 10, top + 10
    draw.rectangle(
        [x0, y0, right - 10, y0 + 22 * len(methods) + 8], fill="white", outline=(160, 160, 160)
    )
    for i, method in enumerate(methods):
        colour, y = COLOURS[i % len(COLOURS)], y0 + 15 + 22 * i
        draw.line([(x0 + 8, y), (x0 + 36, y)], fill=colour, width=2)
        _marker(draw, (x0 + 22, y), i, colour)
        draw.text((x0 + 44, y), method, fill="black", font=font, anchor="lm")
