"""MkDocs hook: the command-line reference (docs/cli.md) from the parsers themselves.

`on_page_markdown` replaces the marker in cli.md with the `--help` of every command and
subcommand of `meshtrace` and `meshnode`, walked from `host.cli._parser()` and
`meshnode.service.cli.parser()` (subparsers found, not listed), so the page cannot drift from
the code.
"""

import argparse
import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

MARKER = "<!-- cli-help -->"
ROOT = Path(__file__).resolve().parents[1]
WIDTH = 100  # the columns argparse formats the help for


def commands(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """(subcommand path, parser) for a parser and every subcommand beneath it."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from commands(sub, (*path, name))


@contextlib.contextmanager
def _as_meshtrace() -> Iterator[None]:
    """The host's parser names itself after the running script (`host.cli.parser.prog`):
    build it as `meshtrace`, at a fixed width, whatever runs MkDocs."""
    argv0, columns = sys.argv[0], os.environ.get("COLUMNS")
    sys.argv[0], os.environ["COLUMNS"] = "meshtrace", str(WIDTH + 2)
    try:
        yield
    finally:
        sys.argv[0] = argv0
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


def parsers() -> list[argparse.ArgumentParser]:
    """The top-level parsers of `meshtrace` and `meshnode`."""
    if str(ROOT) not in sys.path:  # `mkdocs` run by its script, from a checkout not installed
        sys.path.insert(0, str(ROOT))
    from host.cli import _parser
    from meshnode.service.cli import parser

    return [_parser(), parser()]


def reference() -> str:
    """Markdown: a section per command and subcommand, its --help in a code block."""
    sections = []
    with _as_meshtrace():
        for top in parsers():
            for path, parser in commands(top):
                name = " ".join((top.prog, *path))
                text = parser.format_help().rstrip()
                sections.append(f"## `{name}`\n\n```text\n{text}\n```\n")
    return "\n".join(sections)


def on_page_markdown(markdown: str, page, config, files) -> str:
    """Fill the marker of cli.md with the reference; other pages pass through."""
    if page.file.src_uri != "cli.md":
        return markdown
    if MARKER not in markdown:
        raise ValueError(f"docs/cli.md lost its marker {MARKER}")
    return markdown.replace(MARKER, reference())
