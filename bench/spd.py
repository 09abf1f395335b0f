"""SPD benchmark: every NFF scene at 512x512 on one thread, per grid storage and density, with
POV-Ray 3.7 side by side and whole-process wall times (warm and cold numba cache).

    python -m bench.spd [--scenes DIR] [--only balls,tetra] [--densities 1,2,4] [--repeat 3]
                        [--json FILE] [--no-pov] [--no-wall]
    python -m bench.spd --scaling [tetra:1-10,balls:1-6] [--size 512] [--repeat 3] [--json FILE]

Tracing times exclude kernel loading (`render` warms up first) and preprocessing; rays/s is
all rays (eye, reflected, refracted, shadow) over the best tracing time.

--scaling needs no scene folder: it generates SPD tetra and balls at growing size factors
(`bench.generate`: 4^n triangles, 1 + 9 + ... + 9^n spheres) and prints tracing time against
scene size with the default grid (storage auto, default density), one thread; the growth
column is time per ray over the smallest size factor's.
"""

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
POV_SCENES = ("balls", "tetra")  # also the scenes timed best-of-N and as whole processes
STORAGES = ("csr", "hash")
COUNT_KEYS = ("eye_rays", "eye_hits", "reflected_rays", "refracted_rays", "shadow_rays",
              "shadow_rays_blocked")  # fmt: skip
COUNT_LABELS = ("eye", "hits", "reflected", "refracted", "shadow", "blocked")
DEFAULT_SCALING = "tetra:1-10,balls:1-6"  # 4 .. 1,048,576 triangles, 10 .. 597,871 spheres
# The figures of run_config that a scaling row keeps.
SCALING_KEYS = ("used_storage", "resolution", "trace_seconds", "trace_seconds_all",
                "total_rays", "rays_per_second", "tests_per_ray", "steps_per_ray",
                "structure_bytes", "variant")  # fmt: skip

if __package__ in (None, ""):  # run as `python bench/spd.py`
    sys.path.insert(0, str(ROOT))


def default_density() -> float:
    """The density `host render` uses when not told."""
    from protocols.render import EngineSpec
    from protocols.spec import default

    return default(EngineSpec, "density")


class CountMismatchError(AssertionError):
    """Ray counts differ between grid configurations of one scene (an engine bug)."""


# ---------------------------------------------------------------------------- arguments


def parse_args(argv=None) -> argparse.Namespace:
    """Command line options."""
    p = argparse.ArgumentParser(prog="bench.spd", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=Path, default=DEFAULT_SCENES, help="folder of *.nff")
    p.add_argument("--only", help="comma-separated scene names (default: all)")
    p.add_argument("--densities", default="0.5,1,2", help="grid densities (default 0.5,1,2)")
    p.add_argument("--repeat", type=int, default=3,
                   help="best of N tracing runs for balls and tetra (default 3)")  # fmt: skip
    p.add_argument("--json", type=Path, help="write all figures to this JSON file")
    p.add_argument("--no-pov", action="store_true", help="skip the POV-Ray comparison")
    p.add_argument("--no-wall", action="store_true", help="skip whole-process wall times")
    p.add_argument("--scaling", nargs="?", const=DEFAULT_SCALING, metavar="SCENE:N-M,...",
                   help="only the scaling table: generated tetra/balls at size factors N..M "
                   f"(default {DEFAULT_SCALING})")  # fmt: skip
    p.add_argument("--size", type=int, default=512,
                   help="image side for --scaling (SPD corner rays; default 512)")  # fmt: skip
    args = p.parse_args(argv)
    args.densities = [float(d) for d in args.densities.split(",") if d.strip()]
    if args.repeat < 1 or not args.densities or args.size < 1:
        p.error("--repeat and --size must be >= 1 and --densities non-empty")
    if args.scaling is not None:
        try:
            args.scaling = parse_scaling(args.scaling)
        except ValueError as e:
            p.error(f"--scaling: {e}")
    return args


