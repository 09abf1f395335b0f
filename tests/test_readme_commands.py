"""Every `meshtrace render` command line in README.md runs, at a small size, and writes what it
says; the README's Python snippet runs as written. The lines are read from the README, so a
command edited there is the command tested here. (`meshnode serve`, docker compose and
kubectl lines are covered where those are tested: the cluster, compose and deploy tests.)"""

import re
import secrets
import shlex
from pathlib import Path

import numpy as np
import pytest

from host.cli import main
from host.run.localmesh import LocalMesh

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
EXAMPLE = ROOT / "host" / "examples" / "showcase.nff"
SMALL = ["--width", "24", "--height", "18", "--quiet"]


def command_lines() -> list[list[str]]:
    """The README's indented command lines that run `meshtrace render` (continuations joined,
    comments and any `pip install ... &&` before it dropped), split as a shell would."""
    text = README.replace("\\\n", " ")
    found = []
    for line in text.splitlines():
        if not line.startswith("    ") or "meshtrace render" not in line:
            continue
        command = line[line.index("meshtrace render") :]
        found.append(shlex.split(command, comments=True))
    return found


COMMANDS = command_lines()


def _small(argv: list[str], tmp: Path) -> list[str]:
    """`argv` made to run here: repository paths made absolute, a placeholder scene the
    example, outputs into `tmp`, a small image, a live view on any free port that exits."""
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a == "scene.nff":
            a = str(EXAMPLE)
        elif (ROOT / a).exists() and not a.startswith("-"):
            a = str(ROOT / a)
        elif a in ("-o", "--stats", "--float") and i + 1 < len(argv):
            out += [a, str(tmp / Path(argv[i + 1]).name)]
            i += 2
            continue
        elif a == "--serve":
            out += ["--serve", "127.0.0.1:0", "--serve-exit"]
            i += 2
            continue
        out.append(a)
        i += 1
    return out[2:] if out[:2] == ["meshtrace", "render"] else out


def test_the_readme_has_the_render_commands_it_should():
    assert len(COMMANDS) >= 4
    flags = {a for c in COMMANDS for a in c}
    assert {"--mesh", "--cluster", "--camera", "--threads"} <= flags


@pytest.mark.parametrize("argv", COMMANDS, ids=[" ".join(c[2:5]) for c in COMMANDS])
def test_every_readme_render_command_runs(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # outputs a line names by default land here
    args = ["render", *_small(argv, tmp_path), *SMALL]
    if "--cluster" in args:  # a cluster of one running node, named as the README's file is
        secret = secrets.token_hex(32)
        monkeypatch.setenv("MESHTRACE_SECRET", secret)
        with LocalMesh(1, secret=secret.encode()) as addresses:
            cluster = tmp_path / args[args.index("--cluster") + 1]
            cluster.write_text(f"0 0 {addresses[0]}\n")
            args[args.index("--cluster") + 1] = str(cluster)
            assert main(args) == 0
    else:
        assert main(args) == 0
    written = list(tmp_path.glob("*.png"))
    assert written, f"no image from: meshtrace {' '.join(args)}"
    for flag in ("--stats",):
        if flag in argv:
            assert (tmp_path / Path(argv[argv.index(flag) + 1]).name).stat().st_size > 0


def test_the_python_snippet_runs_as_written(monkeypatch):
    snippet = re.search(r"```python\n(.*?)```", README, re.S).group(1)
    monkeypatch.chdir(ROOT)
    scope: dict = {}
    exec(compile(snippet, "README.md", "exec"), scope)  # noqa: S102 - the README's own code
    image, stats = scope["image"], scope["stats"]
    assert image.shape[:2] == (240, 320) and np.isfinite(image).all() and image.max() > 0
    assert stats["rays"]["eye_rays"] > 0
