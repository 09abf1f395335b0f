"""The README's front door holds: the picture at the top exists, is small, and was made by the
command shown under it (which the real CLI parses); the test command is the one CI runs; and
nothing points outside the repository."""

import re
import shlex
from pathlib import Path

from host.cli import _parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_the_picture_on_top_is_made_by_the_command_shown():
    image = re.search(r"!\[[^\]]*\]\(([^)]+)\)", README).group(1)
    assert README.index(image) < README.index("## ")  # above the first section
    path = ROOT / image
    assert path.suffix == ".png" and 0 < path.stat().st_size < 300_000
    command = re.search(r"`(meshtrace render [^`]+)`", README).group(1)
    args = _parser().parse_args(shlex.split(command)[1:])
    assert Path(args.output) == Path(image) and (ROOT / args.scene).is_file()


def test_the_two_commands_and_no_path_outside_the_repository():
    assert '    pip install -e ".[test]" && python -m pytest -q\n' in README
    assert "    pip install . && meshtrace render host/examples/showcase.nff" in README
    assert "../" not in README
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'pip install -e ".[test]" && python -m pytest -q' in ci
