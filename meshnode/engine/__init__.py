"""The tracing engine: numba kernels over `protocols` dtypes, no sockets, no asyncio.

`Engine` is the Python-facing class; `host` uses it in-process for single-node renders and the
Python API, nodes run it on their own objects.
"""

from meshnode.engine import loading
from meshnode.engine.engine import Engine

loading.install()  # before the first kernel loads: only what loading needs is readied

__all__ = ["Engine"]
