"""Screenshots of the live view: `host render --serve` in headless Chromium, once mid-render
and once at the end (the pictures in docs/).

    python -m bench.live_view [--mesh 2x2] [--spp 16] [--out docs]

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
from tests.test_live_browser import DONE, EXAMPLE, chromium, wait_for

MID = (
    "return live.status !== null && live.status.progress.fraction >= {:f} && "
    "live.frames > 1 && !live.status.final;"
)


def shoot(browser, path: Path) -> None:
    """A screenshot of the page, as a small palette PNG."""
    raw = path.with_suffix(".raw.png")
    browser.save_screenshot(str(raw))
    image = Image.open(raw).convert("RGB")
    image.quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
        path, optimize=True
    )
    raw.unlink()
    print(f"{path}: {image.width}x{image.height}, {path.stat().st_size / 1000:.0f} kB")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--mesh", default="2x2")
    p.add_argument("--spp", default="16")
    p.add_argument("--size", default="384")
    p.add_argument("--mid", type=float, default=0.4, help="fraction done at the first shot")
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
                "--quiet",
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
            wait_for(browser, MID.format(args.mid), 600)
            shoot(browser, args.out / "live-mid.png")
            wait_for(browser, DONE, 600)
            shoot(browser, args.out / "live-end.png")
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
