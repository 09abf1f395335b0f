"""SPD benchmark: every NFF scene at 512x512 on one thread, per acceleration structure (the
grid per storage and density, the hierarchy, and the default: structure auto), with POV-Ray 3.7
side by side on every scene that has a pov/NAME.pov, the default's ray counts against the SPD
author's published table, and whole-process wall times (warm and cold numba cache).

    python -m bench.spd [--scenes DIR] [--only balls,tetra] [--structures grid,bvh]
                        [--densities 1,2,4] [--repeat 3] [--json FILE] [--no-pov] [--no-wall]
    python -m bench.spd --scaling [tetra:1-10,balls:1-6] [--size 512] [--repeat 3] [--json FILE]

Tracing times exclude kernel loading (`render` warms up first) and preprocessing; rays/s is
all rays (eye, reflected, refracted, shadow) over the best tracing time. Ray counts must be
identical in every configuration of a scene: grid and hierarchy are both exact.

--scaling needs no scene folder: it generates SPD tetra and balls at growing size factors
(`bench.generate`: 4^n triangles, 1 + 9 + ... + 9^n spheres) and prints tracing time against
scene size for the grid (storage auto, default density) and the default (structure auto) side
by side, one thread; the growth columns are time per ray over the smallest size factor's.
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
WALL_SCENES = ("balls", "tetra")  # timed as whole processes too
GOAL_SCENES = ("balls", "tetra", "gears", "rings", "teapot", "tree")
GOAL_RATIO = 2.0  # the project's goal: POV-Ray's trace time over our default's
STORAGES = ("csr", "hash")
STRUCTURES = ("grid", "bvh", "auto")  # --structures; the default (auto) always runs
# The SPD author's published counts (scenes README) are checked to this relative difference;
# teapot's generator has changed since the table was made.
PUBLISHED_TOLERANCE = {"teapot": 0.005}
TOLERANCE = 0.001
PUBLISHED_COLUMNS = {
    "eye rays that hit": "eye_hits",
    "reflected rays": "reflected_rays",
    "refracted rays": "refracted_rays",
    "shadow rays": "shadow_rays",
}
COUNT_KEYS = (
    "eye_rays",
    "eye_hits",
    "reflected_rays",
    "refracted_rays",
    "shadow_rays",
    "shadow_rays_blocked",
)
COUNT_LABELS = ("eye", "hits", "reflected", "refracted", "shadow", "blocked")
DEFAULT_SCALING = "tetra:1-10,balls:1-6"  # 4 .. 1,048,576 triangles, 10 .. 597,871 spheres
# The structures --scaling compares, and the figures of run_config that a scaling run keeps.
SCALING_STRUCTURES = ("grid", "auto")
SCALING_KEYS = (
    "label",
    "structure",
    "used_structure",
    "structure_reason",
    "used_storage",
    "resolution",
    "bvh",
    "trace_seconds",
    "trace_seconds_all",
    "total_rays",
    "rays_per_second",
    "tests_per_ray",
    "steps_per_ray",
    "structure_bytes",
    "variant",
    "rays",
)

if __package__ in (None, ""):  # run as `python bench/spd.py`
    sys.path.insert(0, str(ROOT))

from bench import add_scenes_option  # noqa: E402 (after the path is set)


def default_density() -> float:
    """The density `host render` uses when not told."""
    from protocols.render import EngineSpec
    from protocols.spec import default

    return default(EngineSpec, "density")


def default_storage() -> str:
    """The grid storage `host render` uses when not told."""
    from protocols.render import EngineSpec
    from protocols.spec import default

    return default(EngineSpec, "storage")


class CountMismatchError(AssertionError):
    """Ray counts differ between configurations of one scene (an engine bug: grid and
    hierarchy are both exact)."""


# ---------------------------------------------------------------------------- arguments


def parse_args(argv=None) -> argparse.Namespace:
    """Command line options."""
    p = argparse.ArgumentParser(prog="bench.spd", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", help="comma-separated scene names (default: all)")
    p.add_argument(
        "--structures",
        default=",".join(STRUCTURES),
        help="which of grid (every storage x density), bvh, auto to run (default "
        "all; auto, the default the POV-Ray ratios are about, always runs)",
    )
    p.add_argument("--densities", default="0.5,1,2", help="grid densities (default 0.5,1,2)")
    p.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="best of N for scenes with a pov/NAME.pov, POV-Ray's and ours, "
        "and for --scaling (default 3)",
    )
    p.add_argument("--json", type=Path, help="write all figures to this JSON file")
    p.add_argument("--no-pov", action="store_true", help="skip the POV-Ray comparison")
    p.add_argument("--no-wall", action="store_true", help="skip whole-process wall times")
    p.add_argument(
        "--scaling",
        nargs="?",
        const=DEFAULT_SCALING,
        metavar="SCENE:N-M,...",
        help="only the scaling table: generated tetra/balls at size factors N..M "
        f"(default {DEFAULT_SCALING})",
    )
    p.add_argument(
        "--size",
        type=int,
        default=512,
        help="image side for --scaling (SPD corner rays; default 512)",
    )
    args = p.parse_args(argv)
    args.densities = [float(d) for d in args.densities.split(",") if d.strip()]
    args.structures = [s.strip() for s in args.structures.split(",") if s.strip()]
    if not set(args.structures) <= set(STRUCTURES):
        p.error(f"--structures: choose among {', '.join(STRUCTURES)}")
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
    """Load grid-build, eye-ray and tracing kernels for both storages on a coarse grid and for
    the hierarchy, so the first measured configuration pays no kernel loading; returns the load
    seconds per storage and 'bvh' (the grid is asked for: auto might build a hierarchy)."""
    from meshnode.engine import Engine
    from meshnode.engine.camera import eye_rays
    from protocols.render import ImageSpec

    eye_rays(scene.view, ImageSpec(spd=True).sized(scene.view), rows=(0, 1))
    loads = {}
    for name, kw in [
        *((s, {"structure": "grid", "storage": s, "density": 0.05}) for s in STORAGES),
        ("bvh", {"structure": "bvh"}),
    ]:
        start = time.perf_counter()
        Engine(scene, **kw).warmup()
        loads[name] = time.perf_counter() - start
    return loads


def config_plan(structures: list[str], densities: list[float]) -> list[tuple[str, str, float]]:
    """(structure, storage, density) of each configuration of one scene: the grid's storages x
    densities, the hierarchy (storage and density unused), and last always the default."""
    plan = [("grid", s, d) for s in STORAGES for d in densities] if "grid" in structures else []
    if "bvh" in structures:
        plan.append(("bvh", default_storage(), default_density()))
    return plan + [("auto", default_storage(), default_density())]


def build(scene, structure: str, storage: str, density: float):
    """The engine of one configuration, built once for all its repeats (SPD shells' grid
    takes tens of seconds to build)."""
    from meshnode.engine import Engine

    return Engine(scene, structure=structure, storage=storage, density=density)


def run_config(
    scene,
    structure: str,
    storage: str,
    density: float,
    repeats: int,
    built=None,
    size: int | None = None,
) -> dict:
    """Render `repeats` times with one configuration; keep the best tracing time.
    `built`: that configuration's engine, reused (a big scene's structure is built once);
    `size`: image side under the SPD rules (default 512)."""
    from host.run.oneprocess import render
    from protocols.render import EngineSpec, ImageSpec

    image = ImageSpec(spd=True, width=size, height=size)
    engine = EngineSpec(threads=1, structure=structure, storage=storage, density=density)
    runs = [render(scene, image, engine, built=built)[1] for _ in range(repeats)]
    best = min(runs, key=lambda s: s["trace_seconds"])
    stats = best["engine"]
    is_grid = stats["structure"] == "grid"  # a hierarchy's grid is only a one-voxel box
    c = {
        "structure": structure,
        "used_structure": stats["structure"],
        "structure_reason": stats["structure_reason"],
        "storage": storage,
        "used_storage": stats["grid"]["storage"] if is_grid else None,
        "density": density,
        "resolution": stats["grid"]["resolution"] if is_grid else None,
        "bvh": stats["bvh"],
        "preprocess_seconds": min(s["preprocess_seconds"] for s in runs),  # one if built
        "trace_seconds": best["trace_seconds"],
        "trace_seconds_all": [s["trace_seconds"] for s in runs],
        "total_rays": best["total_rays"],
        "rays_per_second": best["total_rays"] / best["trace_seconds"],
        "tests_per_ray": best["tests_per_ray"],
        "steps_per_ray": best["steps_per_ray"],
        "structure_bytes": stats["structure_bytes"],
        "kernel_load_seconds": stats.get("kernel_load_seconds"),
        "rays": best["rays"],
        "variant": stats["kernel_variant"],
    }
    return {"label": _label(c), **c}


def check_counts(name: str, configs: list[dict]) -> tuple[str | None, list[str]]:
    """Compare the printed ray counts across configurations: a mismatch message (None when
    they agree), and warnings for other counters that differ."""
    counts = [{k: c["rays"][k] for k in COUNT_KEYS} for c in configs]
    error = None
    if any(c != counts[0] for c in counts):
        lines = [f"  {c['label']}: {n}" for c, n in zip(configs, counts, strict=True)]
        error = f"{name}: ray counts differ between configurations:\n" + "\n".join(lines)
    warnings = []
    for key in sorted(set(configs[0]["rays"]) - set(COUNT_KEYS)):
        values = {c["label"]: c["rays"].get(key) for c in configs}
        if len(set(values.values())) > 1:
            warnings.append(f"{name}: counter {key} differs between configurations: {values}")
    return error, warnings


def bench_scene(path: Path, plan: list[tuple[str, str, float]], repeats: int) -> dict:
    """Every configuration of `plan` on one scene, best of `repeats` each; the last is the
    default (structure auto, storage auto, default density)."""
    from host.scene.nff import read_nff
    from meshnode.engine.counters import spd_counts

    scene = read_nff(path)
    loads = warm_kernels(scene)
    configs = [run_config(scene, *c, repeats, built=build(scene, *c)) for c in plan]
    error, warnings = check_counts(path.stem, configs)
    best, dflt = min(configs, key=lambda c: c["trace_seconds"]), configs[-1]
    return {
        "scene": path.stem,
        "file": str(path),
        "objects": scene.n_objects,
        "repeats": repeats,
        "kernel_load_seconds": loads,
        "counts": {k: dflt["rays"][k] for k in COUNT_KEYS},  # the default's
        "spd_counts": spd_counts(dflt["rays"]),  # as the SPD author counts (internal reflections)
        "count_error": error,
        "configs": configs,
        "best": best["label"],
        "best_trace_seconds": best["trace_seconds"],
        "default": dflt["label"],
        "default_structure": dflt["used_structure"],
        "default_reason": dflt["structure_reason"],
        "default_trace_seconds": dflt["trace_seconds"],
        "warnings": warnings,
    }


def _label(c: dict) -> str:
    """Short configuration name, e.g. 'grid hash d2', 'grid auto(csr) d1', 'bvh', 'auto(bvh)'
    or 'auto(grid csr d1)': what was asked for, and what auto chose."""
    if c["used_structure"] == "bvh":
        return "bvh" if c["structure"] == "bvh" else "auto(bvh)"
    storage = c["storage"] if c["storage"] != "auto" else f"auto({c['used_storage']})"
    grid = f"grid {storage} d{c['density']:g}"
    return grid if c["structure"] == "grid" else f"auto(grid {c['used_storage']} d{c['density']:g})"


# ---------------------------------------------------------------------------- published counts


def parse_published(text: str) -> dict[str, dict[str, int]]:
    """The 'Published ray counts' table of the scenes folder's README (the SPD author's counts,
    513x513 corner rays, depth 5): {scene: {count key: n}}; {} if the README has none."""
    _, found, rest = text.partition("Published ray counts")
    lines = [ln.strip() for ln in rest.split("\n## ")[0].splitlines()]
    rows = [[x.strip() for x in ln.strip("|").split("|")] for ln in lines if ln.startswith("|")]
    rows = [r for r in rows if not all(set(x) <= set("-: ") for x in r)]  # the rule under header
    if not found or not rows:
        return {}
    keys = [PUBLISHED_COLUMNS.get(h.lower()) for h in rows[0][1:]]
    return {
        r[0]: {k: int(v.replace(",", "")) for k, v in zip(keys, r[1:], strict=True) if k}
        for r in rows[1:]
    }


def read_published(scenes: Path) -> dict[str, dict[str, int]]:
    """The published counts of the scenes folder's README.md ({} without one)."""
    readme = scenes / "README.md"
    return parse_published(readme.read_text()) if readme.exists() else {}


