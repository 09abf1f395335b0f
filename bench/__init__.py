"""Benchmarks run from the repository root, e.g. `python -m bench.spd`."""

import os
from pathlib import Path

from host.run.localmesh import NODE_ENVIRONMENT

# Before numpy loads: a bench's own process (the one node its meshes are measured against, or
# a link's sender) runs as the nodes it starts do.
for _name, _value in NODE_ENVIRONMENT.items():
    os.environ.setdefault(_name, _value)


def add_scenes_option(parser) -> None:
    """`--scenes DIR`: the folder of SPD scenes (docs/scenes.md: where they come from), by default
    `$MESHTRACE_SCENES` as the tests read it; required when that is unset."""
    default = os.environ.get("MESHTRACE_SCENES")
    parser.add_argument(
        "--scenes",
        type=Path,
        default=Path(default) if default else None,
        required=not default,
        help="folder of SPD *.nff scenes (default: $MESHTRACE_SCENES)",
    )


def read_scene(folder: Path, name: str):
    """The scene `name` from `folder/NAME.nff`; where that file is absent and `name` is an SPD
    program's (`mount`, `tetra_s8`: `bench.generate.spd`), generated in memory as the SPD
    would print it, so a table's generated rows (the full mountain, a 65,536-triangle tetra)
    come from the same command as its files'."""
    from host.scene.nff import read_nff

    path = folder / f"{name}.nff"
    if path.exists():
        return read_nff(path)
    from bench.generate import spd

    try:
        return spd(name, printed=True)
    except ValueError as e:
        raise FileNotFoundError(f"{path}: no such scene file, and {e}") from None


def add_simulated_mesh_options(parser, only: str, size: int, spp: int) -> None:
    """The options of a benchmark that simulates one object-space mesh in this process:
    scenes (`--scenes`, `--only`), `--mesh` rows x cols, `--overlap`, image `--size` and
    `--spp`, and `--json` for its rows."""
    add_scenes_option(parser)
    parser.add_argument("--only", default=only)
    parser.add_argument("--mesh", default="3x3", help="rows x cols")
    parser.add_argument("--overlap", type=float, default=100.0)
    parser.add_argument("--size", type=int, default=size)
    parser.add_argument("--spp", type=int, default=spp)
    parser.add_argument("--json", type=Path)


def per_mesh(values: str, meshes: list) -> list[float]:
    """A comma-separated option given once for every mesh or once per mesh (`--max-share
    0.5,0.25`), as one float per mesh."""
    got = [float(v) for v in values.split(",")]
    got = got * len(meshes) if len(got) == 1 else got
    if len(got) != len(meshes):
        raise SystemExit(f"{values}: one value, or one per mesh of {len(meshes)}")
    return got


def finish(rows: list, path: Path | None, bad: list[str], failure: str, success: str) -> int:
    """A benchmark's end: its rows as JSON to `path` (if given), then `failure` and the rows
    that broke an exactness check (exit 1), or `success` (exit 0)."""
    import json

    if path:
        path.write_text(json.dumps(rows, indent=2) + "\n")
    if bad:
        print(failure + "\n".join(bad))
        return 1
    print("\n" + success)
    return 0
