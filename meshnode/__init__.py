"""A mesh node: the tracing engine (`meshnode.engine`) and, later, the asyncio service."""
