"""What a render costs beyond the interpreter: a warm whole-process `meshtrace render` against
`python -c "import numba"`, and a cold first render (empty kernel cache) with its compile
steps.

    python -m bench.start --scene $MESHTRACE_SCENES/tetra.nff --turns 7
    python -m bench.start --cold --scene host/examples/showcase.nff --scene tetra.nff
    python -m bench.start --against /tmp/before   # and another checkout's render, in turns

Warm: the two commands run as child processes taking turns (import numba, render, import
numba, render ...; `bench.timing`), `--turns` rounds, after one untimed run of each (it fills
the kernel cache and writes the bytecode caches an installed copy has). Printed per command:
its wall and CPU seconds (user + system, `RUSAGE_CHILDREN`), each a median (least-most), and
the render's medians less import numba's, then the median (least-most) of each round's
render less its import numba (the pair shares a spell of this shared machine). The render
is this tree's (`host.cli` from the repository root), run as the `meshtrace` script runs
it; `--against DIR` adds the render of another checkout (the code before a change: `git
worktree add DIR COMMIT`) to the turns.

Cold: each scene rendered once in a child with NUMBA_CACHE_DIR an empty folder (the kernel
cache, `meshnode.engine.jit`); printed: wall and CPU seconds, and the seconds each setup step
compiled, as the render says them ("compiled the structure build in 5.8 s", `host.run.firstrun`)
and as its statistics sum them (compile, load, build); with `--against DIR` each scene's
first render in DIR takes turns with this tree's.
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

from bench.timing import Figure, Turns, child_cpu, turns  # noqa: E402 (after the path is set)

ROOT = Path(__file__).resolve().parents[1]
# What the `meshtrace` console script runs (pyproject [project.scripts]), by that name.
MESHTRACE = "import sys; sys.argv[0] = 'meshtrace'; from host.cli import main; sys.exit(main())"
IMPORT_NUMBA = "import numba"
STEP = re.compile(r"compiled the (.+?) in ([0-9.]+) s")


def child_env(tree: Path = ROOT, cache: str | None = None) -> dict:
    """The children's environment: `tree`'s packages first on the path, bytecode cached
    (PYTHONDONTWRITEBYTECODE dropped: an installed copy has its .pyc files; without them the
    render compiles its sources every run), `cache` as the kernel cache's root if given."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tree), env.get("PYTHONPATH")]))
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def render_command(scene: str, out: str, spd: bool, quiet: bool, stats: str | None = None):
    """The render as a child's argument list."""
    cmd = [sys.executable, "-c", MESHTRACE, "render", scene, "-o", out]
    cmd += ["--spd"] * spd + ["--quiet"] * quiet
    return cmd + (["--stats", stats] if stats else [])


def timed(cmd: list[str], env: dict, tree: Path = ROOT) -> tuple[float, float, str]:
    """(wall seconds, CPU seconds, stderr) of one child run in `tree` to its end."""
    before, start = child_cpu(), time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=tree, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wall, cpu = time.perf_counter() - start, child_cpu() - before
    if done.returncode:
        sys.stderr.write(done.stderr.decode(errors="replace"))
        raise RuntimeError(f"{' '.join(cmd[3:])}: exit status {done.returncode}")
    return wall, cpu, done.stderr.decode(errors="replace")


def trees(against: str | None) -> dict[str, Path]:
    """The renders compared, by name: this tree's, and `against`'s if given."""
    out = {"render": ROOT}
    if against:
        out[f"render at {against}"] = Path(against).resolve()
    return out


