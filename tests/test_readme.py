"""The README's front door holds: the picture at the top exists, is small, and was made by the
command shown under it (which the real CLI parses); the install and test commands are there,
the test command the one CI runs; the README stays short (the reference is the docs site);
and nothing it or the docs point at lies outside the repository."""

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
    assert "python3 -m venv .venv && . .venv/bin/activate" in README
    assert '    pip install -e ".[test]" && python -m pytest -q\n' in README
    assert "    pip install . && meshtrace render host/examples/showcase.nff -o showcase.png\n" in (
        README
    )
    assert "../" not in README
    ci = (ROOT / ".ci" / "run").read_text()
    assert 'pip install -e ".[test]" && python -m pytest -q' in ci


def test_the_readme_is_a_front_door_not_the_reference():
    assert len(README.splitlines()) <= 230


def test_every_link_lands_inside_the_repository():
    """Relative links of the README and the docs name files that exist, inside the checkout;
    nothing names the data shared beside it."""
    for doc in [ROOT / "README.md", ROOT / "mkdocs.yml", *sorted((ROOT / "docs").rglob("*.md"))]:
        text = doc.read_text()
        assert "../shared" not in text, doc
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue  # a URL, or an anchor of the same page
            path = (doc.parent / target.split("#")[0]).resolve()
            assert path.is_relative_to(ROOT) and path.exists(), (doc.name, target)


def _slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to '-'."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_the_readmes_anchors_name_headings_of_their_pages():
    """(MkDocs checks the docs' own anchors when the site builds; the README is not part of it.)"""
    for target, anchor in re.findall(r"\]\((docs/[^)#\s]+)#([^)\s]+)\)", README):
        headings = re.findall(r"^#+ (.+)$", (ROOT / target).read_text(), flags=re.M)
        assert anchor in {_slug(h.replace("`", "")) for h in headings}, (target, anchor)
