"""The import rule of DESIGN.md 2: host -> protocols <- meshnode; meshnode never imports host,
protocols imports neither, and the engine has no sockets or asyncio."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize(
    "package,forbidden",
    [
        ("protocols", {"host", "meshnode"}),
        ("meshnode", {"host"}),
        ("meshnode/engine", {"host", "asyncio", "socket", "uvloop"}),
    ],
)
def test_no_forbidden_imports(package, forbidden):
    files = list((ROOT / package).rglob("*.py"))
    assert files
    for f in files:
        bad = imports(f) & forbidden
        assert not bad, f"{f.relative_to(ROOT)} imports {sorted(bad)}"
