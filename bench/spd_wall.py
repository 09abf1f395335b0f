"""Whole-process wall times of `host.cli render --spd`, with a warm and a cold numba cache:
what a user waits for, kernel loading and compiling included, which the in-process runs leave
out."""

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

WALL_SCENES = ("balls", "tetra")  # timed as whole processes too


def wall_time(scene: Path, out_png: Path, env: dict) -> float:
    """Wall seconds of one `python -m host.cli render SCENE --spd --mesh 1x1 --threads 1` process
    (one node in the process: the figure POV-Ray's whole run compares with)."""
    cmd = [
        sys.executable,
        "-m",
        "host.cli",
        "render",
        str(scene),
        "--spd",
        "--mesh",
        "1x1",
        "--threads",
        "1",
        "--quiet",
        "-o",
        str(out_png),
    ]
    start = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return seconds


def wall_times(scene: Path, repeat: int) -> dict:
    """Warm: default numba cache, primed by one run, best of `repeat`. Cold: NUMBA_CACHE_DIR
    set to a fresh empty folder (numba then caches only there), so every kernel compiles."""
    with tempfile.TemporaryDirectory(prefix="bench-wall-") as tmp:
        png = Path(tmp) / f"{scene.stem}.png"
        env = dict(os.environ)
        env.pop("NUMBA_CACHE_DIR", None)
        prime = wall_time(scene, png, env)
        warm = [wall_time(scene, png, env) for _ in range(repeat)]
        cache = Path(tmp) / "numba-cache"
        cache.mkdir()
        cold = wall_time(scene, png, {**env, "NUMBA_CACHE_DIR": str(cache)})
    return {
        "prime_seconds": prime,
        "warm_seconds": min(warm),
        "warm_seconds_all": warm,
        "cold_seconds": cold,
    }