def parse_scaling(spec: str) -> list[tuple[str, list[int]]]:
    """'tetra:1-8,balls:3' -> [('tetra', [1, ..., 8]), ('balls', [3])]."""
    from bench.generate import GENERATORS

    plan = []
    for item in filter(None, (x.strip() for x in spec.split(","))):
        name, _, sizes = item.partition(":")
        if name not in GENERATORS:
            raise ValueError(f"no generator for {name!r} (have {', '.join(GENERATORS)})")
        lo, _, hi = sizes.partition("-")
        try:
            lo, hi = int(lo), int(hi or lo)
        except ValueError:
            raise ValueError(f"{item!r}: expected SCENE:N or SCENE:N-M") from None
        if not 1 <= lo <= hi:
            raise ValueError(f"{item!r}: size factors must be 1 <= N <= M")
        plan.append((name, list(range(lo, hi + 1))))
    if not plan:
        raise ValueError("no scenes")
    return plan


def scene_files(folder: Path, only: str | None) -> list[Path]:
    """The *.nff files of `folder`, restricted to the names in `only` if given."""
    files = sorted(folder.glob("*.nff"))
    if only:
        names = [n.strip() for n in only.split(",") if n.strip()]
        missing = sorted(set(names) - {f.stem for f in files})
        if missing:
            raise SystemExit(f"bench.spd: no such scene in {folder}: {', '.join(missing)}")
        files = [f for f in files if f.stem in names]
    if not files:
        raise SystemExit(f"bench.spd: no *.nff scenes in {folder}")
    return files


# ---------------------------------------------------------------------------- in-process runs


def warm_kernels(scene) -> dict:
    """Load grid-build, eye-ray and tracing kernels for both storages on a coarse grid, so the
    first measured configuration pays no kernel loading; returns the load seconds per storage."""
    from meshnode.engine import Engine
    from meshnode.engine.camera import eye_rays
    from protocols.render import ImageSpec

    eye_rays(scene.view, ImageSpec(spd=True).sized(scene.view), rows=(0, 1))
    loads = {}
    for storage in STORAGES:
        start = time.perf_counter()
        Engine(scene, density=0.05, storage=storage).warmup()
        loads[storage] = time.perf_counter() - start
    return loads


def run_config(scene, storage: str, density: float, repeats: int, built=None,
               size: int | None = None) -> dict:  # fmt: skip
    """Render `repeats` times with one grid configuration; keep the best tracing time.
    `built`: that configuration's engine, reused (a big scene's grid is built once);
    `size`: image side under the SPD rules (default 512)."""
    from host.render import render
    from protocols.render import EngineSpec, ImageSpec

    image = ImageSpec(spd=True, width=size, height=size)
    engine = EngineSpec(threads=1, storage=storage, density=density)
    runs = [render(scene, image, engine, built=built)[1] for _ in range(repeats)]
    best = min(runs, key=lambda s: s["trace_seconds"])
    grid = best["engine"]["grid"]
    return {
        "storage": storage,
        "used_storage": grid["storage"],
        "density": density,
        "resolution": grid["resolution"],
        "preprocess_seconds": min(s["preprocess_seconds"] for s in runs),
        "trace_seconds": best["trace_seconds"],
        "trace_seconds_all": [s["trace_seconds"] for s in runs],
        "total_rays": best["total_rays"],
        "rays_per_second": best["total_rays"] / best["trace_seconds"],
        "tests_per_ray": best["tests_per_ray"],
        "steps_per_ray": best["steps_per_ray"],
        "structure_bytes": grid["structure_bytes"],
        "kernel_load_seconds": best["engine"].get("kernel_load_seconds"),
        "rays": best["rays"],
        "variant": best["engine"]["kernel_variant"],
    }


def check_counts(name: str, configs: list[dict]) -> tuple[str | None, list[str]]:
    """Compare the printed ray counts across configurations: a mismatch message (None when
    they agree), and warnings for other counters that differ."""
    counts = [{k: c["rays"][k] for k in COUNT_KEYS} for c in configs]
    error = None
    if any(c != counts[0] for c in counts):
        lines = [f"  {_label(c)}: {n}" for c, n in zip(configs, counts, strict=True)]
        error = f"{name}: ray counts differ between grids:\n" + "\n".join(lines)
    warnings = []
    for key in sorted(set(configs[0]["rays"]) - set(COUNT_KEYS)):
        values = {_label(c): c["rays"].get(key) for c in configs}
        if len(set(values.values())) > 1:
            warnings.append(f"{name}: counter {key} differs between grids: {values}")
    return error, warnings


