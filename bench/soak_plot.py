"""The soak bench's resources over time: every node's resident memory and open descriptors after
each render, read from /proc, and their plot (PNG, drawn with Pillow as the sampling plot is),
so a leak shows as a slope within one mesh's renders."""

import statistics
from pathlib import Path

from bench.sampling_plot import _font

PLOT = (1000, 560)
MARGIN = (80, 40, 90, 60)  # left, top, right, bottom
RSS_COLOUR, FD_COLOUR, MESH_COLOUR = (31, 119, 180), (214, 39, 40), (200, 200, 200)


def node_resources(pids) -> tuple[list[float], list[int]]:
    """(resident MB, open descriptors) of each live process of `pids`."""
    rss, fds = [], []
    for pid in pids:
        try:
            status = Path(f"/proc/{pid}/status").read_text().splitlines()
            kb = next(int(ln.split()[1]) for ln in status if ln.startswith("VmRSS:"))
            fds.append(len(list(Path(f"/proc/{pid}/fd").iterdir())))
            rss.append(kb / 1024)
        except (OSError, StopIteration):
            continue  # gone (killed by the soak): not a sample
    return rss, fds


def growth(samples: list[dict], warm: int = 3) -> tuple[float, float]:
    """How much the busiest node's resources rose within one mesh's life, after its first
    `warm` renders (kernels loaded, engines cached, pools grown): the medians of RSS (MB) and
    of descriptors over the second half of its renders against the first half's. A sample is
    taken as a render returns, while the nodes may still be closing that render's links and a
    flood's sockets, so single samples swing by a dozen descriptors (14 to 27 in 200 renders);
    a leak moves the median."""
    rise_mb, rise_fd = 0.0, 0.0
    for mesh in {s["mesh"] for s in samples}:
        life = [s for s in samples if s["mesh"] == mesh][warm:]
        if len(life) < 8:  # a median of fewer than four is one sample's swing
            continue
        first, second = life[: len(life) // 2], life[len(life) // 2 :]
        for key, rise in (("rss_max_mb", "mb"), ("fds_max", "fd")):
            up = statistics.median(s[key] for s in second) - statistics.median(
                s[key] for s in first
            )
            if rise == "mb":
                rise_mb = max(rise_mb, up)
            else:
                rise_fd = max(rise_fd, up)
    return rise_mb, rise_fd


def plot(samples: list[dict], path: Path) -> None:
    """RSS (left axis, MB) and descriptors (right axis) of the busiest node after each render;
    grey lines where a fresh mesh started (after a kill)."""
    from PIL import Image, ImageDraw

    image = Image.new("RGB", PLOT, "white")
    draw = ImageDraw.Draw(image)
    left, top, right, bottom = MARGIN
    x0, x1, y0, y1 = left, PLOT[0] - right, top, PLOT[1] - bottom
    n = max(len(samples) - 1, 1)
    mb_hi = max(s["rss_max_mb"] for s in samples) * 1.15
    fd_hi = max(s["fds_max"] for s in samples) * 1.15

    def at(i, value, hi):
        return x0 + (x1 - x0) * i / n, y1 - (y1 - y0) * value / hi

    for i in range(1, len(samples)):
        if samples[i]["mesh"] != samples[i - 1]["mesh"]:
            x = at(i, 0, 1)[0]
            draw.line([(x, y0), (x, y1)], fill=MESH_COLOUR)
    for key, hi, colour in (("rss_max_mb", mb_hi, RSS_COLOUR), ("fds_max", fd_hi, FD_COLOUR)):
        points = [at(i, s[key], hi) for i, s in enumerate(samples)]
        draw.line(points, fill=colour, width=2)
    draw.rectangle([x0, y0, x1, y1], outline="black")
    font = _font(14)
    for k in range(5):
        frac = k / 4
        y = y1 - (y1 - y0) * frac
        draw.text((x0 - 8, y), f"{mb_hi * frac:.0f}", fill=RSS_COLOUR, font=font, anchor="rm")
        draw.text((x1 + 8, y), f"{fd_hi * frac:.0f}", fill=FD_COLOUR, font=font, anchor="lm")
    draw.text((x0, y0 - 24), "busiest node's RSS, MB", fill=RSS_COLOUR, font=font)
    draw.text((x1, y0 - 24), "open descriptors", fill=FD_COLOUR, font=font, anchor="ra")
    draw.text(((x0 + x1) / 2, y1 + 30), "render (grey: a fresh mesh)", fill="black", font=font)
    draw.text((x0, y1 + 8), "0", fill="black", font=font)
    draw.text((x1, y1 + 8), str(len(samples) - 1), fill="black", font=font, anchor="ra")
    image.save(path)
