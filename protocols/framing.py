"""Length-prefixed frames: bytes in, whole messages out; never touches a socket.

A frame is a 4-byte big-endian payload length, then the payload: a 4-byte big-endian length
of a msgpack map, the map, and the raw bytes of the map's arrays one after the other, each
starting at a multiple of ALIGN bytes into the payload. In the map an array field is the
msgpack extension ARRAY_EXT holding only `name \0 count (8 bytes LE)`, `name` one of
`protocols.dtypes.WIRE_DTYPES`; its records follow the map in the order the map names them.

So a batch of rays is copied once on each side: on the sender by the kernel's write from the
arrays' own buffers (`frame_buffers`: the frame as the buffers it is made of, for a vectored
write; an array field may be `protocols.records.Parts`, several arrays sent as one), and on the
receiver into the payload's buffer, where the arrays are then views (aligned, writable).
bench.link measures it against a raw socket.
"""

import struct
import weakref

import msgpack
import numpy as np

from protocols.dtypes import WIRE_DTYPES
from protocols.errors import BadFrame, FrameTooLarge
from protocols.records import Parts

HEADER = struct.Struct(">I")
MAP = struct.Struct(">I")  # the msgpack map's length, first in the payload
MAX_FRAME = 64 * 1024 * 1024  # default bound on one frame's payload
ARRAY_EXT = 1
ALIGN = 8  # every array's records start at a multiple of this into the payload
POOL_LEAST = 1 << 20  # a payload from this size is received into a reused buffer
POOL_BYTES = 32 << 20  # the most a decoder keeps for reuse, its buffers in use included
POOL_STEP = 1 << 20  # a pooled buffer's size is rounded up to this (ray batches vary)
_NAMES = {dt: name for name, dt in WIRE_DTYPES.items()}
_ZEROS = bytes(ALIGN)


