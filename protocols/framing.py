"""Length-prefixed msgpack frames: bytes in, whole messages out; never touches a socket.

A frame is a 4-byte big-endian payload length followed by a msgpack map. NumPy arrays travel as
raw bytes: an array field is encoded as the msgpack extension ARRAY_EXT whose data is
`name \\0 count(8 bytes LE) raw-bytes`, with `name` one of `protocols.dtypes.WIRE_DTYPES`, so
a batch of rays is one memcpy on each side and no Python object per ray.
"""

import struct

import msgpack
import numpy as np

from protocols.dtypes import WIRE_DTYPES
from protocols.errors import BadFrame, FrameTooLarge

HEADER = struct.Struct(">I")
MAX_FRAME = 64 * 1024 * 1024  # default bound on one frame's payload
ARRAY_EXT = 1
_NAMES = {dt: name for name, dt in WIRE_DTYPES.items()}


def _default(obj):
    """msgpack hook: NumPy arrays of wire dtypes become ARRAY_EXT extensions."""
    if isinstance(obj, np.ndarray):
        name = _NAMES.get(obj.dtype)
        if name is None or obj.ndim != 1:
            raise TypeError(f"cannot frame an array of dtype {obj.dtype} and shape {obj.shape}")
        head = name.encode() + b"\0" + struct.pack("<Q", len(obj))
        return msgpack.ExtType(ARRAY_EXT, head + np.ascontiguousarray(obj).tobytes())
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot frame {type(obj).__name__}")


def _ext_hook(code: int, data: bytes):
    """msgpack hook: ARRAY_EXT back into a NumPy array over the frame's bytes."""
    if code != ARRAY_EXT:
        raise BadFrame(f"unknown msgpack extension {code}")
    name, sep, rest = data.partition(b"\0")
    dtype = WIRE_DTYPES.get(name.decode("ascii", "replace"))
    if not sep or dtype is None or len(rest) < 8:
        raise BadFrame(f"bad array header {name[:32]!r}")
    (count,) = struct.unpack_from("<Q", rest)
    body = memoryview(rest)[8:]
    if len(body) != count * dtype.itemsize:
        raise BadFrame(f"array {name.decode()} of {count} records has {len(body)} bytes")
    return np.frombuffer(body, dtype=dtype, count=count)


def encode(message: dict, max_frame: int = MAX_FRAME) -> bytes:
    """One frame holding `message` (a dict of msgpack-able values and wire arrays)."""
    payload = msgpack.packb(message, default=_default, use_bin_type=True)
    if len(payload) > max_frame:
        raise FrameTooLarge(f"message of {len(payload)} bytes exceeds the {max_frame} limit")
    return HEADER.pack(len(payload)) + payload


def decode_payload(payload: bytes) -> dict:
    """The message in one frame's payload."""
    try:
        message = msgpack.unpackb(payload, ext_hook=_ext_hook, raw=False, strict_map_key=True)
    except BadFrame:
        raise
    except Exception as e:  # msgpack raises several unrelated types for corrupt input
        raise BadFrame(f"undecodable payload: {e}") from e
    if not isinstance(message, dict):
        raise BadFrame(f"a frame must hold a map, not {type(message).__name__}")
    return message


class FrameDecoder:
    """Feed it bytes as they arrive; it returns the whole messages and keeps the tail.

    A length over `max_frame` raises FrameTooLarge before any of that frame is buffered, so a
    broken or hostile peer cannot make the receiver allocate without bound."""

    def __init__(self, max_frame: int = MAX_FRAME):
        self.max_frame = max_frame
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a whole frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[dict]:
        self._buf += data
        out = []
        at = 0
        buf = self._buf
        while len(buf) - at >= HEADER.size:
            (size,) = HEADER.unpack_from(buf, at)
            if size > self.max_frame:
                raise FrameTooLarge(f"frame of {size} bytes exceeds the {self.max_frame} limit")
            if len(buf) - at - HEADER.size < size:
                break
            start = at + HEADER.size
            out.append(decode_payload(bytes(buf[start : start + size])))
            at = start + size
        del buf[:at]
        return out
