"""What a render costs beyond the interpreter: a warm whole-process `meshtrace render` against
`python -c "import numba"`, and a cold first render (empty kernel cache) with its compile
steps.

    python -m bench.start --scene /work/shared/scenes/tetra.nff --turns 7
    python -m bench.start --cold --scene host/examples/showcase.nff --scene tetra.nff

Warm: the two commands run as child processes taking turns (import numba, render, import
numba, render ...; `bench.timing`), `--turns` rounds, after one untimed run of each (it fills
the kernel cache and writes the bytecode caches an installed copy has). Printed per command:
its wall and CPU seconds (user + system, `RUSAGE_CHILDREN`), each a median (least-most), and
the render's medians less import numba's. The render is this tree's (`host.cli` from the
repository root), run as the `meshtrace` script runs it.

Cold: each scene rendered once in a child with NUMBA_CACHE_DIR an empty folder (the kernel
cache, `meshnode.engine.jit`); printed: wall and CPU seconds, and the seconds each setup step
compiled, as the render says them ("compiled the structure build in 5.8 s", `host.run.firstrun`)
and as its statistics sum them (compile, load, build).
"""

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.timing import Turns, child_cpu, turns  # noqa: E402 (after the path is set)

ROOT = Path(__file__).resolve().parents[1]
# What the `meshtrace` console script runs (pyproject [project.scripts]), by that name.
MESHTRACE = "import sys; sys.argv[0] = 'meshtrace'; from host.cli import main; sys.exit(main())"
IMPORT_NUMBA = "import numba"
STEP = re.compile(r"compiled the (.+?) in ([0-9.]+) s")


def child_env(cache: str | None = None) -> dict:
    """The children's environment: this tree's packages first on the path, bytecode cached
    (PYTHONDONTWRITEBYTECODE dropped: an installed copy has its .pyc files; without them the
    render compiles its sources every run), `cache` as the kernel cache's root if given."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def render_command(scene: str, out: str, spd: bool, quiet: bool, stats: str | None = None):
    """The render as a child's argument list."""
    cmd = [sys.executable, "-c", MESHTRACE, "render", scene, "-o", out]
    cmd += ["--spd"] * spd + ["--quiet"] * quiet
    return cmd + (["--stats", stats] if stats else [])


def timed(cmd: list[str], env: dict) -> tuple[float, float, str]:
    """(wall seconds, CPU seconds, stderr) of one child run to its end."""
    before, start = child_cpu(), time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wall, cpu = time.perf_counter() - start, child_cpu() - before
    if done.returncode:
        sys.stderr.write(done.stderr.decode(errors="replace"))
        raise RuntimeError(f"{' '.join(cmd[3:])}: exit status {done.returncode}")
    return wall, cpu, done.stderr.decode(errors="replace")


def warm(scene: str, rounds: int, spd: bool) -> int:
    """Import numba and the warm render in turns: their medians and the difference."""
    env = child_env()
    with tempfile.TemporaryDirectory() as tmp:
        subjects = {
            "import numba": [sys.executable, "-c", IMPORT_NUMBA],
            "render": render_command(scene, f"{tmp}/x.png", spd, quiet=True),
        }
        for cmd in subjects.values():  # untimed: kernels cached, bytecode written
            timed(cmd, env)
        walls, cpus = Turns(), Turns()
        for _, name in turns(list(subjects), rounds):
            wall, cpu, _ = timed(subjects[name], env)
            walls.add(name, wall)
            cpus.add(name, cpu)
    shown = " ".join(["meshtrace", *subjects["render"][3:]]).replace(tmp, "/tmp")
    print(f"warm, {rounds} rounds in turns, seconds: median (least-most)")
    for name, what in (("import numba", f'python -c "{IMPORT_NUMBA}"'), ("render", shown)):
        wall, cpu = walls.figure(name).text(), cpus.figure(name).text()
        print(f"{name:>12}: wall {wall}   CPU {cpu}   {what}")
    dw = walls.figure("render").median - walls.figure("import numba").median
    dc = cpus.figure("render").median - cpus.figure("import numba").median
    print(f"render - import numba (difference of medians): wall {dw:+.3f} s, CPU {dc:+.3f} s")
    return 0


def cold(scenes: list[str], spd: bool) -> int:
    """Each scene's first render from an empty kernel cache, with its compile steps."""
    print("cold: each scene's first render, NUMBA_CACHE_DIR an empty folder; seconds")
    for scene in scenes:
        with tempfile.TemporaryDirectory() as tmp:
            env = child_env(cache=f"{tmp}/cache")
            cmd = render_command(scene, f"{tmp}/x.png", spd, quiet=False, stats=f"{tmp}/s.json")
            wall, cpu, err = timed(cmd, env)
            stats = json.loads(Path(f"{tmp}/s.json").read_text())
        steps = "  ".join(f"{step} {float(s):.1f}" for step, s in STEP.findall(err))
        print(
            f"{Path(scene).name}: wall {wall:.1f}  CPU {cpu:.1f}  "
            f"compile {stats['compile_seconds']:.1f} ({steps or 'nothing compiled'})  "
            f"load {stats['load_seconds']:.2f}  build {stats['build_seconds']:.2f}  "
            f"trace {stats['trace_seconds']:.2f}  [{stats['engine']['kernel_variant']}]"
        )
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.start", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--scene",
        action="append",
        help="scene file (repeatable with --cold; default /work/shared/scenes/tetra.nff)",
    )
    p.add_argument("--turns", type=int, default=7, help="rounds of import numba, render (7)")
    p.add_argument("--cold", action="store_true", help="first renders from an empty cache")
    p.add_argument("--no-spd", dest="spd", action="store_false", help="render without --spd")
    args = p.parse_args(argv)
    scenes = [str(Path(s).resolve()) for s in args.scene or ["/work/shared/scenes/tetra.nff"]]
    if args.cold:
        return cold(scenes, args.spd)
    if len(scenes) != 1:
        p.error("the warm comparison takes one --scene")
    return warm(scenes[0], args.turns, args.spd)


if __name__ == "__main__":
    sys.exit(main())
