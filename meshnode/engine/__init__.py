"""The tracing engine: numba kernels over `protocols` dtypes, no sockets, no asyncio.

`Engine` is the Python-facing class; `host` uses it in-process for single-node renders and the
Python API, nodes run it on their own objects.
"""

from meshnode.engine.engine import Engine

__all__ = ["Engine"]
