"""Kernels loaded from the disk cache at the cost of loading them, not of numba's compiler.

The first time numba loads a kernel from its disk cache it readies everything compiling
needs: it refreshes its CPU target (`Cache.load_overload`), importing and registering the
typing and lowering of every feature it has (strings, typed containers, random numbers,
datetimes, cffi, polynomials ...); its array functions check for BLAS by importing
scipy.linalg, which imports half of scipy; it scans every installed distribution for numba
extensions; and it imports the module of every function whose environment a loaded kernel
links, for that module's globals. A warm render compiles nothing, so none of it is needed:
together 0.45 s of CPU of a 1.3 s `meshtrace render tetra.nff --spd` (`bench.start`).
`install()`, called once by `meshnode.engine`, leaves each to the first compile:

- a load readies only what loaded code runs on: numba's runtime (NRT, the allocator of
  kernels that make arrays), whose few functions numba compiles anew in every process
  (45 ms): they are kept compiled in the kernel cache folder like a kernel. A miss
  compiles, and numba's compiler refreshes its target itself first (`CompilerBase`),
  extensions included, so compiling is as before. (One compiler module puts symbols in the
  linker's table when imported: numba.cpython.hashing, its hash secret for strings and
  bytes; a kernel hashing those would need it imported before it loads. None does: kernels
  take arrays and numbers.);
- the scan for extensions (`numba_extensions` entry points) is made before a compile, not
  before every first call: a load needs none (meshtrace kernels take no extension's types);
- a loaded environment gets its module's globals if the module is imported, else a stand-in
  naming the module: only object-mode code reads an environment's globals, and every
  kernel is nopython (`jit.py`). numba.np.arrayobj alone takes 0.1 s to import;
- a cache folder is checked writable (a temporary file made in it) once, not once for each
  of the 58 kernels a render's modules define;
- before a compile, numba's BLAS check will import `scipy.linalg.cython_blas`; that
  extension module is loaded alone, under its own name, so the check finds it without
  running the `scipy.linalg` package (0.3 s). It is the module scipy would load, so BLAS
  works as before; no kernel calls BLAS (np.dot and np.linalg stay out of kernels:
  `tests/test_start.py`).

Each is best effort: with a numba or scipy laid out otherwise it is left out.
MESHTRACE_PLAIN_NUMBA=1 leaves numba as it is (to tell whether a fault is ours).
"""

import hashlib
import importlib.machinery
import importlib.util
import os
import pickle
import sys
import threading
import time

BLAS = "scipy.linalg.cython_blas"
# CPU seconds this process spent loading kernels from the disk cache, or compiling those
# missing from it
_LOADING = [0.0]
_DEPTH = threading.local()  # compiles under way on this thread (a kernel compiles its callees)


def load_seconds() -> float:
    """CPU seconds this process's threads have spent loading kernels from the disk cache, or
    compiling them where it lacked them (0 where numba is left as it is): a process pays it
    once a kernel (a machine once a kernel, for compiles), so whoever first traces here (the
    host's cost pre-pass) can tell it from its own work."""
    return _LOADING[0]


def cpu_less_loads() -> float:
    """This process's CPU seconds less its kernel loads and compiles (`load_seconds`): a
    clock for work whose first run in a process also readies the kernels it calls."""
    return time.process_time() - _LOADING[0]


def install() -> None:
    """Make kernel loads cheap (see the module's docstring); safe to call more than once."""
    if os.environ.get("MESHTRACE_PLAIN_NUMBA") == "1":
        return
    from numba.core import caching, dispatcher, entrypoints, environment, runtime
    from numba.core.runtime import nrtdynmod

    if not hasattr(caching.Cache.load_overload, "readies_runtime_only"):
        _loads_ready_the_runtime_only(caching.Cache, runtime.rtsys, entrypoints)
        _extensions_before_compiling(dispatcher._DispatcherBase)
        _environments_without_imports(environment)
        _cache_folders_checked_once(caching)
        _runtime_kept_compiled(nrtdynmod)
        _compiles_timed(dispatcher.Dispatcher)


def _blas_alone() -> None:
    """scipy.linalg.cython_blas imported without its package, if scipy has it."""
    if BLAS in sys.modules or "scipy.linalg" in sys.modules:
        return
    try:
        scipy = importlib.util.find_spec("scipy")  # found, not imported
        if scipy is None or not scipy.submodule_search_locations:
            return
        linalg = [f"{place}/linalg" for place in scipy.submodule_search_locations]
        spec = importlib.machinery.PathFinder.find_spec(BLAS, linalg)
        if spec is None or spec.loader is None:
            return
        module = importlib.util.module_from_spec(spec)
        sys.modules[BLAS] = module
        spec.loader.exec_module(module)
    except Exception:  # any failure leaves numba to import it its own way
        sys.modules.pop(BLAS, None)