def compare_published(name: str, counts: dict, published: dict | None) -> dict | None:
    """Relative difference of each of our counts from the published one (over max(published, 1):
    a published 0 stays finite) and whether all are within the scene's tolerance."""
    if not published:
        return None
    tolerance = PUBLISHED_TOLERANCE.get(name, TOLERANCE)
    relative = {k: (counts[k] - n) / max(n, 1) for k, n in published.items()}
    return {
        "published": published,
        "relative": relative,
        "tolerance": tolerance,
        "within": all(abs(d) <= tolerance for d in relative.values()),
    }


# ---------------------------------------------------------------------------- scaling


def scaling_run(scene, structure: str, size: int, repeat: int) -> dict:
    """One structure on one generated scene: its engine built once (storage auto, default
    density) and its kernels loaded before anything is timed, then the best of `repeat`."""
    storage, density = default_storage(), default_density()
    engine = build(scene, structure, storage, density)
    load = engine.warmup()
    c = run_config(scene, structure, storage, density, repeat, built=engine, size=size)
    return {
        "build_seconds": engine.preprocess_seconds,
        "kernel_load_seconds": load,
        **{k: c[k] for k in SCALING_KEYS},
        "seconds_per_ray": c["trace_seconds"] / c["total_rays"],
    }


def scaling_row(name: str, n: int, size: int, repeat: int) -> dict:
    """One generated scene under every structure of SCALING_STRUCTURES (one engine alive at a
    time: the biggest scenes are large), their ray counts checked equal."""
    from bench.generate import GENERATORS

    start = time.perf_counter()
    scene = GENERATORS[name](n)
    generate_seconds = time.perf_counter() - start
    runs = {s: scaling_run(scene, s, size, repeat) for s in SCALING_STRUCTURES}
    error, warnings = check_counts(f"{name} size factor {n}", list(runs.values()))
    return {
        "scene": name,
        "size_factor": n,
        "objects": scene.n_objects,
        "generate_seconds": generate_seconds,
        "total_rays": runs["auto"]["total_rays"],
        "runs": runs,
        "count_error": error,
        "warnings": warnings,
    }


