"""The default plan against `--mesh 1x1` on this machine: whole `host render` processes, taking
turns, medians over the rounds.

    python -m bench.plan [--scenes DIR] [--only balls,gears,tetra] [--repeat 3] [--json FILE]

On one machine the default (`--mesh auto`) renders in one process with a tracing thread per
core; `--mesh 1x1` is a one-node mesh plan in the same process. Each scene is rendered under
the SPD rules both ways, taking turns (`bench.timing`), `--repeat` rounds after one warming
render each; the table gives, each as a median (least-most), the whole process's wall seconds
(start-up, kernel loading, reading, building, tracing, writing: what a user waits for, the
claim this benchmark checks) and its CPU seconds (user + system, `RUSAGE_CHILDREN`: the work,
which the machine's load moves far less), and default / 1x1 of each as the median of the
rounds' paired ratios (wall <= 1: the default is at least as fast); then the plan each chose
(its first line). The tracing seconds from `--stats` go to the JSON file.
"""

import argparse
import json
import statistics
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
from bench.timing import Turns, child_cpu, turns  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bench.plan", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,gears,tetra", help="comma-separated scene names")
    p.add_argument("--repeat", type=int, default=3, help="rounds of turns per scene (3)")
    p.add_argument("--json", type=Path, help="write the figures to this JSON file")
    return p.parse_args(argv)


def run_once(scene: Path, extra: list[str], tmp: Path) -> dict:
    """One whole `host render --spd` process: wall and CPU seconds, tracing seconds, the plan
    line."""
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
    start, cpu = time.perf_counter(), child_cpu()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall, cpu = time.perf_counter() - start, child_cpu() - cpu
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    plan = next((ln for ln in done.stderr.splitlines() if ln.startswith("host: plan:")), "")
    return {
        "wall_seconds": wall,
        "cpu_seconds": cpu,
        "trace_seconds": json.loads(stats.read_text())["trace_seconds"],
        "plan": plan,
    }


def bench_scene(scene: Path, repeat: int) -> dict:
    """Both plans on one scene, taking turns: each one's wall and CPU seconds (median,
    least-most, every round's), median tracing seconds, and default / 1x1 of each as the
    median of the rounds' paired ratios."""
    runs: dict[str, list[dict]] = {name: [] for name in PLANS}
    wall, cpu = Turns(), Turns()
    with tempfile.TemporaryDirectory(prefix="bench-plan-") as tmp:
        for extra in PLANS.values():  # once each first: kernels loaded, files cached
            run_once(scene, extra, Path(tmp))
        for _, name in turns(list(PLANS), repeat):
            runs[name].append(run_once(scene, PLANS[name], Path(tmp)))
            wall.add(name, runs[name][-1]["wall_seconds"])
            cpu.add(name, runs[name][-1]["cpu_seconds"])
    out = {"scene": scene.stem}
    for name, rs in runs.items():
        out[name] = {
            **wall.figure(name).fields("wall_seconds"),
            **cpu.figure(name).fields("cpu_seconds"),
            "trace_seconds": statistics.median(r["trace_seconds"] for r in rs),
            "plan": rs[0]["plan"],
        }
    out.update(wall.ratio("default", "1x1").fields("wall_ratio"))
    out.update(cpu.ratio("default", "1x1").fields("cpu_ratio"))
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
        f"default plan vs --mesh 1x1: whole host render --spd processes, taking turns, "
        f"{args.repeat} rounds: median (least-most); ratios: the median of paired ratios"
    )
    rows = []
    for name in names:
        print(f"  {name} ...", file=sys.stderr, flush=True)
        rows.append(bench_scene(args.scenes / f"{name}.nff", args.repeat))
    print(
        f"{'scene':8} {'default wall s':>19} {'1x1 wall s':>19} {'ratio':>16} "
        f"{'default CPU s':>19} {'1x1 CPU s':>19} {'ratio':>16}"
    )

    def spread(f: dict, key: str, digits: int = 3) -> str:
        lo, mid, hi = f[f"{key}_low"], f[key], f[f"{key}_high"]
        return f"{mid:.{digits}f} ({lo:.{digits}f}-{hi:.{digits}f})"

    for r in rows:
        d, m = r["default"], r["1x1"]
        print(
            f"{r['scene']:8} {spread(d, 'wall_seconds'):>19} {spread(m, 'wall_seconds'):>19} "
            f"{spread(r, 'wall_ratio', 2):>16} {spread(d, 'cpu_seconds'):>19} "
            f"{spread(m, 'cpu_seconds'):>19} {spread(r, 'cpu_ratio', 2):>16}"
        )
    for r in rows:
        print(f"{r['scene']}: default {r['default']['plan'] or '(no plan line)'}")
        print(f"{r['scene']}: 1x1     {r['1x1']['plan'] or '(no plan line)'}")
    slower = [r["scene"] for r in rows if r["wall_ratio"] > 1.0]
    same = [r["scene"] for r in rows if _plan(r["default"]["plan"]) == _plan(r["1x1"]["plan"])]
    print(
        "default at least as fast as --mesh 1x1 (median paired wall ratio): "
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