def _aligned(at: int) -> int:
    return -(-at // ALIGN) * ALIGN


def encode(message: dict, max_frame: int = MAX_FRAME) -> bytes:
    """One frame holding `message` (a dict of msgpack-able values and wire arrays), as bytes."""
    return b"".join(frame_buffers(message, max_frame))


def frame_buffers(message: dict, max_frame: int = MAX_FRAME) -> list:
    """One frame holding `message`, as the buffers it is made of in order: its header and map,
    then each array's records where they lie (padding between), for a vectored write that
    copies them once, into the socket. The caller must not change the arrays until written."""
    fields: list[tuple] = []  # each array field's parts, in the map's order

    def default(obj):
        """msgpack hook: a NumPy array of a wire dtype (or `Parts` of one) becomes an
        ARRAY_EXT placeholder; its records go after the map."""
        if isinstance(obj, (np.ndarray, Parts)):
            parts = obj.arrays if isinstance(obj, Parts) else (obj,)
            name = _NAMES.get(obj.dtype)
            if name is None or any(a.ndim != 1 for a in parts):
                shape = getattr(obj, "shape", "parts")
                raise TypeError(f"cannot frame an array of dtype {obj.dtype} and shape {shape}")
            fields.append(tuple(np.ascontiguousarray(a) for a in parts))
            count = struct.pack("<Q", sum(len(a) for a in parts))
            return msgpack.ExtType(ARRAY_EXT, name.encode() + b"\0" + count)
        if isinstance(obj, np.generic):
            return obj.item()
        raise TypeError(f"cannot frame {type(obj).__name__}")

    meta = msgpack.packb(message, default=default, use_bin_type=True)
    head, at = [b"", MAP.pack(len(meta)), meta], MAP.size + len(meta)
    parts = []
    for field in fields:  # aligned at its first record; its parts end to end
        pad = _aligned(at) - at
        if pad:
            parts.append(_ZEROS[:pad])
        at += pad
        for a in field:
            if a.nbytes:
                parts.append(memoryview(a).cast("B"))
                at += a.nbytes
    if at > max_frame:
        raise FrameTooLarge(f"message of {at} bytes exceeds the {max_frame} limit")
    head[0] = HEADER.pack(at)
    return [b"".join(head), *parts]


def decode_payload(payload) -> dict:
    """The message in one frame's payload (bytes, or a writable buffer its arrays view)."""
    view = memoryview(payload)
    if len(view) < MAP.size:
        raise BadFrame(f"a payload of {len(view)} bytes has no map length")
    (size,) = MAP.unpack_from(view)
    if size > len(view) - MAP.size:
        raise BadFrame(f"map of {size} bytes in a payload of {len(view)}")
    at = [MAP.size + size]  # where the next array's records start (before alignment)

    def ext_hook(code: int, data: bytes):
        """msgpack hook: an ARRAY_EXT placeholder becomes its records, viewed in place."""
        if code != ARRAY_EXT:
            raise BadFrame(f"unknown msgpack extension {code}")
        name, sep, rest = data.partition(b"\0")
        dtype = WIRE_DTYPES.get(name.decode("ascii", "replace"))
        if not sep or dtype is None or len(rest) != 8:
            raise BadFrame(f"bad array header {name[:32]!r}")
        (count,) = struct.unpack("<Q", rest)
        start = _aligned(at[0])
        if count > (len(view) - start) // dtype.itemsize:
            raise BadFrame(
                f"array {name.decode()} of {count} records: only {max(len(view) - start, 0)} "
                "bytes follow"
            )
        at[0] = start + count * dtype.itemsize
        return np.frombuffer(view, dtype=dtype, count=count, offset=start)

    try:
        message = msgpack.unpackb(
            view[MAP.size : MAP.size + size], ext_hook=ext_hook, raw=False, strict_map_key=True
        )
    except BadFrame:
        raise
    except Exception as e:  # msgpack raises several unrelated types for corrupt input
        raise BadFrame(f"undecodable payload: {e}") from e
    if not isinstance(message, dict):
        raise BadFrame(f"a frame must hold a map, not {type(message).__name__}")
    if at[0] != len(view):
        raise BadFrame(f"{len(view) - at[0]} bytes after the map's arrays")
    return message


class FrameDecoder:
    """Feed it bytes as they arrive; it returns the whole messages and keeps the tail.

    A length over `max_frame` raises FrameTooLarge before any of that frame is buffered, so a
    broken or hostile peer cannot make the receiver allocate without bound. A frame's payload
    is copied once, into a buffer of its announced size, which its arrays then view; a large
    one into a `Payloads` buffer whose last frame nothing views any more."""

    def __init__(self, max_frame: int = MAX_FRAME):
        self.max_frame = max_frame
        self._head = bytearray()  # a length prefix still arriving
        self._body: np.ndarray | None = None  # the payload being filled (bytes)
        self._filled = 0
        self._payloads = Payloads()

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a whole frame."""
        return len(self._head) + self._filled

    def buffer(self, least: int) -> memoryview:
        """Where the next bytes may be written: the rest of a payload still arriving, when at
        least `least` bytes of it are missing (a reader then receives a large frame's records
        straight into their place: the one copy on this side); else None, and they come
        through `feed`."""
        if self._body is not None and len(self._body) - self._filled >= least:
            return memoryview(self._body[self._filled :])
        return None

    def wrote(self, n: int) -> list[dict]:
        """`n` bytes were written into `buffer()`: the frame they complete, if any."""
        self._filled += n
        if self._filled < len(self._body):
            return []
        body, self._body, self._filled = self._body, None, 0
        self._head.clear()
        return [decode_payload(body)]

    def feed(self, data) -> list[dict]:
        view, out, at = memoryview(data).cast("B"), [], 0
        while at < len(view):
            if self._body is None:
                take = min(HEADER.size - len(self._head), len(view) - at)
                self._head += view[at : at + take]
                at += take
                if len(self._head) < HEADER.size:
                    break
                (size,) = HEADER.unpack(self._head)
                if size > self.max_frame:
                    raise FrameTooLarge(f"frame of {size} bytes exceeds the {self.max_frame} limit")
                self._body, self._filled = self._payloads.take(size), 0
            take = min(len(self._body) - self._filled, len(view) - at)
            self._body[self._filled : self._filled + take] = np.frombuffer(
                view[at : at + take], np.uint8
            )
            self._filled += take
            at += take
            if self._filled == len(self._body):
                body, self._body, self._filled = self._body, None, 0
                self._head.clear()
                out.append(decode_payload(body))
        return out


class Payloads:
    """Large payload buffers, reused once nothing views their last frame.

    A fresh buffer's pages are zeroed by the kernel as the bytes first land in them, which
    cost as much as receiving the bytes (`python -m bench.link`: the receiver 0.36-0.48 s of
    CPU for 200 frames of 6.8 MB, against 0.23-0.29 s receiving into reused buffers). A frame's
    arrays view its buffer, so a buffer is handed out again only when the view it last lent
    (and so every array made from it) is gone: a weak reference tells."""

    def __init__(self, limit: int = POOL_BYTES):
        self.limit = limit
        self._kept: list[list] = []  # [buffer, weak reference to the view last lent, or None]

    def take(self, size: int) -> np.ndarray:
        """`size` bytes to receive a payload into (its contents undefined)."""
        if size < POOL_LEAST:
            return np.empty(size, np.uint8)  # touches no page: taken as the bytes arrive
        free = sorted(
            (k for k in self._kept if k[1] is None or k[1]() is None), key=lambda k: len(k[0])
        )
        kept = next((k for k in free if len(k[0]) >= size), None)
        if kept is None:
            need = -(-size // POOL_STEP) * POOL_STEP
            for small in free:  # too small for it: room given back, smallest first
                if self._held() + need <= self.limit:
                    break
                # by identity: `list.remove` compares with ==, which on arrays is elementwise
                self._kept = [k for k in self._kept if k is not small]
            if self._held() + need > self.limit:
                return np.empty(size, np.uint8)  # the rest are in use: this one is not kept
            kept = [np.empty(need, np.uint8), None]
            self._kept.append(kept)
        view = kept[0][:size]
        kept[1] = weakref.ref(view)
        return view

    def _held(self) -> int:
        return sum(len(k[0]) for k in self._kept)
