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
