"""Sizes as people write them on command lines (512M, 8G), for the host's and the node's
options alike."""

import argparse


def memory_size(text: str) -> int:
    """A memory size: bytes, or a number with K, M, G or T (powers of 1024)."""
    units = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    unit = t[-1:] if t[-1:] in units else ""
    try:
        value = float(t[: len(t) - len(unit)]) * units[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a memory size (e.g. 512M, 8G)") from None
    if not 0 < value < 1 << 62:
        raise argparse.ArgumentTypeError(f"{text!r}: a memory size must be positive")
    return int(value)
