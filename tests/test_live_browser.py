"""The live view in a real browser (headless Chromium driven by selenium): after `host render
--serve` finishes, the page's canvas holds exactly the PNG the render wrote, and its node
panels show the statistics JSON's figures. Skips without Chromium, fails without it when
MESHTRACE_REQUIRE_BROWSER=1 (CI sets it)."""

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

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
    service = webdriver.ChromeService(executable_path=driver)
    return webdriver.Chrome(options=options, service=service)


def serve(tmp_path: Path, *options: str) -> tuple[subprocess.Popen, str]:
    """`host render --serve 0` of the showcase in a process of its own, and the page's URL."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "host.cli",
            "render",
            str(EXAMPLE),
            "-o",
            str(tmp_path / "a.png"),
            "--stats",
            str(tmp_path / "s.json"),
            "--quiet",
            "--serve",
            "0",
            *options,
        ],
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=os.environ | {"PYTHONPATH": str(ROOT)},
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
