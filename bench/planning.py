"""The host's planning CPU for object space under a memory budget (issue 38: planning that
stays cheap as the mesh grows), each plan made on a freshly read scene.

    python -m bench.planning [--scenes DIR] [--only balls,gears,rings,teapot,tetra,mount]
                             [--meshes 3x3] [--max-share 0.25] [--size 256] [--spp 64]
                             [--repeat 3] [--json FILE]

Two figures per scene and mesh, in turns (`bench.timing.interleaved`, this process's CPU):

- the whole plan with every stage of the pre-pass run (its allowance lifted), with what a plan
  shares (`prepass.planning`: its simulations' engines and the eye's view of the map;
  `host.scene.derived`: the scene's tables and clipped boxes) and with each simulation
  building its own engines and eye map and each clip and table made anew, and the ratio of
  the two (the plans are the same: `tests/test_plan_engines`);
- the plan as `host render` makes it at `--spp`: its CPU, the pre-pass's allowance (a tenth
  of one node's tracing, estimated from the first cut), what the pre-pass spent and which
  stages it skipped (`host.planning.allowance`).
"""

import argparse
import contextlib
import math
import sys
from pathlib import Path
from unittest import mock

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import add_scenes_option, per_mesh, read_scene  # noqa: E402 (after the path is set)
from bench.timing import interleaved  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="bench.planning", description=__doc__.split("\n\n")[0])
    add_scenes_option(p)
    p.add_argument("--only", default="balls,gears,rings,teapot,tetra,mount")
    p.add_argument("--meshes", default="3x3")
    p.add_argument(
        "--max-share",
        default="0.25",
        help="the share of the objects a node may hold, one for every mesh or one per mesh",
    )
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("--repeat", type=int, default=3, help="rounds of turns (3)")
    p.add_argument("--json", type=Path)
    return p.parse_args(argv)


def _request(folder: Path, name: str, rows: int, cols: int, share: float, args):
    from host.planning.request import Auto, Request
    from protocols.render import EngineSpec, ImageSpec, MeshPlan

    plan = MeshPlan(rows, cols, 1.0, "objects", "object", "static", max_share=share)
    image = ImageSpec(args.size, args.size, spp=args.spp)
    scene = read_scene(folder, name)
    return Request(scene, image, EngineSpec(threads=1), plan=plan, auto=Auto(budget_copies=True))


@contextlib.contextmanager
def _nothing_shared():
    """Every simulation builds its own engines and eye map, every clip and table anew."""
    from host.planning import allowance, plan

    with (
        mock.patch.object(
            plan, "planning", lambda n: contextlib.nullcontext(allowance.Allowance())
        ),
        mock.patch("host.scene.derived.kept", lambda scene, name, make: make()),
        mock.patch("host.planning.clip.kept", lambda scene, name, make: make()),
    ):
        yield


def measure(folder: Path, name: str, mesh: str, share: float, args) -> dict:
    """One scene's figures on one mesh (module docstring)."""
    from host.planning import allowance
    from host.planning.plan import plan_render

    rows, cols = map(int, mesh.split("x"))

    def every_stage(shared: bool):
        def run():
            request = _request(folder, name, rows, cols, share, args)
            with mock.patch.object(allowance, "PREPASS_SHARE", math.inf):
                with contextlib.nullcontext() if shared else _nothing_shared():
                    return plan_render(request)

        return run

    plan_render(_request(folder, name, rows, cols, share, args))  # kernels loaded, caches warm
    subjects = {
        "shared": every_stage(True),
        "anew": every_stage(False),
        "bounded": lambda: plan_render(_request(folder, name, rows, cols, share, args)),
    }
    times, results = interleaved(subjects, args.repeat)
    prepass = results["bounded"].balance.get("prepass", {})
    return {
        "scene": name,
        "mesh": mesh,
        "max_share": share,
        "spp": args.spp,
        **times.figure("shared").fields("every_stage_shared_cpu_seconds"),
        **times.figure("anew").fields("every_stage_anew_cpu_seconds"),
        **times.ratio("anew", "shared").fields("anew_over_shared"),
        **times.figure("bounded").fields("bounded_cpu_seconds"),
        "prepass": prepass,
    }


def main(argv=None) -> int:
    from bench import finish

    args = parse_args(argv)
    print(
        f"{'scene':8s} {'mesh':4s} {'every stage, shared s':>22s} {'anew s':>18s} "
        f"{'anew/shared':>16s} {'at ' + str(args.spp) + ' spp s':>18s} {'allowed s':>9s} "
        "skipped"
    )
    rows, meshes = [], args.meshes.split(",")
    shares = per_mesh(args.max_share, meshes)
    for name in args.only.split(","):
        for mesh, share in zip(meshes, shares, strict=True):
            r = measure(args.scenes, name, mesh, share, args)
            rows.append(r)
            pp = r["prepass"]
            skipped = ", ".join(dict.fromkeys(s["stage"] for s in pp.get("skipped", ())))
            print(
                f"{name:8s} {mesh:4s} {_text(r, 'every_stage_shared_cpu_seconds'):>22s} "
                f"{_text(r, 'every_stage_anew_cpu_seconds'):>18s} "
                f"{_text(r, 'anew_over_shared', '{:.2f}'):>16s} "
                f"{_text(r, 'bounded_cpu_seconds'):>18s} "
                f"{pp.get('allowed_cpu_seconds') or 0.0:>9.2f} {skipped or 'nothing'}",
                flush=True,
            )
    return finish(rows, args.json, [], "", "planning measured on every scene")


def _text(row: dict, name: str, fmt: str = "{:.2f}") -> str:
    low, high = row[f"{name}_low"], row[f"{name}_high"]
    return f"{fmt.format(row[name])} ({fmt.format(low)}-{fmt.format(high)})"


if __name__ == "__main__":
    sys.exit(main())
