"""Measures the unit costs of `meshnode.engine.structure_cost` on this machine: per scene,
each structure's build seconds (its kernels loaded first) and tracing CPU seconds per ray of
an SPD render on one thread, beside the forecasts the cost model reads (the hierarchy's tests
and node visits per crossing ray, the grid's forecast tests, steps, references and voxels
tested while counting); then fits the constants by non-negative least squares and prints
them with each scene's estimated seconds against the measured.

    python -m bench.structure_cost [--scenes DIR] [--only shells,tetra] [--size 256]
                                   [--nested 200,800] [--repeat 3] [--json FILE]

One thread, each measurement the best of `--repeat` (the machine is shared). A scene's first
run compiles its kernel variant (tens of seconds); nothing compiled is timed. `--nested N`
adds `nested_spheres(N)`: the SPD scenes all trace faster with the hierarchy, and a model fitted
on them alone could not say where the grid's tracing pays.
"""

import argparse
import json
import math
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # run as `python bench/structure_cost.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option  # noqa: E402 (after the path is set)

SCENES = "balls,gears,rings,teapot,tetra,tree,shells,jacks,mount_s1"


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bench.structure_cost", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default=SCENES, help=f"scene names (default {SCENES})")
    p.add_argument("--nested", default="200,800", help="nested_spheres sizes (default 200,800)")
    p.add_argument("--size", type=int, default=256, help="SPD image side (default 256)")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--json", type=Path)
    return p.parse_args(argv)


def best(fn, repeat: int) -> float:
    """Fewest seconds of `repeat` calls of fn (wall)."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def nested_spheres(n: int, seed: int = 1):
    """`n` spheres about one centre, radii 1 to 2 in shuffled order, seen from outside with one
    light: every box holds the smaller ones, so a hierarchy's leaves mix large and small and a
    crossing ray tests most of them, while the grid keeps each sphere only in the voxels its
    surface passes through."""
    import numpy as np

    from host.scene.builder import SceneBuilder
    from protocols.scene import View

    b = SceneBuilder(f"nested_spheres({n})")
    matte = b.material((1.0, 0.8, 0.6, 0.8, 0.0, 1.0, 0.0, 1.0))
    b.light((10.0, 10.0, 10.0))
    for r in np.random.default_rng(seed).permutation(np.linspace(1.0, 2.0, n)):
        b.sphere((0.0, 0.0, 0.0), r, matte)
    return b.build(View((0.0, 0.0, 8.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0))


def grid_load_seconds(path: Path | None, nested: int) -> float:
    """Seconds loading the grid's build kernels from the disk cache in a fresh process whose
    hierarchy's are loaded (as "auto" loads them): a one-object hierarchy, then a one-voxel
    grid, as `meshnode.engine.structure` loads them."""
    import subprocess

    scene = f"read_nff({str(path)!r})" if path else f"nested_spheres({nested})"
    code = f"""
