"""Benchmarks run from the repository root, e.g. `python -m bench.spd`."""

import os
from pathlib import Path


def add_scenes_option(parser) -> None:
    """`--scenes DIR`: the folder of SPD scenes (README: where they come from), by default
    `$MESHTRACE_SCENES` as the tests read it; required when that is unset."""
    default = os.environ.get("MESHTRACE_SCENES")
    parser.add_argument("--scenes", type=Path, default=Path(default) if default else None,
                        required=not default,
                        help="folder of SPD *.nff scenes (default: $MESHTRACE_SCENES)")


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
