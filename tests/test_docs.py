"""The documentation site builds from docs/ with MkDocs in strict mode (a broken link, a
missing anchor or a page left out of the nav fails the build), its command-line reference
is generated from the parsers and lists every option of every command and subcommand, and
every page of docs/ is in the nav."""

import argparse
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from host.cli import _parser as host_parser
from meshnode.service.cli import parser as node_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _commands(parser: argparse.ArgumentParser, path=()):
    """(argv prefix, parser) for a parser and every subcommand beneath it (walked, not listed:
    the same walk as tests/test_help.py, apart from the hook's own)."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built once, strict: (its folder, what MkDocs printed)."""
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    log = r.stdout + r.stderr
    assert r.returncode == 0, log
    return out, log


def test_the_site_builds_strict_without_a_warning(site):
    out, log = site
    warnings = [line for line in log.splitlines() if re.match(r"\s*(WARNING|ERROR)\b", line)]
    assert not warnings, "\n".join(warnings)
    assert (out / "index.html").is_file() and (out / "cli" / "index.html").is_file()


def test_the_cli_page_lists_every_option_of_every_command(site):
    out, _ = site
    page = html.unescape(re.sub(r"<[^>]+>", "", (out / "cli" / "index.html").read_text()))
    assert "cli-help" not in page  # the hook replaced its marker
    for prog, top in (("meshtrace", host_parser()), ("meshnode", node_parser())):
        for path, parser in _commands(top):
            assert f"usage: {' '.join((prog, *path))} " in page, (prog, path)
            for action in parser._actions:
                for option in action.option_strings:
                    assert option in page, (prog, path, option)


def _nav_pages(node) -> list[str]:
    """Every page file of an mkdocs.yml nav (nested lists of {title: page or list})."""
    if isinstance(node, str):
        return [node]
    if isinstance(node, list):
        return [page for item in node for page in _nav_pages(item)]
    if isinstance(node, dict):
        return [page for value in node.values() for page in _nav_pages(value)]
    return []


def test_every_docs_page_is_in_the_nav():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    nav = _nav_pages(config["nav"])
    pages = sorted(p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md"))
    assert sorted(nav) == pages
    assert config["strict"] is True and config["hooks"] == ["docs/hooks.py"]
