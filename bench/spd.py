"""SPD benchmark: every NFF scene at 512x512 on one thread, per acceleration structure (the
grid per storage and density, the hierarchy, and the default: structure auto), with POV-Ray 3.7
side by side on every scene (its pov/NAME.pov, else one converted from the NFF by
`bench.pov_scene`), the default's ray counts against the SPD author's published table, and
whole-process wall times (warm and cold numba cache).

    python -m bench.spd [--scenes DIR] [--only balls,tetra] [--structures grid,bvh]
                        [--densities 1,2,4] [--repeat 3] [--json FILE] [--no-pov] [--no-wall]
    python -m bench.spd --scaling [tetra:1-10,balls:1-6] [--size 512] [--repeat 3] [--json FILE]

Tracing times exclude kernel loading (`render` warms up first) and preprocessing; rays/s is
all rays (eye, reflected, refracted, shadow) over the best tracing time. Ray counts must be
identical in every configuration of a scene: grid and hierarchy are both exact. The process
is pinned to one core (`bench.timing`; POV-Ray, its child, inherits it), and POV-Ray and our
default take turns on trace CPU seconds: the goal's ratio is the median of the turns' paired
ratios.

--scaling needs no scene folder: it generates SPD tetra and balls at growing size factors
(`bench.generate`: 4^n triangles, 1 + 9 + ... + 9^n spheres) and prints tracing time against
scene size for the grid (storage auto, default density) and the default (structure auto) side
by side, one thread; the growth columns are time per ray over the smallest size factor's.
"""

import argparse
import json
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as `python bench/spd.py`
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option  # noqa: E402 (after the path is set)
from bench.spd_povray import GENERATED, compare_pov, goal, pov_file  # noqa: E402
from bench.spd_published import compare_published, read_published  # noqa: E402
from bench.spd_report import (  # noqa: E402
    print_pov,
    print_published,
    print_scene,
    print_summary,
    print_wall,
)
from bench.spd_runs import CountMismatchError, bench_scene, config_plan  # noqa: E402
from bench.spd_scaling import main_scaling  # noqa: E402
from bench.spd_wall import WALL_SCENES, wall_times  # noqa: E402
from bench.timing import pin_one_core, pinned_text  # noqa: E402

STRUCTURES = ("grid", "bvh", "auto")  # --structures; the default (auto) always runs
DEFAULT_SCALING = "tetra:1-10,balls:1-6"  # 4 .. 1,048,576 triangles, 10 .. 597,871 spheres


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
        help="best of N for every scene (POV-Ray's and ours: each scene has a POV-Ray "
        "version, shipped or converted from its NFF) and for --scaling (default 3)",
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


def main(argv=None) -> int:
    """Run the benchmark, print it, optionally write JSON."""
    args = parse_args(argv)
    core = pin_one_core()  # one thread throughout; children (POV-Ray) inherit the core
    if args.scaling is not None:
        return main_scaling(args)
    files = scene_files(args.scenes, args.only)
    generated = [p.stem for p in files if not pov_file(args.scenes, p.stem)]
    print(
        f"SPD benchmark: {len(files)} scenes from {args.scenes}, 512x512 corner rays, depth 5, "
        f"1 thread {pinned_text(core)}; {', '.join(sorted(set(args.structures) | {'auto'}))}; "
        f"densities {args.densities}; best of {args.repeat}; POV-Ray versions shipped in "
        f"{args.scenes / 'pov'}, {GENERATED} (bench.pov_scene) for: "
        f"{', '.join(generated) or 'none'}"
    )
    results = bench_scenes(args, files)
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
        write_json(args, results, pov, wall)
    errors = [r["count_error"] for r in results if r["count_error"]]
    if errors:
        raise CountMismatchError("\n".join(errors))
    return 0


def bench_scenes(args: argparse.Namespace, files: list[Path]) -> list[dict]:
    """Every scene under every configuration (best of `--repeat`), each printed as it
    finishes (a long run shows its progress) and checked against the published counts."""
    plan = config_plan(args.structures, args.densities)
    published = read_published(args.scenes)
    results = []
    for path in files:
        print(f"  {path.stem} ...", file=sys.stderr, flush=True)
        results.append(bench_scene(path, plan, args.repeat))
        r = results[-1]
        r["published"] = compare_published(r["scene"], r["spd_counts"], published.get(r["scene"]))
        print_scene(r)
        sys.stdout.flush()
    return results


def write_json(args: argparse.Namespace, results: list[dict], pov: dict, wall: dict) -> None:
    """All figures to `--json`, to compare runs and machines later."""
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


if __name__ == "__main__":
    sys.exit(main())