def _loads_ready_the_runtime_only(cache, rtsys, entrypoints) -> None:
    """numba's Cache.load_overload without the refresh of its whole target."""
    needed = ("_load_overload", "_guard_against_spurious_io_errors")
    if not all(hasattr(cache, name) for name in needed) or not hasattr(rtsys, "initialize"):
        return

    def load_overload(self, sig, target_context):
        """The cached compile result for `sig`, or None: numba then compiles it, after
        the extensions' initialisation its compile chain would have run first."""
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            loaded = self._load_overload(sig, target_context)
        if loaded is None:
            _blas_alone()
            entrypoints.init_all()
        return loaded

    load_overload.readies_runtime_only = True
    cache.load_overload = load_overload


def _compiles_timed(dispatcher) -> None:
    """A dispatcher's `compile` (a load from the disk cache, or a compile where it misses)
    timed into `load_seconds` on the thread that runs it (another's may run meanwhile),
    the outermost only: a kernel's compile compiles the functions it calls."""
    if not hasattr(dispatcher, "compile") or hasattr(dispatcher.compile, "timed"):
        return
    compile_ = dispatcher.compile

    def compile(self, sig):
        depth = getattr(_DEPTH, "n", 0)
        began = time.thread_time() if depth == 0 else 0.0
        _DEPTH.n = depth + 1
        try:
            return compile_(self, sig)
        finally:
            _DEPTH.n = depth
            if depth == 0:
                _LOADING[0] += time.thread_time() - began

    compile.timed = True
    dispatcher.compile = compile


def _extensions_before_compiling(base) -> None:
    """The dispatchers' first-call hook (it scans for extensions) left to the compile: a
    cache miss (`load_overload` above) or a dispatcher without a cache, whose compile
    refreshes the target, extensions included."""
    if hasattr(base, "_compilation_chain_init_hook"):
        base._compilation_chain_init_hook = lambda self: None


def _environments_without_imports(environment) -> None:
    """numba's pickled environments rebuilt without importing their modules."""
    needed = ("_rebuild_env", "lookup_environment", "Environment")
    if not all(hasattr(environment, name) for name in needed):
        return
    Environment = environment.Environment

    def _rebuild_env(modname, consts, env_name):
        env = environment.lookup_environment(env_name)
        if env is not None:
            return env
        module = sys.modules.get(modname)
        env = Environment(module.__dict__ if module is not None else {"__name__": modname})
        env.consts[:] = consts
        env.env_name = env_name
        Environment._memo[env_name] = env
        return env

    environment._rebuild_env = _rebuild_env


def _cache_folders_checked_once(caching) -> None:
    """numba's check that a kernel's cache folder is writable, made once per folder."""
    locator = getattr(caching, "_CacheLocator", None)
    if locator is None or not hasattr(locator, "ensure_cache_path"):
        return
    check = locator.ensure_cache_path
    checked: set = set()

    def ensure_cache_path(self):
        path = self.get_cache_path()
        if path not in checked:
            check(self)  # raises where the folder cannot be written: numba then looks on
            checked.add(path)

    locator.ensure_cache_path = ensure_cache_path


def _runtime_kept_compiled(nrtdynmod) -> None:
    """numba's runtime functions (`nrtdynmod.compile_nrt_functions`) loaded from a file in
    the kernel cache folder, compiled and written there when it is missing or unreadable."""
    needed = ("create_nrt_module", "compile_nrt_functions")
    if not all(hasattr(nrtdynmod, name) for name in needed):
        return
    compile_anew = nrtdynmod.compile_nrt_functions

    def compile_nrt_functions(ctx):
        import llvmlite
        import numba

        codegen = ctx.codegen()
        key = repr((numba.__version__, llvmlite.__version__, codegen.magic_tuple()))
        path = os.path.join(numba.config.CACHE_DIR, f"nrt-{_digest(key)}.pickle")
        try:
            with open(path, "rb") as f:
                return codegen.unserialize_library(pickle.load(f))
        except Exception:  # missing, unreadable or stale: compiled below
            pass
        try:
            ir_module, library = nrtdynmod.create_nrt_module(ctx)
            library.enable_object_caching()
            library.add_ir_module(ir_module)
            library.finalize()
            state = library.serialize_using_object_code()
        except Exception:  # numba's own way, kept out of the cache
            return compile_anew(ctx)
        try:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            temporary = f"{path}.{os.getpid()}"
            with open(temporary, "wb") as f:
                pickle.dump(state, f)
            os.replace(temporary, path)  # whole or not at all, for processes reading it
        except OSError:  # a read-only cache: compiled again next time
            pass
        return library

    nrtdynmod.compile_nrt_functions = compile_nrt_functions


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]
