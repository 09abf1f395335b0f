"""The wire between host and mesh nodes: record dtypes, scene containers and (later) framing.

Pure code: imports only the standard library, numpy and msgpack; never `host` or `meshnode`.
"""
