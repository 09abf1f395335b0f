"""What the on-disk kernel cache holds, for telling a first run (kernels compile, tens of
seconds) from a later one (they load, about a second), and for checking that a warmup left
nothing to compile. The cache folder itself is chosen in `jit.py`; this module stays out of
the hash that names it, so it can change without a recompile."""

import hashlib
import sys
from pathlib import Path

import numba

from meshnode.engine.trace import trace_batch


def _marker(name: str) -> Path:
    """numba keeps a folder per source location inside the cache (a checkout and an installed
    copy of the same sources share the cache but not their kernels): mark in that one."""
    folder = Path(trace_batch.stats.cache_path)
    return folder / "warm" / hashlib.sha256(name.encode()).hexdigest()[:16]


def is_warm(name: str) -> bool:
    """Whether the kernels named `name` (an engine variant, the camera) were compiled into
    this cache folder; a new version of the kernel sources has a new, empty folder."""
    return _marker(name).exists()


def mark_warm(name: str) -> None:
    """Note that the kernels named `name` are in the cache (best effort: a read-only cache
    only means the next run says it compiles when it loads)."""
    try:
        _marker(name).parent.mkdir(parents=True, exist_ok=True)
        _marker(name).touch()
    except OSError:
        pass


def kernels_compiled() -> int:
    """Kernels compiled in this process rather than loaded from the disk cache (numba's cache
    misses over every engine dispatcher): zero for a render after `meshnode warmup`."""
    total = 0
    for name, module in list(sys.modules.items()):
        if not name.startswith("meshnode.engine."):
            continue
        for value in vars(module).values():
            if isinstance(value, numba.core.registry.CPUDispatcher):
                total += sum(value.stats.cache_misses.values())
    return total