def bench_scene(path: Path, densities: list[float], repeat: int) -> dict:
    """All grid configurations of one scene plus the default (storage auto, default density)."""
    from host.nff import read_nff

    scene = read_nff(path)
    repeats = repeat if path.stem in POV_SCENES else 1
    loads = warm_kernels(scene)
    plan = [(s, d) for s in STORAGES for d in densities] + [("auto", default_density())]
    configs = [run_config(scene, s, d, repeats) for s, d in plan]
    error, warnings = check_counts(path.stem, configs)
    best = min(configs, key=lambda c: c["trace_seconds"])
    return {
        "scene": path.stem,
        "file": str(path),
        "objects": scene.n_objects,
        "repeats": repeats,
        "kernel_load_seconds": loads,
        "counts": {k: configs[-1]["rays"][k] for k in COUNT_KEYS},  # the default's
        "count_error": error,
        "configs": configs,
        "best": _label(best),
        "best_trace_seconds": best["trace_seconds"],
        "default_trace_seconds": configs[-1]["trace_seconds"],
        "warnings": warnings,
    }


def _label(c: dict) -> str:
    """Short configuration name, e.g. 'hash d2' or 'auto(csr) d2'."""
    storage = c["storage"] if c["storage"] != "auto" else f"auto({c['used_storage']})"
    return f"{storage} d{c['density']:g}"


# ---------------------------------------------------------------------------- scaling


def scaling_row(name: str, n: int, size: int, repeat: int) -> dict:
    """One generated scene: its engine built once with the default grid and its kernels
    loaded before anything is timed, then the best of `repeat` SPD renders."""
    from bench.generate import GENERATORS
    from meshnode.engine import Engine
    from protocols.render import EngineSpec
    from protocols.spec import default

    start = time.perf_counter()
    scene = GENERATORS[name](n)
    generate_seconds = time.perf_counter() - start
    storage, density = default(EngineSpec, "storage"), default_density()
    engine = Engine(scene, density=density, storage=storage)
    load = engine.warmup()
    c = run_config(scene, storage, density, repeat, built=engine, size=size)
    return {"scene": name, "size_factor": n, "objects": scene.n_objects,
            "generate_seconds": generate_seconds, "build_seconds": engine.preprocess_seconds,
            "kernel_load_seconds": load, **{k: c[k] for k in SCALING_KEYS},
            "seconds_per_ray": c["trace_seconds"] / c["total_rays"]}  # fmt: skip


def bench_scaling(plan: list[tuple[str, list[int]]], size: int, repeat: int) -> list[dict]:
    """Rows of every scene and size factor; `growth` is time per ray over the scene's first
    (smallest) size factor's, the figure that shows how cost follows scene size."""
    from bench.generate import GENERATORS

    rows = []
    for name, sizes in plan:
        warm_kernels(GENERATORS[name](sizes[0]))  # build seconds then exclude grid kernels
        first = None
        for n in sizes:
            print(f"  {name} size factor {n} ...", file=sys.stderr, flush=True)
            row = scaling_row(name, n, size, repeat)
            first = first or row
            row["growth"] = row["seconds_per_ray"] / first["seconds_per_ray"]
            rows.append(row)
        print_scaling([r for r in rows if r["scene"] == name])
    return rows


def growth_exponent(rows: list[dict]) -> float | None:
    """a in time per ray ~ objects^a between the first and last rows of one scene."""
    objects = rows[-1]["objects"] / rows[0]["objects"]
    return math.log(rows[-1]["growth"]) / math.log(objects) if objects > 1 else None


