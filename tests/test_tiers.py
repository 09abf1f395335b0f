"""The test tiers find what spawns: a test that starts nodes through a helper of its module, or
through the CLI's --mesh, is `spawn`; a test of pure functions is not."""

import types

import pytest

import tests.test_mesh_service as mesh_service
from tests import tiers


def test_helpers_that_start_processes_are_followed_to_a_fixpoint():
    names = tiers.spawning_names(mesh_service)
    assert {"LocalMesh", "mesh_render", "slow_mesh"} <= names
    assert "records" not in names and "spd_scene" not in names


def test_tests_are_marked_by_what_they_call(probe_items):
    marked = {name for name, item in probe_items.items() if item.marks}
    assert marked == {"test_via_helper", "test_via_cli"}


class _Item:
    """What `classify` reads of a collected item: its module and function; marks it gets."""

    def __init__(self, module, function):
        self.module, self.function, self.marks = module, function, []

    def add_marker(self, mark):
        self.marks.append(mark)


def _probe_module():
    source = """
def start_nodes():
    return LocalMesh(4)

def test_via_helper():
    start_nodes()

def test_via_cli():
    main(["render", "s.nff", "--mesh", "2x2"])

def test_pure():
    assert 1 + 1 == 2
"""
    module = types.ModuleType("tests.probe_tiers")
    module.__file__ = "probe"
    exec(compile(source, "probe", "exec"), module.__dict__)
    return module, source


@pytest.fixture
def probe_items(monkeypatch):
    module, source = _probe_module()
    lines = source.splitlines(keepends=True)
    # inspect.getsource cannot read an exec'd module: serve each function's own lines
    blocks = {}
    for name in ("start_nodes", "test_via_helper", "test_via_cli", "test_pure"):
        start = next(i for i, line in enumerate(lines) if line.startswith(f"def {name}("))
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("def ")), None)
        blocks[getattr(module, name)] = "".join(lines[start:end])
    monkeypatch.setattr(tiers, "_source", lambda obj: blocks.get(obj, ""))
    items = {
        n: _Item(module, getattr(module, n))
        for n in ("test_via_helper", "test_via_cli", "test_pure")
    }
    tiers.classify(items.values())
    return items
