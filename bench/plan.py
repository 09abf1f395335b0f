"""The default plan against `--mesh 1x1` on this machine: whole `host render` processes, taking
turns, best of N.

    python -m bench.plan [--scenes DIR] [--only balls,gears,tetra] [--repeat 3] [--json FILE]

On one machine the default (`--mesh auto`) renders in one process with a tracing thread per
core; `--mesh 1x1` is a one-node mesh plan in the same process. Each scene is rendered under
the SPD rules both ways, alternately, `--repeat` times; the table gives wall seconds of the
whole process (start-up, kernel loading, reading, building, tracing, writing), the tracing
seconds from `--stats`, the plan each chose (its first line) and default / 1x1 (<= 1: the
default is at least as fast).
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLANS = {"default": [], "1x1": ["--mesh", "1x1"]}

if __package__ in (None, ""):  # run as `python bench/plan.py`
    sys.path.insert(0, str(ROOT))

from bench import add_scenes_option  # noqa: E402 (after the path is set)


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bench.plan", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,gears,tetra", help="comma-separated scene names")
    p.add_argument("--repeat", type=int, default=3, help="renders per plan and scene (best)")
    p.add_argument("--json", type=Path, help="write the figures to this JSON file")
    return p.parse_args(argv)


def run_once(scene: Path, extra: list[str], tmp: Path) -> dict:
    """One whole `host render --spd` process: wall seconds, tracing seconds, the plan line."""
    stats = tmp / "stats.json"
    cmd = [
        sys.executable,
        "-m",
        "host.cli",
        "render",
        str(scene),
        "--spd",
        "-o",
        str(tmp / "out.png"),
        "--stats",
        str(stats),
        *extra,
    ]
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    plan = next((ln for ln in done.stderr.splitlines() if ln.startswith("host: plan:")), "")
    return {
        "wall_seconds": wall,
        "trace_seconds": json.loads(stats.read_text())["trace_seconds"],
        "plan": plan,
    }


def bench_scene(scene: Path, repeat: int) -> dict:
    """Both plans on one scene, taking turns; best wall and tracing seconds of each."""
    runs: dict[str, list[dict]] = {name: [] for name in PLANS}
    with tempfile.TemporaryDirectory(prefix="bench-plan-") as tmp:
        for extra in PLANS.values():  # once each first: kernels loaded, files cached
            run_once(scene, extra, Path(tmp))
        for _ in range(repeat):
            for name, extra in PLANS.items():
                runs[name].append(run_once(scene, extra, Path(tmp)))
    out = {"scene": scene.stem}
    for name, rs in runs.items():
        out[name] = {
            "wall_seconds": min(r["wall_seconds"] for r in rs),
            "trace_seconds": min(r["trace_seconds"] for r in rs),
            "wall_seconds_all": [r["wall_seconds"] for r in rs],
            "plan": rs[0]["plan"],
        }
    out["wall_ratio"] = out["default"]["wall_seconds"] / out["1x1"]["wall_seconds"]
    out["trace_ratio"] = out["default"]["trace_seconds"] / out["1x1"]["trace_seconds"]
    return out


def _plan(line: str) -> str:
    """The plan of a 'host: plan: ...' line without its reason: 'one process, 2 tracing
    threads'."""
    return line.removeprefix("host: plan: ").split(" (")[0]


def main(argv=None) -> int:
    args = parse_args(argv)
    names = [n for n in args.only.split(",") if n]
    missing = [n for n in names if not (args.scenes / f"{n}.nff").exists()]
    if missing:
        print(f"bench.plan: no {', '.join(missing)} in {args.scenes}", file=sys.stderr)
        return 2
    print(
        f"default plan vs --mesh 1x1: whole host render --spd processes, taking turns, best "
        f"of {args.repeat}"
    )
    rows = []
    for name in names:
        print(f"  {name} ...", file=sys.stderr, flush=True)
        rows.append(bench_scene(args.scenes / f"{name}.nff", args.repeat))
    print(
        f"{'scene':8} {'default wall s':>14} {'1x1 wall s':>10} {'ratio':>6} "
        f"{'default trace s':>15} {'1x1 trace s':>11} {'ratio':>6}"
    )
    for r in rows:
        d, m = r["default"], r["1x1"]
        print(
            f"{r['scene']:8} {d['wall_seconds']:14.3f} {m['wall_seconds']:10.3f} "
            f"{r['wall_ratio']:6.2f} {d['trace_seconds']:15.3f} {m['trace_seconds']:11.3f} "
            f"{r['trace_ratio']:6.2f}"
        )
    for r in rows:
        print(f"{r['scene']}: default {r['default']['plan'] or '(no plan line)'}")
        print(f"{r['scene']}: 1x1     {r['1x1']['plan'] or '(no plan line)'}")
    slower = [r["scene"] for r in rows if r["wall_ratio"] > 1.0]
    same = [r["scene"] for r in rows if _plan(r["default"]["plan"]) == _plan(r["1x1"]["plan"])]
    print(
        "default at least as fast as --mesh 1x1 (wall): "
        + ("on every scene" if not slower else f"not on {', '.join(slower)}")
    )
    if same:
        print(f"same plan both ways on {', '.join(same)}: a ratio there is this machine's noise")
    if args.json:
        args.json.write_text(json.dumps({"repeat": args.repeat, "rows": rows}, indent=2) + "\n")
        print(f"figures written to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