def print_scaling(rows: list[dict]) -> None:
    """The scaling table of one scene and its growth in one line."""
    name = rows[0]["scene"]
    print(f"\n== {name}  (generated SPD {name}; default grid; best of "
          f"{len(rows[0]['trace_seconds_all'])})")  # fmt: skip
    headers = ["n", "objects", "gen s", "build s", "grid", "storage", "trace s", "rays",
               "Mrays/s", "us/ray", "tests/ray", "steps/ray", "growth"]  # fmt: skip
    body = [[r["size_factor"], f"{r['objects']:,}", f"{r['generate_seconds']:.2f}",
             f"{r['build_seconds']:.2f}", "x".join(map(str, r["resolution"])), r["used_storage"],
             f"{r['trace_seconds']:.3f}", f"{r['total_rays']:,}",
             f"{r['rays_per_second'] / 1e6:.3f}", f"{r['seconds_per_ray'] * 1e6:.3f}",
             f"{r['tests_per_ray']:.2f}", f"{r['steps_per_ray']:.2f}", f"{r['growth']:.2f}"]
            for r in rows]  # fmt: skip
    print(table(headers, body))
    a = growth_exponent(rows)
    if a is not None:
        print(f"{name}: {rows[-1]['objects'] / rows[0]['objects']:,.0f}x the objects, "
              f"{rows[-1]['growth']:.2f}x the time per ray (objects^{a:.3f})")  # fmt: skip
    sys.stdout.flush()


def main_scaling(args: argparse.Namespace) -> int:
    """--scaling: the table for generated scenes only (no scene folder, no POV-Ray)."""
    plan = ", ".join(f"{name} {sizes[0]}-{sizes[-1]}" for name, sizes in args.scaling)
    print(f"SPD scaling: generated {plan}; {args.size}x{args.size} SPD image "
          f"({args.size + 1}x{args.size + 1} corner rays), depth 5, 1 thread, storage auto, "
          f"density {default_density():g}; best of {args.repeat}")  # fmt: skip
    rows = bench_scaling(args.scaling, args.size, args.repeat)
    if args.json:
        data = {"size": args.size, "repeat": args.repeat, "threads": 1,
                "density": default_density(), "rows": rows}  # fmt: skip
        args.json.write_text(json.dumps({"scaling": data}, indent=2) + "\n")
        print(f"figures written to {args.json}")
    return 0


# ---------------------------------------------------------------------------- POV-Ray


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
    "rays": r"^Rays:\s+(\d+)",
    "shadow_rays": r"Shadow Ray Tests:\s+(\d+)",
    "shadow_rays_blocked": r"Shadow Ray Tests:\s+\d+\s+Succeeded:\s+(\d+)",
    "reflected_rays": r"Reflected Rays:\s+(\d+)",
    "refracted_rays": r"Refracted Rays:\s+(\d+)",
}


def parse_povray(text: str) -> dict:
    """Trace time and ray statistics from POV-Ray's console output (absent counters: 0)."""
    out = {}
    for key, pattern in _POV_PATTERNS.items():
        m = re.search(pattern, text, re.MULTILINE)
        out[key] = (float(m.group(1)) if key == "trace_seconds" else int(m.group(1))) if m else 0
    if "Trace Time:" not in text:
        raise RuntimeError("no 'Trace Time:' in POV-Ray output:\n" + text[-2000:])
    return out


