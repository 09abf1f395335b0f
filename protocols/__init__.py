"""What host and mesh nodes agree on: the records of a render, record dtypes of ray, deposit and
object batches, the scene container, frames, messages, the handshake, torus topology and the
render's states.

Pure code: imports only the standard library, numpy and msgpack; never `host` or
`meshnode`.
"""
