"""POV-Ray 3.7 beside our default engine on every scene, the two taking turns on CPU seconds
(`bench.timing`), and the project's goal (POV-Ray's trace time over ours) judged from the
ratios. A scene's POV-Ray version is its shipped pov/NAME.pov, else one converted from its NFF
(`bench.pov_scene`, in the SPD's own POV-Ray style) into a temporary folder."""

import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.spd_runs import build, default_density, default_storage, run_config
from bench.timing import Turns

# the project's goal (issue 42): POV-Ray's trace time over our default's, on these scenes
GOAL_SCENES = ("balls", "tetra", "gears", "rings", "teapot", "tree", "shells", "jacks")
GOAL_RATIO = 3.0


def find_povray() -> str | None:
    """Path of `povray`, installing the Debian package first if missing and allowed."""
    exe = shutil.which("povray")
    if exe or os.geteuid() != 0 or not shutil.which("apt-get"):
        return exe
    print("povray not found: installing it with apt-get ...", flush=True)
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update"], ["apt-get", "install", "-y", "povray"]):
        if subprocess.run(cmd, env=env, capture_output=True).returncode != 0:
            return None
    return shutil.which("povray")


_POV_PATTERNS = {
    "trace_seconds": r"Trace Time:.*\(([\d.]+) seconds\)",
    # the next line: "using 1 thread(s) with 2.021 CPU-seconds total"
    "cpu_seconds": r"Trace Time:.*\n.*with ([\d.]+) CPU-seconds total",
    "rays": r"^Rays:\s+(\d+)",
    "shadow_rays": r"Shadow Ray Tests:\s+(\d+)",
    "shadow_rays_blocked": r"Shadow Ray Tests:\s+\d+\s+Succeeded:\s+(\d+)",
    "reflected_rays": r"Reflected Rays:\s+(\d+)",
    "refracted_rays": r"Refracted Rays:\s+(\d+)",
}


def parse_povray(text: str) -> dict:
    """Trace time (wall and CPU seconds) and ray statistics from POV-Ray's console output
    (absent counters: 0; an absent trace time or its CPU seconds: an error)."""
    out = {}
    for key, pattern in _POV_PATTERNS.items():
        m = re.search(pattern, text, re.MULTILINE)
        if m is None and key.endswith("seconds"):
            raise RuntimeError(
                "no 'Trace Time:' with its CPU-seconds in POV-Ray output:\n" + text[-2000:]
            )
        out[key] = (float(m.group(1)) if key.endswith("seconds") else int(m.group(1))) if m else 0
    return out


def run_povray(exe: str, pov: Path, repeats: int, between=None) -> dict:
    """Render `pov` at 512x512 on one thread `repeats` times: its trace CPU seconds (median,
    least-most, every run's; its wall trace seconds' median beside them) and counts.
    `between()`, if given, runs after each POV-Ray run and returns our trace CPU seconds: the
    two tracers take turns, so a slow spell of this shared machine falls on both alike, and
    the ratio is the median of each turn's POV-Ray / ours. POV-Ray runs on this process's
    cores (pinned to one by `bench.spd`: a child inherits it)."""
    runs, times = [], Turns()
    with tempfile.TemporaryDirectory(prefix="bench-pov-") as tmp:
        cmd = [
            exe,
            f"+I{pov}",
            f"+O{Path(tmp) / pov.stem}.png",
            "+W512",
            "+H512",
            "-A",
            "+MV3.7",
            "-D",
            "+WT1",
            "+FN",
        ]
        for _ in range(repeats):
            done = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True)
            if done.returncode != 0:
                raise RuntimeError(f"povray failed ({done.returncode}):\n{done.stderr[-2000:]}")
            runs.append(parse_povray(done.stderr + done.stdout))
            times.add("povray", runs[-1]["cpu_seconds"])
            if between is not None:
                times.add("ours", between())
    out = {
        **runs[-1],  # the counts: the same every run
        **times.figure("povray").fields("cpu_seconds"),
        "trace_seconds": statistics.median(r["trace_seconds"] for r in runs),
        "trace_seconds_all": [r["trace_seconds"] for r in runs],
    }
    if between is not None:
        out.update(times.figure("ours").fields("ours_default_cpu_seconds"))
        out.update(times.ratio("povray", "ours").fields("ratio_default"))
    return out


