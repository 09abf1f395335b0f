"""Decorators for every kernel: compiled once, cached on disk, GIL released.

numba keys a cached kernel on its own file only, so a change in a kernel it calls from another
file, or in a constant it reads from another file, would load stale machine code. The cache
therefore lives in a folder named after a hash of every engine source file that defines kernels
and of every engine module those import (constants such as counter indices and table columns
are compiled in), under NUMBA_CACHE_DIR if set, else the user's cache folder; other plain Python
modules beside them can change without a recompile.

`leaf` kernels allocate nothing, so they are compiled without numba's reference counting:
a call between jitted functions otherwise touches the count of every array argument, which
costs more than a whole ray-sphere test when made once per ray segment.
"""

import hashlib
import os
import re
from pathlib import Path

import numba


def _cache_dir() -> str:
    """A cache folder per version of the engine sources (and of protocols' dtypes)."""
    here = Path(__file__).resolve().parent
    texts = {f.name: f.read_bytes() for f in here.glob("*.py")}
    kernels = [name for name, text in texts.items() if b"from meshnode.engine.jit import" in text]
    imported = re.findall(
        rb"from meshnode\.engine\.(\w+) import", b"".join(texts[name] for name in kernels)
    )
    digest = hashlib.sha256()
    for name in sorted({"jit.py", *kernels, *(m.decode() + ".py" for m in imported)}):
        digest.update(name.encode() + texts[name])
    digest.update(b"dtypes.py" + (here.parent.parent / "protocols" / "dtypes.py").read_bytes())
    root = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "meshtrace"
    )
    return os.path.join(root, f"engine-{digest.hexdigest()[:16]}")


numba.config.CACHE_DIR = _cache_dir()

kernel = numba.njit(cache=True, nogil=True, error_model="numpy")
leaf = numba.njit(cache=True, nogil=True, error_model="numpy", _nrt=False)
inline = numba.njit(cache=True, nogil=True, error_model="numpy", _nrt=False, inline="always")
