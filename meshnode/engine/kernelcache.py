"""What the on-disk kernel cache holds, for telling a first run (kernels compile, tens of
seconds) from a later one (they load, about a second), and for checking that a warmup left
nothing to compile. The cache folder itself is chosen in `jit.py`; this module stays out of
the hash that names it, so it can change without a recompile."""

import contextlib
import hashlib
import sys
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; processes there may compile the same
    fcntl = None

import numba
from numba.core import event

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


def lock_path(name: str) -> Path:
    """The file `compiling(name)` locks, beside the warm markers."""
    return _marker(name).parent.parent / "lock" / _marker(name).name


@contextlib.contextmanager
def compiling(name: str):
    """Hold this cache folder's lock for the kernels named `name` while they compile:
    processes sharing the cache that need the same variant (a local mesh's nodes, a machine's
    test workers) compile it once and the others wait, then load it from disk; nine nodes of
    a 3x3 mesh otherwise compile it nine times over on the same cores. Best effort: where
    no lock can be taken (a read-only cache, no fcntl) each compiles its own."""
    path = lock_path(name)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(path, "a")  # held for the block: the lock goes with it
    except OSError:
        handle = None
    try:
        if handle is not None and fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)  # released on close, or when the holder dies
        yield
    finally:
        if handle is not None:
            handle.close()


@contextlib.contextmanager
def compiled_once(name: str):
    """`compiling(name)` over the block unless kernels named `name` are marked warm, then
    marked: for kernels of no variant (the structure builds), which every process sharing
    the cache would otherwise compile at once (a cold 3x3's nine nodes each compiled the
    hierarchy build in 82-85 s)."""
    if is_warm(name):
        yield
        return
    with compiling(name):
        yield
    mark_warm(name)


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


class CompileClock:
    """Seconds numba spent compiling (cache misses only: loading from the disk cache is not
    counted) while `compile_clock()` was installed, so a first run's summary can tell
    compiling from building and loading."""

    def __init__(self):
        self.listener = event.TimingListener()

    @property
    def seconds(self) -> float:
        return self.listener.duration if self.listener.done else 0.0


@contextlib.contextmanager
def compile_clock():
    """A CompileClock over the block (numba's compile events are process-wide: compiles on
    other threads meanwhile count too)."""
    clock = CompileClock()
    with event.install_listener("numba:compile", clock.listener):
        yield clock