def bench_scaling(plan: list[tuple[str, list[int]]], size: int, repeat: int) -> list[dict]:
    """Rows of every scene and size factor; each structure's `growth` is its time per ray over
    its own at the scene's first (smallest) size factor: how cost follows scene size."""
    from bench.generate import GENERATORS

    rows = []
    for name, sizes in plan:
        warm_kernels(GENERATORS[name](sizes[0]))  # build seconds then exclude build kernels
        first = None
        for n in sizes:
            print(f"  {name} size factor {n} ...", file=sys.stderr, flush=True)
            row = scaling_row(name, n, size, repeat)
            first = first or row
            for s, run in row["runs"].items():
                run["growth"] = run["seconds_per_ray"] / first["runs"][s]["seconds_per_ray"]
            rows.append(row)
        print_scaling([r for r in rows if r["scene"] == name])
    return rows


def growth_exponent(rows: list[dict], structure: str) -> float | None:
    """a in time per ray ~ objects^a between the first and last rows of one scene."""
    objects = rows[-1]["objects"] / rows[0]["objects"]
    growth = rows[-1]["runs"][structure]["growth"]
    return math.log(growth) / math.log(objects) if objects > 1 else None


def _chosen(rows: list[dict]) -> str:
    """What auto chose across the size factors, e.g. 'bvh at every size' or
    'bvh at n=1,2, grid at n=3'."""
    by: dict[str, list[str]] = {}
    for r in rows:
        by.setdefault(r["runs"]["auto"]["used_structure"], []).append(str(r["size_factor"]))
    if len(by) == 1:
        return f"{next(iter(by))} at every size"
    return ", ".join(f"{s} at n={','.join(ns)}" for s, ns in by.items())


