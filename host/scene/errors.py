"""The error every scene reader raises: bad input named by file and line.

Its own module so that the readers (NFF, OBJ, PLY, Inventor, settings) and the dispatcher that
chooses among them (host.scene.formats) all import it without importing each other.
"""


class SceneError(ValueError):
    """Bad scene input, worded `file:line: what is wrong` so editors and people can jump to it."""

    def __init__(self, source: str, line: int, what: str):
        super().__init__(f"{source}:{line}: {what}")
        self.source, self.line, self.what = source, line, what

    def __reduce__(self):
        # Default exception pickling calls cls(*args) with the one formatted message; keep the
        # parts so the error survives crossing a process boundary.
        return type(self), (self.source, self.line, self.what)
