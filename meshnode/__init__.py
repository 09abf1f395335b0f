"""A mesh node: the tracing engine (`engine`), the mesh algorithm without sockets (`mesh`), the
framed link both sides speak (`transport`) and the asyncio node service (`service`)."""