def print_scaling(rows: list[dict]) -> None:
    """The scaling table of one scene, grid and default side by side, and each one's growth."""
    name = rows[0]["scene"]
    print(
        f"\n== {name}  (generated SPD {name}; grid vs the default, structure auto; best of "
        f"{len(rows[0]['runs']['grid']['trace_seconds_all'])})"
    )
    headers = [
        "n",
        "objects",
        "gen s",
        "rays",
        "grid",
        "build s",
        "trace s",
        "us/ray",
        "tests/ray",
        "growth",
        "auto",
        "build s",
        "trace s",
        "us/ray",
        "tests/ray",
        "growth",
        "grid/auto",
    ]
    body = []
    for r in rows:
        g, a = r["runs"]["grid"], r["runs"]["auto"]
        body.append(
            [
                r["size_factor"],
                f"{r['objects']:,}",
                f"{r['generate_seconds']:.2f}",
                f"{r['total_rays']:,}",
                "x".join(map(str, g["resolution"])) + f" {g['used_storage']}",
                *_cells(g),
                a["used_structure"],
                *_cells(a),
                f"{g['trace_seconds'] / a['trace_seconds']:.2f}",
            ]
        )
    print(table(headers, body))
    print(
        f"{name}: auto chose {_chosen(rows)}; at n={rows[-1]['size_factor']}: "
        f"{rows[-1]['runs']['auto']['structure_reason']}"
    )
    for s in SCALING_STRUCTURES:
        a = growth_exponent(rows, s)
        if a is not None:
            growth = rows[-1]["runs"][s]["growth"]
            print(
                f"{name} {s}: {rows[-1]['objects'] / rows[0]['objects']:,.0f}x the objects, "
                f"{growth:.2f}x the time per ray (objects^{a:.3f})"
            )
    for r in rows:
        if r["count_error"]:
            print("COUNT MISMATCH:", r["count_error"])
        for w in r["warnings"]:
            print("WARNING:", w)
    sys.stdout.flush()


