"""Screenshots of the live view: `host render --serve` in headless Chromium at about a quarter
and half of the primary rays and at the end (the pictures in docs/).

    python -m bench.live_view [--mesh 2x2] [--size 1024] [--spp 16] [--out docs]

Each shot is taken once the page's own progress reaches its mark; the page's progress, the
share of its canvas filled in and the render's time at the shot are printed (the page shows
a mark a fraction of a second late: a quarter of the showcase's primary rays is sky, cheap).
Needs Chromium, chromedriver and selenium (as the browser test). The PNGs are reduced to a
256-colour palette so they stay small in the repository.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

from tests.test_live import stderr_lines, wait_for_line
from tests.test_live_browser import DONE, EXAMPLE, chromium

AT = (
    "return live.status !== null && live.status.progress.fraction >= {:f} && "
    "live.frames > 0 && !live.status.final;"
)
# The page's progress, the share of its canvas's pixels not black, and its elapsed seconds.
SEEN = """const d = document.getElementById("canvas").getContext("2d")
    .getImageData(0, 0, canvas.width, canvas.height).data;
let lit = 0;
for (let i = 0; i < d.length; i += 4) if (d[i] || d[i + 1] || d[i + 2]) lit++;
const p = live.status.progress;
return [p.fraction, lit / (d.length / 4), p.elapsed_seconds];"""


def shoot(browser, path: Path) -> None:
    """A screenshot of the page, as a small palette PNG, and what the page showed."""
    raw = path.with_suffix(".raw.png")
    browser.save_screenshot(str(raw))
    fraction, lit, elapsed = browser.execute_script(SEEN)
    image = Image.open(raw).convert("RGB")
    image.quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
        path, optimize=True
    )
    raw.unlink()
    print(
        f"{path}: {image.width}x{image.height}, {path.stat().st_size / 1000:.0f} kB; "
        f"page at {100 * fraction:.0f}% of the primary rays, {100 * lit:.0f}% of the canvas "
        f"lit, {elapsed:.1f} s"
    )


def wait_for(browser, script: str, timeout: float) -> None:
    """Until `script` holds, polled every 20 ms (a mark passes quickly)."""
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(browser, timeout, poll_frequency=0.02).until(lambda b: b.execute_script(script))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mesh", default="2x2")
    p.add_argument("--spp", default="16")
    p.add_argument("--size", default="1024")
    p.add_argument("--marks", default="0.25,0.5", help="fractions done at the shots")
    p.add_argument("--out", type=Path, default=Path("docs"))
    args = p.parse_args(argv)
    args.out.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        browser = chromium(Path(tmp) / "profile")
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "host.cli",
                "render",
                str(EXAMPLE),
                "-o",
                str(Path(tmp) / "a.png"),
                "--serve",
                "0",
                "--mesh",
                args.mesh,
                "--spp",
                args.spp,
                "--width",
                args.size,
                "--height",
                args.size,
            ],
            stderr=subprocess.PIPE,
            text=True,
            env=os.environ,
        )
        try:
            lines = stderr_lines(proc)
            url = wait_for_line(lines, "live view at ").split("live view at ")[1].strip()
            browser.get(url)
            for mark in map(float, args.marks.split(",")):
                wait_for(browser, AT.format(mark), 600)
                shoot(browser, args.out / f"live-{round(100 * mark)}.png")
            wait_for(browser, DONE, 600)
            shoot(browser, args.out / "live-end.png")
            print(wait_for_line(lines, " wall ").strip())  # the summary line
            proc.send_signal(signal.SIGINT)
            proc.wait(30)
        finally:
            browser.quit()
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
