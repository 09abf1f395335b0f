"""Errors of the wire, each naming what was wrong so a link can log it and close, and the
one way either side turns any error into text that says what failed."""


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


class AuthFailed(ProtocolError):
    """The peer could not prove it holds the cluster secret (or this side could not)."""


class Saturated(ProtocolError):
    """The peer proved the secret, but the node has no room for another link of its kind
    now (its hosts' links all taken); the dialler may try again."""


def describe(error: BaseException) -> str:
    """`Type: message`; with an empty message (`str(TimeoutError())` is ""), the type and
    its cause, so no report ever ends in nothing."""
    text = str(error).strip()
    name = type(error).__name__
    if text:
        return f"{name}: {text}"
    cause = error.__cause__ or error.__context__
    if cause is not None and cause is not error:
        return f"{name} ({describe(cause)})"
    return f"{name} (no message)"
