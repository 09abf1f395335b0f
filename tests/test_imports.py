"""The import rule (docs/architecture.md), by package: host -> protocols <- meshnode.

Each package of the node side and each wing of the host is a layer; a layer may import only
the layers listed for it (and protocols, the standard library and third parties), so nothing
points back up: the engine knows nothing of the mesh, the mesh algorithm nothing of sockets,
the transport nothing of either, and the host never reaches the node's service except through
frames. The layers are found from the tree, so a new package has to be placed here."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# layer -> the project layers it may import (itself and protocols always)
MAY_IMPORT = {
    "protocols": set(),
    "meshnode.engine": set(),
    "meshnode.transport": set(),
    "meshnode.mesh": {"meshnode.engine"},
    "meshnode.service": {"meshnode.engine", "meshnode.mesh", "meshnode.transport"},
    "host.scene": {"meshnode.engine"},
    "host.camera": {"host.scene", "meshnode.engine"},
    "host.planning": {"host.scene", "host.camera", "meshnode.engine", "meshnode.mesh"},
    "host.run": {
        "host.scene",
        "host.camera",
        "host.planning",
        "meshnode.engine",
        "meshnode.mesh",
        "meshnode.transport",
    },
    "host.live": {"host.run"},
    "host.cli": {
        "host.scene",
        "host.camera",
        "host.planning",
        "host.run",
        "host.live",
        "meshnode.transport",
    },
}
# Modules that may import nothing that blocks or touches the network.
NO_IO = {"protocols", "meshnode.engine", "meshnode.mesh"}
IO = {"asyncio", "socket", "uvloop", "ssl"}


def layer(module: str) -> str:
    """The layer a dotted module name belongs to: a package of meshnode or host (host.cli
    is a layer of its own), or protocols."""
    parts = module.split(".")
    if parts[0] == "protocols":
        return "protocols"
    return ".".join(parts[:2]) if len(parts) > 1 else parts[0]


def imports(path: Path) -> set[str]:
    """Full dotted names of the modules `path` imports (absolute imports only)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def sources() -> list[tuple[str, Path]]:
    """(layer, file) for every module of the three packages."""
    out = []
    for top in ("protocols", "meshnode", "host"):
        for f in sorted((ROOT / top).rglob("*.py")):
            module = ".".join(f.relative_to(ROOT).with_suffix("").parts)
            out.append((layer(module), f))
    return out


def test_every_module_is_in_a_layer_the_rule_names():
    unplaced = {
        str(f.relative_to(ROOT))
        for lay, f in sources()
        if lay not in MAY_IMPORT and f.name != "__init__.py"
    }
    assert not unplaced, f"modules outside every layer of the rule: {sorted(unplaced)}"


@pytest.mark.parametrize("name", sorted(MAY_IMPORT))
def test_a_layer_imports_only_what_it_may(name):
    files = [f for lay, f in sources() if lay == name]
    assert files, name
    allowed = MAY_IMPORT[name] | {name, "protocols"}
    for f in files:
        project = {m for m in imports(f) if m.split(".")[0] in ("protocols", "meshnode", "host")}
        bad = sorted(m for m in project if layer(m) not in allowed)
        assert not bad, f"{f.relative_to(ROOT)} ({name}) imports {bad}"
        if name in NO_IO:
            io = sorted({m.split(".")[0] for m in imports(f)} & IO)
            assert not io, f"{f.relative_to(ROOT)} ({name}) imports {io}"


def test_the_layers_have_no_cycle():
    seen, done = set(), set()

    def visit(node, path):
        assert node not in seen - done, f"import cycle: {' -> '.join([*path, node])}"
        if node in done:
            return
        seen.add(node)
        for nxt in MAY_IMPORT[node]:
            visit(nxt, [*path, node])
        done.add(node)

    for node in MAY_IMPORT:
        visit(node, [])


def test_the_rule_checker_catches_a_service_import(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("from meshnode.service.server import NodeService\nimport host.run.cluster\n")
    found = imports(probe)
    assert found == {"meshnode.service.server", "host.run.cluster"}
    assert {layer(m) for m in found} == {"meshnode.service", "host.run"}
    assert "meshnode.service" not in MAY_IMPORT["host.run"] | MAY_IMPORT["host.cli"]
    assert "host.run" not in MAY_IMPORT["host.scene"]


def test_the_architecture_page_names_every_layer_and_its_rule():
    """docs/architecture.md's table lists each layer with what it may import, as here."""
    page = (ROOT / "docs" / "architecture.md").read_text()
    rows = {}
    for line in page.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`"):
            allowed = {c.strip("` ") for c in cells[2].split(",")} - {"nothing of the project"}
            rows[cells[0].strip("`")] = allowed - {"every host layer"}
    assert set(rows) == set(MAY_IMPORT)
    for name, allowed in rows.items():
        if name != "host.cli":  # "every host layer" stands for the list
            assert allowed == MAY_IMPORT[name], name