import time
import numpy as np
from bench.structure_cost import nested_spheres
from host.scene.nff import read_nff
from meshnode.engine.bvhbuild import Bvh
from meshnode.engine.grid import build_grid
from meshnode.engine.tables import build_tables
tb = build_tables({scene})
Bvh(tb.lo[:1], tb.hi[:1], np.minimum(tb.offsets, 1))
start = time.perf_counter()
build_grid(tb, tb.lo.min(axis=0), tb.hi.max(axis=0), res=np.ones(3, np.int64))
print(time.perf_counter() - start)
"""
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True)
    return float(out.stdout.split()[-1])


def measure(path: Path | None, size: int, repeat: int, nested: int = 0) -> dict:
    """One scene's forecasts and measured seconds, per structure (`path` None:
    nested_spheres(nested))."""
    import numpy as np

    from host.planning.request import Request
    from host.run.oneprocess import render
    from host.scene.nff import read_nff
    from meshnode.engine import Engine
    from meshnode.engine.bvhbuild import Bvh
    from meshnode.engine.grid import build_grid
    from meshnode.engine.structure_cost import grid_forecast
    from protocols.render import EngineSpec, ImageSpec

    scene = read_nff(path) if path else nested_spheres(nested)
    row: dict = {"scene": path.stem if path else f"nested{nested}"}
    image = ImageSpec(spd=True, width=size, height=size)
    for structure in ("bvh", "grid"):
        engine = Engine(scene, structure=structure)
        engine.warmup()
        tb = engine.tables
        lo, hi = tb.lo.min(axis=0), tb.hi.max(axis=0)
        if structure == "bvh":
            bvh = Bvh(tb.lo, tb.hi, tb.offsets)
            build = best(lambda: Bvh(tb.lo, tb.hi, tb.offsets), repeat)  # noqa: B023
            row["objects"] = int(tb.n)
            row["bvh_tests"] = bvh.stats["expected_tests"]
            row["bvh_visits"] = bvh.stats["expected_visits"]
            row["bvh_bytes"] = bvh.stats["structure_bytes"]
        else:
            fc = grid_forecast(tb.lo, tb.hi, lo, hi, 1.0)
            row["forecast_seconds"] = best(lambda: grid_forecast(tb.lo, tb.hi, lo, hi, 1.0), 1)  # noqa: B023
            build = best(lambda: build_grid(tb, lo, hi), repeat)  # noqa: B023
            grid = engine.grid.stats
            row.update(
                grid_tests=fc.tests,
                grid_steps=fc.steps,
                grid_refs=fc.refs,
                grid_voxels=fc.voxels,
                grid_candidates=fc.candidates,
                grid_bytes=fc.bytes,
                grid_built_refs=grid["object_references"],
                grid_built_resolution=grid["resolution"],
            )
        row[f"{structure}_build_seconds"] = build
        spec = EngineSpec(threads=1, structure=structure)
        runs = [render(Request(scene, image, spec), built=engine)[1] for _ in range(repeat)]
        fastest = min(runs, key=lambda s: s["trace_cpu_seconds"])
        segments = max(fastest["rays"]["ray_segments"], 1)
        row["rays"] = fastest["total_rays"]
        row[f"{structure}_trace_seconds"] = fastest["trace_cpu_seconds"]
        row[f"{structure}_tests_per_ray"] = fastest["intersection_tests"] / segments
        row[f"{structure}_steps_per_ray"] = fastest["voxel_steps"] / segments
        del engine
    row["lights"] = len(scene.lights)
    row["grid_load_seconds"] = min(grid_load_seconds(path, nested) for _ in range(repeat))
    _ = np  # numpy is the model's; imported here so a bare run fails early without it
    return row


def fit(rows: list[dict]) -> dict:
    """The constants, by non-negative least squares on seconds relative to each measurement
    (every scene weighs alike, not only the slowest)."""
    import numpy as np
    from scipy.optimize import nnls

    # Tracing: seconds per ray = per ray + per test x tests + per visit/step x visits/steps.
    a, b = [], []
    for r in rows:
        for s, tests, walk in (
            ("bvh", r["bvh_tests"], r["bvh_visits"]),
            ("grid", r["grid_tests"], r["grid_steps"]),
        ):
            per_ray = r[f"{s}_trace_seconds"] / r["rays"]
            x = [1.0, tests, walk, 0, 0] if s == "bvh" else [1.0, 0, 0, tests, walk]
            a.append(np.array(x) / per_ray)
            b.append(1.0)
    trace, _ = nnls(np.array(a), np.array(b))
    # Building: the hierarchy per object x log2 objects; the grid per voxel tested while
    # counting, per reference and per voxel.
    a = [[r["objects"] * math.log2(max(r["objects"], 2)) / r["bvh_build_seconds"]] for r in rows]
    hier, _ = nnls(np.array(a), np.ones(len(rows)))
    a = [
        np.array([r["grid_candidates"], r["grid_refs"], r["grid_voxels"]]) / r["grid_build_seconds"]
        for r in rows
    ]
    grid, _ = nnls(np.array(a), np.ones(len(rows)))
    names = ("per_ray", "per_bvh_test", "per_bvh_visit", "per_grid_test", "per_grid_step")
    return {
        **dict(zip(names, trace.tolist(), strict=True)),
        "per_bvh_object_log2": float(hier[0]),
        "per_grid_candidate": float(grid[0]),
        "per_grid_ref": float(grid[1]),
        "per_grid_voxel": float(grid[2]),
        "grid_load": float(np.median([r["grid_load_seconds"] for r in rows])),
    }


def estimates(row: dict) -> tuple:
    """The committed model's (hierarchy, grid) estimates for a measured row's forecasts."""
    from meshnode.engine.structure_cost import GridForecast, grid_estimate, hierarchy_estimate

    rays = row["rays"]
    hierarchy = hierarchy_estimate(
        row["objects"], row["bvh_tests"], row["bvh_visits"], rays, row["bvh_bytes"]
    )
    forecast = GridForecast(
        res=(0, 0, 0),
        voxels=row["grid_voxels"],
        refs=row["grid_refs"],
        candidates=row["grid_candidates"],
        tests=row["grid_tests"],
        steps=row["grid_steps"],
        bytes=row["grid_bytes"],
    )
    return hierarchy, grid_estimate(forecast, rays)


def report(rows: list[dict], fitted: dict) -> None:
    """Each scene's estimates (the committed constants) against the measured seconds, and
    the constants this run's measurements fit."""
    print(
        f"{'scene':10s} {'rays':>8s} | hierarchy build est/meas  trace est/meas | "
        "grid build est/meas  trace est/meas | faster: est/meas"
    )
    for r in rows:
        h, g = estimates(r)
        measured = (
            "bvh"
            if r["bvh_build_seconds"] + r["bvh_trace_seconds"]
            <= r["grid_build_seconds"] + r["grid_trace_seconds"]
            else "grid"
        )
        print(
            f"{r['scene']:10s} {r['rays']:8d} | {h.build:8.4f} {r['bvh_build_seconds']:8.4f}  "
            f"{h.trace:6.3f} {r['bvh_trace_seconds']:6.3f} | {g.build:8.4f} "
            f"{r['grid_build_seconds']:8.4f}  {g.trace:6.3f} {r['grid_trace_seconds']:6.3f} | "
            f"{min((h, g), key=lambda e: e.total).structure:4s} {measured}"
        )
    print("fitted here: " + ", ".join(f"{n} {v:.2g}" for n, v in fitted.items()))


def main(argv=None) -> int:
    args = parse_args(argv)
    runs = [(args.scenes / f"{n}.nff", 0) for n in args.only.split(",") if n]
    runs += [(None, int(n)) for n in args.nested.split(",") if n]
    rows = []
    for path, nested in runs:
        rows.append(measure(path, args.size, args.repeat, nested))
        print(json.dumps(rows[-1]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    report(rows, fit(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
