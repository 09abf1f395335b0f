"""The import rule of DESIGN.md 2: host -> protocols <- meshnode; meshnode never imports host,
protocols imports neither, the engine has no sockets or asyncio, and the host reaches the node
side only through its public API (README, "Layout")."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# What the host may use of the node side: the engine (a compute library), the adaptive
# sampling books, the scheduler (pure: the host deals dynamic tiles with it) and the
# simulated mesh that drives it, and the framed link both ends speak (and its TLS options).
# Never the service, its session or node internals.
HOST_MAY_USE = ("meshnode.engine", "meshnode.adaptive", "meshnode.simulator", "meshnode.link",
                "meshnode.scheduler", "meshnode.tls")


def imports(path: Path, full: bool = False) -> set[str]:
    """Modules `path` imports (top-level package names, or full dotted names)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found = [node.module]
        else:
            continue
        names.update(found if full else (n.split(".")[0] for n in found))
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


def test_host_uses_the_node_side_only_through_its_public_api():
    files = list((ROOT / "host").rglob("*.py"))
    assert files
    for f in files:
        node_side = {m for m in imports(f, full=True) if m.split(".")[0] == "meshnode"}
        bad = {m for m in node_side if not m.startswith(HOST_MAY_USE)}
        assert not bad, f"{f.relative_to(ROOT)} imports node internals {sorted(bad)}"


def test_the_rule_checker_catches_node_internals(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from meshnode.service import NodeService\nimport meshnode.engine.grid\n")
    found = imports(probe, full=True)
    assert found == {"meshnode.service", "meshnode.engine.grid"}
    assert [m for m in sorted(found) if not m.startswith(HOST_MAY_USE)] == ["meshnode.service"]
    assert "meshnode.session" not in HOST_MAY_USE and "meshnode.node" not in HOST_MAY_USE
