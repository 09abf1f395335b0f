"""Test tiers: which tests start processes (node meshes, the CLI in a subprocess, a browser,
network namespaces) and which are slow, so a developer runs the fast tier in about a minute
(`pytest -m "not spawn and not slow"`) while CI runs everything.

`spawn` is found, not listed: a test spawns if its source names a spawning primitive, or a
function that does (helpers of its own module or imported from another test module, followed
to a fixpoint), so a new test lands in the right tier by itself. `slow` is a decorator in
the test file (`@pytest.mark.slow`): tests over about ten seconds of their own on a warm cache.
"""

import inspect
import re
import types

# What starts a process or a network namespace, by name.
PRIMITIVES = (
    "LocalMesh",
    "subprocess",
    "Popen",
    "namespaced_mesh",
    "netns",
    "webdriver",
    "faultnode",
    "docker",
    '"--mesh"',  # the CLI starting a local mesh (1x1 too: cheap to misfile, dear to miss)
    '"--cluster"',
)
MARKERS = {
    "spawn": "starts processes (meshnode nodes, the CLI, a browser) or network namespaces",
    "slow": "takes over about ten seconds on a warm kernel cache",
}


def _source(obj) -> str:
    try:
        return inspect.getsource(obj)
    except (OSError, TypeError):
        return ""


def _mentions(text: str, names) -> bool:
    """Whether `text` names any of `names` (whole names, not parts of dotted ones)."""
    return any(re.search(rf"(?<![\w.]){re.escape(n)}", text) for n in names)


def spawning_names(module: types.ModuleType) -> set[str]:
    """Names in `module` that start processes: the primitives, and every test-suite function
    visible there whose source uses one of them (to a fixpoint)."""
    helpers = {
        name: _source(obj)
        for name, obj in vars(module).items()
        if callable(obj) and str(getattr(obj, "__module__", "")).startswith("tests")
    }
    found = set(PRIMITIVES)
    changed = True
    while changed:
        changed = False
        for name, text in helpers.items():
            if name not in found and _mentions(text, found):
                found.add(name)
                changed = True
    return found


def classify(items) -> None:
    """Mark every collected test that spawns with `spawn`."""
    import pytest

    per_module: dict[str, set[str]] = {}
    for item in items:
        module = getattr(item, "module", None)
        function = getattr(item, "function", None)
        if module is None or function is None:
            continue
        if module.__name__ not in per_module:  # once a module (not setdefault: it would
            per_module[module.__name__] = spawning_names(module)  # read every source again)
        names = per_module[module.__name__]
        if _mentions(_source(function), names):
            item.add_marker(pytest.mark.spawn)