def _cells(run: dict) -> list[str]:
    """One structure's columns of a scaling row."""
    return [
        f"{run['build_seconds']:.2f}",
        f"{run['trace_seconds']:.3f}",
        f"{run['seconds_per_ray'] * 1e6:.3f}",
        f"{run['tests_per_ray']:.2f}",
        f"{run['growth']:.2f}",
    ]


def main_scaling(args: argparse.Namespace) -> int:
    """--scaling: the table for generated scenes only (no scene folder, no POV-Ray)."""
    plan = ", ".join(f"{name} {sizes[0]}-{sizes[-1]}" for name, sizes in args.scaling)
    print(
        f"SPD scaling: generated {plan}; {args.size}x{args.size} SPD image "
        f"({args.size + 1}x{args.size + 1} corner rays), depth 5, 1 thread; grid (storage "
        f"{default_storage()}, density {default_density():g}) and the default (structure "
        f"auto); best of {args.repeat}"
    )
    rows = bench_scaling(args.scaling, args.size, args.repeat)
    if args.json:
        data = {
            "size": args.size,
            "repeat": args.repeat,
            "threads": 1,
            "structures": list(SCALING_STRUCTURES),
            "storage": default_storage(),
            "density": default_density(),
            "rows": rows,
        }
        args.json.write_text(json.dumps({"scaling": data}, indent=2) + "\n")
        print(f"figures written to {args.json}")
    errors = [r["count_error"] for r in rows if r["count_error"]]
    if errors:
        raise CountMismatchError("\n".join(errors))
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


