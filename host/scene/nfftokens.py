"""NFF text as whitespace tokens, each with its line, and the readers of numbers and counts
over them; every error is a `SceneError` reading `file:line: what is wrong`.

The file is read as tokens, not line by line: SPD writes a cone's eight numbers on one line
where the spec shows three, and neither layout is wrong. The entity grammar on top of these
readers is `host.scene.nff`'s.
"""

from __future__ import annotations

import math
import re
from itertools import chain

import numpy as np

from host.scene.errors import SceneError
from protocols.scene import MAX_COORDINATE

_COMMENT = re.compile(r"#[^\n]*")
INT = re.compile(r"[+-]?[0-9]+")

_ASCII_SPACE = np.zeros(256, bool)
_ASCII_SPACE[[9, 10, 11, 12, 13, 28, 29, 30, 31, 32]] = True  # what str.split() splits on


def _tokens(body: str) -> tuple[list[str], np.ndarray]:
    """Whitespace tokens of `body` and the 1-based line of each.

    str.split() makes the tokens in C; the lines come from where tokens start in the bytes,
    because a list per line (the obvious way) costs several times more in allocation and
    garbage-collector passes. Non-ASCII text, where Unicode spaces also split, goes line by line.
    """
    toks = body.split()
    if body.isascii() and body:
        b = np.frombuffer(body.encode("ascii"), np.uint8)
        space = _ASCII_SPACE[b]
        start = np.flatnonzero(space[1:] < space[:-1]) + 1  # non-space after space
        if not space[0]:
            start = np.concatenate(([0], start))
        if len(start) == len(toks):
            return toks, np.searchsorted(np.flatnonzero(b == 10), start) + 1
    per_line = [ln.split() for ln in body.split("\n")]
    lines = np.repeat(np.arange(1, len(per_line) + 1), [len(t) for t in per_line])
    return list(chain.from_iterable(per_line)), lines


def _strict_float(tok: str) -> float:
    """float() also takes '1_0' and non-ASCII digits; NFF numbers are plain ASCII."""
    if "_" in tok or not tok.isascii():
        raise ValueError(tok)
    return float(tok)


class Tokens:
    """The tokens of one NFF text with their lines, read as numbers and counts."""

    def __init__(self, text: str, source: str):
        self.source = source
        body = _COMMENT.sub("", text)
        self.toks, self.tline = _tokens(body)
        self.n_lines = max(1, text.count("\n") + (0 if text.endswith("\n") else 1))
        # Plain float() is the fast path; the strict one is only needed if the text could hold
        # something float() accepts but NFF does not.
        self.conv = float if body.isascii() and "_" not in body else _strict_float

    # -- errors -------------------------------------------------------------------------------

    def error(self, i: int, what: str) -> SceneError:
        """An error at token i's line: every message points into the file."""
        return SceneError(self.source, int(self.tline[i]), what)

    def need(self, i: int, k: int, at: int) -> None:
        """Raise if fewer than k tokens remain from i; reported at the entity's token `at`."""
        have = len(self.toks) - i
        if have < k:
            raise self.error(
                at,
                f"'{self.toks[at]}' needs {k} number{'s' * (k != 1)} "
                f"but the file ends after {max(have, 0)}",
            )

    # -- token readers ------------------------------------------------------------------------

    def nums(self, i: int, k: int, at: int) -> list[float]:
        """k finite floats from token i on; `at` is the entity's token, for end-of-file errors."""
        seg = self.toks[i : i + k]
        try:
            vals = list(map(self.conv, seg))
        except ValueError:
            for j, tok in enumerate(seg):
                try:
                    self.conv(tok)
                except ValueError:
                    raise self.error(
                        i + j, f"'{self.toks[at]}': expected a number, got {tok!r}"
                    ) from None
            raise  # unreachable: map() failed, so one token fails alone
        if len(vals) < k:
            self.need(i, k, at)
        # One sum, max and min instead of k checks; an overflowing sum of finite values
        # just costs the slow look.
        if (
            not math.isfinite(sum(vals))
            or max(vals) > MAX_COORDINATE
            or min(vals) < -MAX_COORDINATE
        ):
            for j, v in enumerate(vals):
                if not math.isfinite(v):
                    raise self.error(i + j, f"non-finite number {seg[j]!r}")
                if abs(v) > MAX_COORDINATE:
                    raise self.error(
                        i + j,
                        f"{seg[j]} is beyond +-{MAX_COORDINATE:g} (the "
                        "tracer's products would overflow)",
                    )
        return vals

    def is_number(self, i: int) -> bool:
        """Whether token i is a number: optional groups (a light's colour) end at a word."""
        if i >= len(self.toks):
            return False
        try:
            self.conv(self.toks[i])
        except ValueError:
            return False
        return True

    def count(self, i: int, at: int) -> int:
        """Vertex count of `p`/`pp` at token i."""
        if i >= len(self.toks):
            raise self.error(at, f"'{self.toks[at]}' needs a vertex count but the file ends")
        tok = self.toks[i]
        if not INT.fullmatch(tok):
            raise self.error(i, f"vertex count must be an integer, got {tok!r}")
        n = int(tok)
        if n < 3:
            raise self.error(i, f"a polygon needs at least 3 vertices, got {n}")
        return n
