"""The live view in a real browser (headless Chromium driven by selenium): after `host render
--serve` finishes, the page's canvas holds exactly the PNG the render wrote, and its node
panels show the statistics JSON's figures; in every mode the canvas fills in while fewer than
half the primary rays are traced, the final figures are the command line's and the
statistics', the page fits above the fold and logs no error. Skips without Chromium, fails
without it when MESHTRACE_REQUIRE_BROWSER=1 (CI sets it)."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.conftest import ctrl_c_default
from tests.test_live import WAIT, stderr_lines, wait_for_line

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "host" / "examples" / "showcase.nff"
RAY_KINDS = ("eye_rays", "reflected_rays", "refracted_rays", "shadow_rays")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1200,820",
]
# The canvas's pixels as [width, height, RGBA bytes...], read with getImageData.
CANVAS = """const c = document.getElementById("canvas");
return [c.width, c.height, ...c.getContext("2d").getImageData(0, 0, c.width, c.height).data];"""
DONE = "return live.status !== null && live.status.final && live.drawn === live.status.frame;"


def chromium(profile: Path):
    """A headless Chromium with a fresh profile, or a skip (a failure when CI requires it)."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    try:
        from selenium import webdriver
    except ImportError:
        webdriver = None
    if not (browser and driver and webdriver):
        why = (
            f"no headless browser (chromium: {browser}, chromedriver: {driver}, selenium: "
            f"{'yes' if webdriver else 'no'}); apt-get install chromium chromium-driver"
        )
        if os.environ.get("MESHTRACE_REQUIRE_BROWSER") == "1":
            pytest.fail(why)
        pytest.skip(why)
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in [*FLAGS, f"--user-data-dir={profile}"]:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # console errors
    service = webdriver.ChromeService(executable_path=driver)
    return webdriver.Chrome(options=options, service=service)


def serve(
    tmp_path: Path, *options: str, quiet: bool = True, scene: Path = EXAMPLE
) -> tuple[subprocess.Popen, str]:
    """`host render --serve 0` of the showcase (or `scene`) in a process of its own, and the
    page's URL."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "host.cli",
            "render",
            str(scene),
            "-o",
            str(tmp_path / "a.png"),
            "--stats",
            str(tmp_path / "s.json"),
            *(["--quiet"] if quiet else []),
            "--serve",
            "0",
            *options,
        ],
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
        preexec_fn=ctrl_c_default,
    )
    proc.lines = stderr_lines(proc)
    line = wait_for_line(proc.lines, "live view at ")
    return proc, line.split("live view at ")[1].strip()


def wait_for(browser, script: str, timeout: float) -> None:
    from selenium.webdriver.support.ui import WebDriverWait

    WebDriverWait(browser, timeout, poll_frequency=0.1).until(lambda b: b.execute_script(script))


def children(pid: int) -> list[int]:
    """Processes whose parent is `pid` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


@pytest.mark.parametrize("mesh", ["1x1", "2x2"])
def test_the_page_shows_the_image_and_the_nodes(tmp_path, mesh):
    browser = chromium(tmp_path / "profile")
    proc = None
    try:
        proc, url = serve(
            tmp_path,
            "--mesh",
            mesh,
            "--width",
            "40",
            "--height",
            "30",
            "--spp",
            "2",
            "--mode",
            "object",
        )  # rays cross the links
        browser.get(url)
        wait_for(browser, DONE, WAIT * 6)  # a cold mesh loads its kernels first
        assert browser.execute_script("return document.body.dataset.phase") == "done"

        width, height, *rgba = browser.execute_script(CANVAS)
        png = np.asarray(Image.open(tmp_path / "a.png"))
        page = np.array(rgba, np.uint8).reshape(height, width, 4)
        assert (width, height) == (40, 30)
        np.testing.assert_array_equal(page[..., 3], 255)
        np.testing.assert_array_equal(page[..., :3], png)  # exactly the PNG written

        stats = json.loads((tmp_path / "s.json").read_text())
        nodes = stats.get("nodes") or [
            {"rays": stats["rays"], "links": {}, "objects": stats["engine"]["objects"]}
        ]
        assert len(nodes) == (4 if mesh == "2x2" else 1)
        for n, s in enumerate(nodes):
            panel = f'.node[data-node="{n}"]'
            shown = browser.execute_script(f"""const p = document.querySelector('{panel}');
                return [p.querySelector(".traced").dataset.value,
                        p.querySelector(".objects").dataset.value,
                        [...p.querySelectorAll(".links li")].map(
                            (li) => [li.dataset.peer, li.dataset.rays, li.dataset.bytes])];""")
            links = [
                [p, str(v["rays_sent"]), str(v["bytes_out"])]
                for p, v in sorted(s["links"].items(), key=lambda kv: int(kv[0]))
            ]
            assert shown == [
                str(sum(s["rays"].get(k, 0) for k in RAY_KINDS)),
                str(s["objects"]),
                links,
            ]
        if mesh == "2x2":
            assert sum(s["rays_sent"] for s in nodes) > 0  # rays crossed links: shown above
        assert not children(proc.pid)  # the local mesh is gone; only the page is left
        proc.send_signal(signal.SIGINT)
        assert proc.wait(WAIT) == 0
        wait_for(browser, "return document.body.dataset.closed === '1';", WAIT)
    finally:
        browser.quit()
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()