def warm(scene: str, rounds: int, spd: bool, against: str | None = None) -> int:
    """Import numba and the warm render(s) in turns: their medians and the differences."""
    with tempfile.TemporaryDirectory() as tmp:
        subjects = {"import numba": ([sys.executable, "-c", IMPORT_NUMBA], ROOT)}
        for name, tree in trees(against).items():
            subjects[name] = (render_command(scene, f"{tmp}/x.png", spd, quiet=True), tree)
        for cmd, tree in subjects.values():  # untimed: kernels cached, bytecode written
            timed(cmd, child_env(tree), tree)
        walls, cpus = Turns(), Turns()
        for _, name in turns(list(subjects), rounds):
            cmd, tree = subjects[name]
            wall, cpu, _ = timed(cmd, child_env(tree), tree)
            walls.add(name, wall)
            cpus.add(name, cpu)
    shown = " ".join(["meshtrace", *subjects["render"][0][3:]]).replace(tmp, "/tmp")
    print(f"warm, {rounds} rounds in turns, seconds: median (least-most); the render: {shown}")
    width = max(len(name) for name in subjects)
    for name in subjects:
        wall, cpu = walls.figure(name).text(), cpus.figure(name).text()
        what = f'   python -c "{IMPORT_NUMBA}"' if name == "import numba" else ""
        print(f"{name:>{width}}: wall {wall}   CPU {cpu}{what}")
    for name in list(subjects)[1:]:
        dw = walls.figure(name).median - walls.figure("import numba").median
        dc = cpus.figure(name).median - cpus.figure("import numba").median
        pw, pc = (paired(t, name, "import numba").text("{:+.3f}") for t in (walls, cpus))
        print(
            f"{name} - import numba: difference of medians wall {dw:+.3f} s, CPU {dc:+.3f} s; "
            f"of each round's pair, median (least-most): wall {pw}, CPU {pc}"
        )
    return 0


def paired(times: Turns, a: str, b: str) -> Figure:
    """Each round's `a` seconds less its `b` seconds: a pair shares its spell of the machine."""
    sa, sb = times.seconds[a], times.seconds[b]
    return Figure.of(x - y for x, y in zip(sa, sb, strict=True))


def cold(scenes: list[str], spd: bool, against: str | None = None, rounds: int = 1) -> int:
    """Each scene's first render from an empty kernel cache, with its compile steps."""
    print("cold: each scene's first render, NUMBA_CACHE_DIR an empty folder; seconds")
    runs = [
        (s, *render) for _ in range(rounds) for s in scenes for render in trees(against).items()
    ]
    for scene, name, tree in runs:  # each scene's renders in turns, round after round
        with tempfile.TemporaryDirectory() as tmp:
            env = child_env(tree, cache=f"{tmp}/cache")
            out, stats = f"{tmp}/x.png", f"{tmp}/s.json"
            cmd = render_command(scene, out, spd, quiet=False, stats=stats)
            wall, cpu, err = timed(cmd, env, tree)
            stats = json.loads(Path(stats).read_text())
        where = "" if tree == ROOT else f" ({name})"
        print_cold(f"{Path(scene).name}{where}", wall, cpu, stats, err, flush=True)
    return 0


def print_cold(name: str, wall: float, cpu: float, stats: dict, err: str, flush=False) -> None:
    """One first render's line: its seconds and what compiled."""
    steps = "  ".join(f"{step} {float(s):.1f}" for step, s in STEP.findall(err))
    print(
        f"{name}: wall {wall:.1f}  CPU {cpu:.1f}  "
        f"compile {stats['compile_seconds']:.1f} ({steps or 'nothing compiled'})  "
        f"load {stats['load_seconds']:.2f}  build {stats['build_seconds']:.2f}  "
        f"trace {stats['trace_seconds']:.2f}  [{stats['engine']['kernel_variant']}]",
        flush=flush,
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="bench.start", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--scene",
        action="append",
        help="scene file (repeatable with --cold; default $MESHTRACE_SCENES/tetra.nff)",
    )
    p.add_argument("--turns", type=int, help="rounds in turns (7 of import numba, render; cold: 1)")
    p.add_argument("--cold", action="store_true", help="first renders from an empty cache")
    p.add_argument("--no-spd", dest="spd", action="store_false", help="render without --spd")
    p.add_argument("--against", metavar="DIR", help="another checkout's render, in turns")
    args = p.parse_args(argv)
    default = os.environ.get("MESHTRACE_SCENES")
    if not args.scene and not default:
        p.error("give --scene (or set MESHTRACE_SCENES to the SPD scenes' folder)")
    scenes = [str(Path(s).resolve()) for s in args.scene or [Path(default) / "tetra.nff"]]
    if args.cold:
        return cold(scenes, args.spd, args.against, args.turns or 1)
    if len(scenes) != 1:
        p.error("the warm comparison takes one --scene")
    return warm(scenes[0], args.turns or 7, args.spd, args.against)


if __name__ == "__main__":
    sys.exit(main())
