"""Every command's help prints and exits 0: a `%` in a help string, a bad default or a
broken `choices` shows up only when argparse formats the help, so each command and
subcommand of both parsers is formatted here, and the installed entry points once each."""

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from host.cli import _parser as host_parser
from host.cli.options import FLAGS
from meshnode.service.cli import parser as node_parser


def _commands(parser: argparse.ArgumentParser, path=()):
    """(argv prefix, parser) for a parser and every subcommand beneath it."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


CASES = [("host", path, p) for path, p in _commands(host_parser())] + [
    ("meshnode", path, p) for path, p in _commands(node_parser())
]


@pytest.mark.parametrize(
    ("prog", "path", "parser"), CASES, ids=[" ".join((c[0], *c[1])) for c in CASES]
)
def test_every_help_prints_and_exits_0(prog, path, parser, capsys):
    top = host_parser() if prog == "host" else node_parser()
    for flag in ("--help", "-h"):
        with pytest.raises(SystemExit) as done:
            top.parse_args([*path, flag])
        assert done.value.code == 0
        out = capsys.readouterr().out
        assert out.startswith("usage:") and "Traceback" not in out
        # every option of this (sub)command is listed
        for action in parser._actions:
            for option in action.option_strings:
                assert option in out, (prog, path, option)
        # values named in the user's terms, never by a record's field (IMAGESPEC.SPP)
        records = {dest.split(".")[0] for dest in FLAGS}
        assert records and not any(f"{r}.".upper() in out for r in records), out


def test_the_subcommands_are_all_walked():
    host = {" ".join(path) for prog, path, _ in CASES if prog == "host"}
    node = {" ".join(path) for prog, path, _ in CASES if prog == "meshnode"}
    assert {"", "render", "camera", "cluster-file"} <= host
    assert {"", "serve", "warmup"} <= node


@pytest.mark.parametrize("module", ["host.cli", "meshnode.service.cli"])
def test_the_commands_print_help_in_a_fresh_process(module):
    r = subprocess.run(
        [sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 0 and r.stdout.startswith("usage:"), r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("script", ["meshtrace", "meshnode"])
def test_installed_scripts_print_help(script):
    """The console scripts pip installs beside this interpreter (names no system tool takes)."""
    exe = Path(sys.executable).with_name(script)
    exe = exe if exe.exists() else shutil.which(script)
    assert exe, f"{script} is not installed: pip install -e ."
    r = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.startswith(f"usage: {script}"), r.stderr
