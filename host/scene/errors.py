"""The error every scene reader raises: bad input named by file and line.

Its own module so that the readers (NFF, OBJ, PLY, Inventor, settings) and the dispatcher that
chooses among them (host.scene.formats) all import it without importing each other.
"""

import re

QUOTE_AT_MOST = 80  # characters of one piece of bad input an error repeats


def clipped(what: str) -> str:
    """`what` with every run of more than QUOTE_AT_MOST characters without a space cut to
    its start and its length: a 10 MB number in a scene file was echoed whole."""

    def cut(m: re.Match) -> str:
        word = m.group(0)
        return f"{word[: QUOTE_AT_MOST - 20]}... ({len(word):,} characters)"

    return re.sub(rf"\S{{{QUOTE_AT_MOST + 1},}}", cut, what)


class SceneError(ValueError):
    """Bad scene input, worded `file:line: what is wrong` so editors and people can jump to it
    (what bad input it quotes, at most QUOTE_AT_MOST characters at a time)."""

    def __init__(self, source: str, line: int, what: str):
        what = clipped(what)
        super().__init__(f"{source}:{line}: {what}")
        self.source, self.line, self.what = source, line, what

    def __reduce__(self):
        # Default exception pickling calls cls(*args) with the one formatted message; keep the
        # parts so the error survives crossing a process boundary.
        return type(self), (self.source, self.line, self.what)