def run_povray(exe: str, pov: Path, repeats: int, between=None) -> dict:
    """Render `pov` at 512x512 on one thread `repeats` times; best trace time and counts.
    `between()`, if given, runs after each POV-Ray run and returns our trace seconds: the two
    tracers take turns, so a slow spell of this shared machine falls on both alike."""
    runs, ours = [], []
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
            if between is not None:
                ours.append(between())
    best = min(runs, key=lambda r: r["trace_seconds"])
    out = {**best, "trace_seconds_all": [r["trace_seconds"] for r in runs]}
    if ours:
        out["ours_default_seconds"] = min(ours)
        out["ours_default_seconds_all"] = ours
    return out


def default_runner(path: Path):
    """A function tracing `path` once with the default engine (built here, once) and returning
    its trace seconds: our turns between POV-Ray's."""
    from host.scene.nff import read_nff

    scene = read_nff(path)
    storage, density = default_storage(), default_density()
    engine = build(scene, "auto", storage, density)
    return lambda: run_config(scene, "auto", storage, density, 1, built=engine)["trace_seconds"]


def pov_file(scenes: Path, name: str) -> Path | None:
    """The POV-Ray version of scene `name` (<scenes>/pov/NAME.pov), if there is one."""
    pov = scenes / "pov" / f"{name}.pov"
    return pov if pov.exists() else None


def compare_pov(results: list[dict], scenes: Path, repeat: int) -> dict:
    """POV-Ray figures (best of `repeat`) and pov/ours ratios for every scene of `results`
    that has a POV-Ray version."""
    wanted = [r for r in results if pov_file(scenes, r["scene"])]
    if not wanted:
        return {}
    exe = find_povray()
    if exe is None:
        print("\nPOV-Ray: unavailable (not on PATH and cannot install); no ratios.")
        return {"available": False}
    out = {"available": True, "executable": exe, "repeat": repeat, "scenes": {}}
    for r in wanted:
        print(f"  povray {r['scene']} ...", file=sys.stderr, flush=True)
        ours = default_runner(Path(r["file"]))
        pov = run_povray(exe, pov_file(scenes, r["scene"]), repeat, between=ours)
        pov["ratio_best"] = pov["trace_seconds"] / r["best_trace_seconds"]
        pov["ratio_default"] = pov["trace_seconds"] / pov["ours_default_seconds"]
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


# ---------------------------------------------------------------------------- whole process


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


# ---------------------------------------------------------------------------- printing


def table(headers: list[str], rows: list[list[str]]) -> str:
    """Right-aligned text table."""
    widths = [max(len(str(x)) for x in col) for col in zip(headers, *rows, strict=True)]
    lines = [headers, ["-" * w for w in widths], *rows]
    return "\n".join(
        "  ".join(str(x).rjust(w) for x, w in zip(ln, widths, strict=True)) for ln in lines
    )


def print_scene(r: dict) -> None:
    """Counts line and per-configuration table of one scene; counts go into the table (and a
    mismatch is flagged) when they differ between configurations."""
    c = r["counts"]
    loads = ", ".join(f"{k} {v:.2f} s" for k, v in r["kernel_load_seconds"].items())
    print(
        f"\n== {r['scene']}  ({r['objects']} objects, best of {r['repeats']}; kernel load {loads})"
    )
    pairs = list(zip(COUNT_LABELS, COUNT_KEYS, strict=True))
    if r["count_error"] is None:
        print(
            "rays (identical in every configuration): "
            + "  ".join(f"{lab} {c[k]}" for lab, k in pairs)
        )
    headers = [
        "config",
        "structure",
        "prep s",
        "trace s",
        "Mrays/s",
        "tests/ray",
        "steps/ray",
        "struct bytes",
    ]
    rows = [
        [
            x["label"],
            _shape(x),
            f"{x['preprocess_seconds']:.3f}",
            f"{x['trace_seconds']:.3f}",
            f"{x['rays_per_second'] / 1e6:.3f}",
            f"{x['tests_per_ray']:.2f}",
            f"{x['steps_per_ray']:.2f}",
            f"{x['structure_bytes']:,}",
        ]
        for x in r["configs"]
    ]
    if r["count_error"] is not None:
        headers += [lab for lab, _ in pairs]
        rows = [
            row + [x["rays"][k] for _, k in pairs]
            for row, x in zip(rows, r["configs"], strict=True)
        ]
    print(table(headers, rows))
    print(
        f"(steps/ray: voxel steps, or ray-box tests in the hierarchy; default {r['default']}: "
        f"{r['default_reason']})"
    )
    if r["count_error"] is not None:
        print("COUNT MISMATCH: the ray counts differ between configurations (engine bug)")
    for w in r["warnings"]:
        print("WARNING:", w)