def default_runner(path: Path):
    """A function tracing `path` once with the default engine (built here, once) and returning
    its trace CPU seconds: our turns between POV-Ray's."""
    from host.scene.nff import read_nff

    scene = read_nff(path)
    storage, density = default_storage(), default_density()
    engine = build(scene, "auto", storage, density)
    return lambda: run_config(scene, "auto", storage, density, 1, built=engine)["trace_cpu_seconds"]


def pov_file(scenes: Path, name: str) -> Path | None:
    """The shipped POV-Ray version of scene `name` (<scenes>/pov/NAME.pov), if there is one."""
    pov = scenes / "pov" / f"{name}.pov"
    return pov if pov.exists() else None


GENERATED = "generated from the NFF"  # how a converted POV-Ray version is named in the output


def pov_version(scenes: Path, nff: Path, folder: Path) -> tuple[Path, str]:
    """The POV-Ray version of scene `nff` and where it came from: the shipped file, else one
    converted from the NFF into `folder` (never into the scene folder, which is data)."""
    shipped = pov_file(scenes, nff.stem)
    if shipped is not None:
        return shipped, "shipped"
    from bench.pov_scene import write_pov

    return write_pov(nff, folder), GENERATED


def compare_pov(results: list[dict], scenes: Path, repeat: int) -> dict:
    """POV-Ray figures (`repeat` turns with our default) and pov/ours CPU ratios for every
    scene of `results` (its POV-Ray version: `pov_version`; "pov_source" says which):
    pov/default the median of the turns' paired ratios, pov/best POV-Ray's median over the
    best configuration's best (its own pass, not in turns)."""
    if not results:
        return {}
    exe = find_povray()
    if exe is None:
        print("\nPOV-Ray: unavailable (not on PATH and cannot install); no ratios.")
        return {"available": False}
    out = {"available": True, "executable": exe, "repeat": repeat, "scenes": {}}
    with tempfile.TemporaryDirectory(prefix="bench-pov-scenes-") as folder:
        for r in results:
            print(f"  povray {r['scene']} ...", file=sys.stderr, flush=True)
            path, source = pov_version(scenes, Path(r["file"]), Path(folder))
            ours = default_runner(Path(r["file"]))
            pov = run_povray(exe, path, repeat, between=ours)
            pov["ratio_best"] = pov["cpu_seconds"] / r["best_trace_cpu_seconds"]
            pov["pov_source"] = source
            out["scenes"][r["scene"]] = pov
    return out


def goal(pov: dict) -> dict:
    """Which of GOAL_SCENES meet the goal (POV-Ray over our default >= GOAL_RATIO), which
    miss it, and which were not measured: {"met"|"missed": {scene: ratio}, "absent": [...]}."""
    measured = pov.get("scenes", {}) if pov else {}
    out = {"ratio": GOAL_RATIO, "met": {}, "missed": {}, "absent": []}
    for name in GOAL_SCENES:
        if name not in measured:
            out["absent"].append(name)
        else:
            ratio = measured[name]["ratio_default"]
            out["met" if ratio >= GOAL_RATIO else "missed"][name] = ratio
    return out


def goal_line(g: dict) -> str:
    """The goal in one line, e.g. 'goal POV-Ray/default >= 2.0: met on balls 2.31; not met
    on gears 1.52; not measured: tree'."""
    line = (
        f"goal POV-Ray/default >= {g['ratio']:.1f}: met on {_ratios(g['met'])}; "
        f"not met on {_ratios(g['missed'])}"
    )
    return line + (f"; not measured: {', '.join(g['absent'])}" if g["absent"] else "")


def _ratios(by_scene: dict) -> str:
    """'balls 2.31, tetra 3.02', or 'none'."""
    return ", ".join(f"{k} {v:.2f}" for k, v in by_scene.items()) or "none"