# The figures of the page's progress line (their exact values), and the node panels' and the
# canvas's places against the window.
FIGURES = """const v = (c) => {
  const e = document.querySelector("#progress-text ." + c);
  return e ? Number(e.dataset.value) : null;
};
return [v("traced"), v("rate"), v("elapsed")];"""
FOLD = """const below = (e) => e.getBoundingClientRect().bottom > window.innerHeight;
return [...document.querySelectorAll(".node, #canvas")].filter(below).length;"""
# Each traces for a few seconds: a page shows new pixels within about a quarter of a second
# (its throttle), and object-space nodes send deposits in packets of 32,768 (on a small image
# their first packet comes late); image space and one process trace fastest, so with more
# samples (one process at 4 spp drew its first pixels at half the rays, 1 run in 9).
SIZE = ["--width", "640", "--height", "640"]
MODES = {
    "one process": ["--mesh", "1x1", "--threads", "2", *SIZE, "--spp", "8"],
    "image space": ["--mesh", "2x2", "--mode", "image", "--tiles", "dynamic", *SIZE, "--spp", "8"],
    "object space": ["--mesh", "2x2", "--mode", "object", *SIZE, "--spp", "4"],
}


def from_above(tmp_path: Path) -> Path:
    """The showcase seen from above: all floor and objects, no sky, so every row costs about
    the same and half the primary rays take about half the time (from the front, the sky's
    cheap rows are half the rays and take a seventh of it: no page could show them in time)."""
    text = EXAMPLE.read_text().replace("from 0 -7 3.2", "from 0 -3 9")
    assert "from 0 -3 9" in text
    scene = tmp_path / "above.nff"
    scene.write_text(text)
    return scene


def expected_figures(stats: dict) -> tuple[int, float, float]:
    """Rays of every kind, rays/s (after setup) and elapsed seconds (the wall's) as the
    statistics give them, one process or a mesh alike."""
    rays = sum(stats["rays"].get(k, 0) for k in RAY_KINDS)
    assert rays == stats["total_rays"]
    trace = stats["wall_seconds"] - stats["setup_seconds"]
    assert trace == pytest.approx(stats["trace_seconds"])
    return rays, rays / trace, stats["wall_seconds"]


def summary_figures(lines) -> tuple[str, str]:
    """(seconds, rays/s) as the command line's summary printed them."""
    text = "".join(drain_all(lines))
    found = re.search(r"wall ([0-9.]+) s  ([0-9]+) rays/s", text)
    assert found, text
    return found.groups()


def drain_all(lines):
    """The lines so far, until the one that says the page stays."""
    while (line := lines.get(timeout=WAIT)) is not None:
        yield line
        if "stays at" in line:
            return


@pytest.mark.parametrize("mode", list(MODES))
def test_the_canvas_fills_in_and_ends_on_the_summary_figures(tmp_path, mode):
    """The first frame the page drew with rendered pixels was copied by the server before half
    the primary rays were traced (its progress then, which a page drawing late under load does
    not change); at the end the page's elapsed seconds, rays and rays/s are the statistics'
    and the summary line's."""
    browser = chromium(tmp_path / "profile")
    proc = None
    try:
        proc, url = serve(tmp_path, *MODES[mode], quiet=False, scene=from_above(tmp_path))
        browser.get(url)
        wait_for(browser, DONE, WAIT * 6)  # a cold mesh loads its kernels first
        first = browser.execute_script("return live.firstPixels;")
        assert first is not None and first["phase"] == "tracing"
        # When the server copied the pixels, not when a page under load drew them.
        assert first["copied"] is not None and first["copied"] < first["total"] / 2, first

        stats = json.loads((tmp_path / "s.json").read_text())
        rays, rate, seconds = expected_figures(stats)
        assert browser.execute_script(FIGURES) == [rays, rate, seconds]
        printed = summary_figures(proc.lines)
        assert printed == (f"{seconds:.3f}", f"{rate:.0f}")  # one summary line, any mode

        assert browser.execute_script(FOLD) == 0  # every node and the image above the fold
        errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
        assert not errors
        proc.send_signal(signal.SIGINT)
        assert proc.wait(WAIT) == 0
    finally:
        browser.quit()
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
