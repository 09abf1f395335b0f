"""`bench.spd --scaling`: tracing time against scene size on generated SPD tetra and balls,
grid against the default, to show how cost per ray grows with the number of objects."""

import argparse
import json
import math
import sys
import time

from bench.spd_report import table
from bench.spd_runs import (
    CountMismatchError,
    build,
    check_counts,
    default_density,
    default_storage,
    run_config,
    warm_kernels,
)

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