def run_povray(exe: str, pov: Path, repeats: int) -> dict:
    """Render `pov` at 512x512 on one thread `repeats` times; best trace time and counts."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench-pov-") as tmp:
        cmd = [exe, f"+I{pov}", f"+O{Path(tmp) / pov.stem}.png", "+W512", "+H512", "-A",
               "+MV3.7", "-D", "+WT1", "+FN"]  # fmt: skip
        for _ in range(repeats):
            done = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True)
            if done.returncode != 0:
                raise RuntimeError(f"povray failed ({done.returncode}):\n{done.stderr[-2000:]}")
            runs.append(parse_povray(done.stderr + done.stdout))
    best = min(runs, key=lambda r: r["trace_seconds"])
    return {**best, "trace_seconds_all": [r["trace_seconds"] for r in runs]}


def compare_pov(results: list[dict], scenes: Path, repeat: int) -> dict:
    """POV-Ray figures and pov/ours ratios for the POV scenes among `results`."""
    wanted = [r for r in results if r["scene"] in POV_SCENES]
    if not wanted:
        return {}
    exe = find_povray()
    if exe is None:
        print("\nPOV-Ray: unavailable (not on PATH and cannot install); no ratios.")
        return {"available": False}
    out = {"available": True, "executable": exe, "scenes": {}}
    for r in wanted:
        pov = run_povray(exe, scenes / "pov" / f"{r['scene']}.pov", repeat)
        pov["ratio_best"] = pov["trace_seconds"] / r["best_trace_seconds"]
        pov["ratio_default"] = pov["trace_seconds"] / r["default_trace_seconds"]
        out["scenes"][r["scene"]] = pov
    return out


# ---------------------------------------------------------------------------- whole process


def wall_time(scene: Path, out_png: Path, env: dict) -> float:
    """Wall seconds of one `python -m host.cli render SCENE --spd --mesh 1x1 --threads 1` process
    (one node in the process: the figure POV-Ray's whole run compares with)."""
    cmd = [sys.executable, "-m", "host.cli", "render", str(scene), "--spd", "--mesh", "1x1",
           "--threads", "1", "--quiet", "-o", str(out_png)]  # fmt: skip
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
    return {"prime_seconds": prime, "warm_seconds": min(warm), "warm_seconds_all": warm,
            "cold_seconds": cold}  # fmt: skip


# ---------------------------------------------------------------------------- printing


def table(headers: list[str], rows: list[list[str]]) -> str:
    """Right-aligned text table."""
    widths = [max(len(str(x)) for x in col) for col in zip(headers, *rows, strict=True)]
    lines = [headers, ["-" * w for w in widths], *rows]
    return "\n".join("  ".join(str(x).rjust(w) for x, w in zip(ln, widths, strict=True))
                     for ln in lines)  # fmt: skip


def print_scene(r: dict) -> None:
    """Counts line and per-configuration table of one scene; counts go into the table (and a
    mismatch is flagged) when they differ between configurations."""
    c = r["counts"]
    loads = ", ".join(f"{k} {v:.2f} s" for k, v in r["kernel_load_seconds"].items())
    print(f"\n== {r['scene']}  ({r['objects']} objects, best of {r['repeats']}; "
          f"kernel load {loads})")  # fmt: skip
    pairs = list(zip(COUNT_LABELS, COUNT_KEYS, strict=True))
    if r["count_error"] is None:
        print("rays (identical for every grid): " + "  ".join(f"{lab} {c[k]}" for lab, k in pairs))
    headers = ["storage", "dens", "grid", "prep s", "trace s", "Mrays/s", "tests/ray",
               "steps/ray", "struct bytes"]  # fmt: skip
    rows = [[_label(x).split(" ")[0], f"{x['density']:g}", "x".join(map(str, x["resolution"])),
             f"{x['preprocess_seconds']:.3f}", f"{x['trace_seconds']:.3f}",
             f"{x['rays_per_second'] / 1e6:.3f}", f"{x['tests_per_ray']:.2f}",
             f"{x['steps_per_ray']:.2f}", f"{x['structure_bytes']:,}"]
            for x in r["configs"]]  # fmt: skip
    if r["count_error"] is not None:
        headers += [lab for lab, _ in pairs]
        rows = [row + [x["rays"][k] for _, k in pairs] for row, x in zip(rows, r["configs"],
                                                                         strict=True)]
    print(table(headers, rows))
    if r["count_error"] is not None:
        print("COUNT MISMATCH: the ray counts differ between grid configurations (engine bug)")
    for w in r["warnings"]:
        print("WARNING:", w)


def print_pov(results: list[dict], pov: dict) -> None:
    """Side-by-side tracing times and shadow/reflection counts against POV-Ray."""
    if not pov.get("available"):
        return
    print("\n== POV-Ray 3.7 side by side (512x512, 1 thread, trace time only)")
    headers = ["scene", "ours best", "config", "ours default", "povray", "pov/best",
               "pov/default", "shadow ours", "pov", "blocked ours", "pov", "refl ours", "pov"]
    rows = []
    for r in results:
        p = pov["scenes"].get(r["scene"])
        if p is None:
            continue
        c = r["counts"]
        rows.append([r["scene"], f"{r['best_trace_seconds']:.3f}", r["best"],
                     f"{r['default_trace_seconds']:.3f}", f"{p['trace_seconds']:.3f}",
                     f"{p['ratio_best']:.2f}", f"{p['ratio_default']:.2f}",
                     c["shadow_rays"], p["shadow_rays"], c["shadow_rays_blocked"],
                     p["shadow_rays_blocked"], c["reflected_rays"], p["reflected_rays"]])
    print(table(headers, rows))
    print("(ratio > 1: we are faster; ours traces 513x513 corner rays, POV-Ray 512x512 centres"
          f" with adc_bailout; default = storage auto, density {default_density():g})")


def print_wall(wall: dict) -> None:
    """Whole-process wall seconds, warm and cold numba cache."""
    if not wall:
        return
    print("\n== whole process: python -m host.cli render SCENE --spd --mesh 1x1 --threads 1"
          " --quiet")
    rows = [[name, f"{w['warm_seconds']:.2f}", f"{w['cold_seconds']:.2f}"]
            for name, w in wall.items()]  # fmt: skip
    print(table(["scene", "warm cache s", "cold cache s"], rows))


def print_summary(results: list[dict], pov: dict, wall: dict) -> None:
    """One line per POV scene: ratios and wall times."""
    print("\n== summary")
    for r in results:
        p = pov.get("scenes", {}).get(r["scene"]) if pov else None
        w = wall.get(r["scene"])
        if p is None and w is None:
            continue
        parts = [f"{r['scene']}: ours {r['best_trace_seconds']:.3f} s ({r['best']}), "
                 f"default {r['default_trace_seconds']:.3f} s"]
        if p:
            parts.append(f"POV-Ray {p['trace_seconds']:.3f} s -> pov/ours {p['ratio_best']:.2f}"
                         f" best, {p['ratio_default']:.2f} default")
        if w:
            parts.append(f"process warm {w['warm_seconds']:.2f} s, cold {w['cold_seconds']:.2f} s")
        print("; ".join(parts))
    total = sum(r["best_trace_seconds"] for r in results)
    print(f"all {len(results)} scenes: best tracing times sum to {total:.3f} s")


# ---------------------------------------------------------------------------- main


def main(argv=None) -> int:
    """Run the benchmark, print it, optionally write JSON."""
    args = parse_args(argv)
    if args.scaling is not None:
        return main_scaling(args)
    files = scene_files(args.scenes, args.only)
    print(f"SPD benchmark: {len(files)} scenes from {args.scenes}, 512x512 corner rays, depth 5, "
          f"1 thread; densities {args.densities}; best of {args.repeat} for "
          f"{', '.join(POV_SCENES)}")  # fmt: skip
    results = []
    for path in files:
        results.append(bench_scene(path, args.densities, args.repeat))
        print_scene(results[-1])
        sys.stdout.flush()
    pov = {} if args.no_pov else compare_pov(results, args.scenes, args.repeat)
    print_pov(results, pov)
    wall = {} if args.no_wall else {p.stem: wall_times(p, args.repeat) for p in files
                                    if p.stem in POV_SCENES}  # fmt: skip
    print_wall(wall)
    print_summary(results, pov, wall)
    if args.json:
        data = {"densities": args.densities, "repeat": args.repeat, "scenes": results,
                "povray": pov, "wall": wall}  # fmt: skip
        args.json.write_text(json.dumps(data, indent=2) + "\n")
        print(f"figures written to {args.json}")
    errors = [r["count_error"] for r in results if r["count_error"]]
    if errors:
        raise CountMismatchError("\n".join(errors))
    return 0


if __name__ == "__main__":
    sys.exit(main())