def _shape(c: dict) -> str:
    """The structure's size: grid resolution, or the hierarchy's inner nodes and leaves."""
    if c["bvh"] is not None:
        return f"{c['bvh']['inner_nodes']:,} nodes {c['bvh']['leaves']:,} leaves"
    return "x".join(map(str, c["resolution"]))


def print_published(results: list[dict]) -> None:
    """Our default's counts against the SPD author's, per scene with a published row."""
    rows = []
    for r in results:
        p = r.get("published")
        if p is None:
            continue
        cells = []
        for k in PUBLISHED_COLUMNS.values():
            cells += (
                [r["spd_counts"][k], p["published"][k], f"{p['relative'][k]:+.3%}"]
                if k in p["published"]
                else ["-"] * 3
            )
        off = [k for k, d in p["relative"].items() if abs(d) > p["tolerance"]]
        rows.append(
            [
                r["scene"],
                *cells,
                f"{p['tolerance']:.1%}",
                "yes" if p["within"] else "NO: " + ", ".join(off),
            ]
        )
    if not rows:
        return
    print(
        "\n== ray counts of the default against the SPD author's published table "
        "(scenes README; 513x513 corner rays, depth 5; refracted counts total internal "
        "reflections, as the author's counter does)"
    )
    headers = [
        "scene",
        "hits",
        "SPD",
        "diff",
        "reflected",
        "SPD",
        "diff",
        "refracted",
        "SPD",
        "diff",
        "shadow",
        "SPD",
        "diff",
        "tolerance",
        "within",
    ]
    print(table(headers, rows))


def print_pov(results: list[dict], pov: dict) -> None:
    """Side-by-side tracing times and shadow/reflection counts against POV-Ray."""
    if not pov.get("available"):
        return
    print("\n== POV-Ray 3.7 side by side (512x512, 1 thread, trace time only)")
    headers = [
        "scene",
        "povray",
        "ours best",
        "config",
        "ours default",
        "config",
        "pov/best",
        "pov/default",
        "shadow ours",
        "pov",
        "blocked ours",
        "pov",
        "refl ours",
        "pov",
    ]
    rows = []
    for r in results:
        p = pov["scenes"].get(r["scene"])
        if p is None:
            continue
        c = r["counts"]
        rows.append(
            [
                r["scene"],
                f"{p['trace_seconds']:.3f}",
                f"{r['best_trace_seconds']:.3f}",
                r["best"],
                f"{p['ours_default_seconds']:.3f}",
                r["default"],
                f"{p['ratio_best']:.2f}",
                f"{p['ratio_default']:.2f}",
                c["shadow_rays"],
                p["shadow_rays"],
                c["shadow_rays_blocked"],
                p["shadow_rays_blocked"],
                c["reflected_rays"],
                p["reflected_rays"],
            ]
        )
    print(table(headers, rows))
    print(
        f"(best of {pov['repeat']} each, ours' default taking turns with POV-Ray (ours best: "
        "the scene's own pass); ratio > 1: we are faster; ours traces 513x513 "
        "corner rays, POV-Ray 512x512 centres with adc_bailout; default = structure auto, "
        f"storage auto, density {default_density():g})"
    )


