"""Errors of the wire, each naming what was wrong so a link can log it and close."""


class ProtocolError(Exception):
    """A peer sent something this side cannot accept; the link carrying it is closed."""


class FrameTooLarge(ProtocolError):
    """A length prefix announced more bytes than the agreed maximum frame size."""


class BadFrame(ProtocolError):
    """A frame's payload is not a valid message (msgpack, fields or array sizes)."""


class UnknownKind(ProtocolError):
    """A message kind this protocol version does not define."""


class VersionMismatch(ProtocolError):
    """The peer speaks another protocol version or belongs to another cluster."""