def print_wall(wall: dict) -> None:
    """Whole-process wall seconds, warm and cold numba cache."""
    if not wall:
        return
    print(
        "\n== whole process: python -m host.cli render SCENE --spd --mesh 1x1 --threads 1 --quiet"
    )
    rows = [
        [name, f"{w['warm_seconds']:.2f}", f"{w['cold_seconds']:.2f}"] for name, w in wall.items()
    ]
    print(table(["scene", "warm cache s", "cold cache s"], rows))


def print_summary(results: list[dict], pov: dict, wall: dict) -> None:
    """One line per POV-Ray or wall-timed scene: ratios and wall times; then the goal and
    the published counts each in one line."""
    print("\n== summary")
    for r in results:
        p = pov.get("scenes", {}).get(r["scene"]) if pov else None
        w = wall.get(r["scene"])
        if p is None and w is None:
            continue
        parts = [
            f"{r['scene']}: ours {r['best_trace_seconds']:.3f} s ({r['best']}), "
            f"default {r['default_trace_seconds']:.3f} s ({r['default']})"
        ]
        if p:
            parts.append(
                f"POV-Ray {p['trace_seconds']:.3f} s -> pov/ours {p['ratio_best']:.2f}"
                f" best, {p['ratio_default']:.2f} default"
            )
        if w:
            parts.append(f"process warm {w['warm_seconds']:.2f} s, cold {w['cold_seconds']:.2f} s")
        print("; ".join(parts))
    total = sum(r["best_trace_seconds"] for r in results)
    print(f"all {len(results)} scenes: best tracing times sum to {total:.3f} s")
    if pov.get("available"):
        print(goal_line(goal(pov)))
    checked = [r for r in results if r.get("published")]
    if checked:
        off = [r["scene"] for r in checked if not r["published"]["within"]]
        print(
            f"published counts: {len(checked) - len(off)} of {len(checked)} scenes within "
            f"tolerance" + (f"; outside: {', '.join(off)}" if off else "")
        )


# ---------------------------------------------------------------------------- main


def main(argv=None) -> int:
    """Run the benchmark, print it, optionally write JSON."""
    args = parse_args(argv)
    if args.scaling is not None:
        return main_scaling(args)
    files = scene_files(args.scenes, args.only)
    plan = config_plan(args.structures, args.densities)
    with_pov = [p.stem for p in files if pov_file(args.scenes, p.stem)]
    print(
        f"SPD benchmark: {len(files)} scenes from {args.scenes}, 512x512 corner rays, depth 5, "
        f"1 thread; {', '.join(sorted(set(args.structures) | {'auto'}))}; densities "
        f"{args.densities}; best of {args.repeat} for the scenes with a POV-Ray version: "
        f"{', '.join(with_pov) or 'none'}"
    )
    published = read_published(args.scenes)
    results = []
    for path in files:
        print(f"  {path.stem} ...", file=sys.stderr, flush=True)
        repeats = args.repeat if path.stem in with_pov else 1
        results.append(bench_scene(path, plan, repeats))
        r = results[-1]
        r["published"] = compare_published(r["scene"], r["spd_counts"], published.get(r["scene"]))
        print_scene(r)
        sys.stdout.flush()
    print_published(results)
    pov = {} if args.no_pov else compare_pov(results, args.scenes, args.repeat)
    print_pov(results, pov)
    wall = (
        {}
        if args.no_wall
        else {p.stem: wall_times(p, args.repeat) for p in files if p.stem in WALL_SCENES}
    )
    print_wall(wall)
    print_summary(results, pov, wall)
    if args.json:
        data = {
            "structures": args.structures,
            "densities": args.densities,
            "repeat": args.repeat,
            "scenes": results,
            "povray": pov,
            "goal": goal(pov) if pov.get("available") else None,
            "wall": wall,
        }
        args.json.write_text(json.dumps(data, indent=2) + "\n")
        print(f"figures written to {args.json}")
    errors = [r["count_error"] for r in results if r["count_error"]]
    if errors:
        raise CountMismatchError("\n".join(errors))
    return 0


if __name__ == "__main__":
    sys.exit(main())
