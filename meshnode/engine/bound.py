"""A kernel bound to the argument types of its calls, so repeated calls skip numba's typing.

numba's dispatcher types every argument on every call to find the compiled overload; for the
tracing kernel's named tuples of tables that took ~13 us of a ~45 us call (one ray, tetra),
and a mesh node makes thousands of calls per render, many on a few dozen passed rays. An
engine's tables are the same objects on every call, so only the arrays made per batch need a
key: the overload found for a key is called directly from then on.
"""


class Bound:
    """`dispatcher` called through its compiled entry point, looked up once per `key`.

    `key` must name the types of every argument that can change between calls (`array_key`
    of each array); the other arguments must be the same objects on every call. A key whose
    overload the dispatcher found only by converting types stays on the dispatcher."""

    def __init__(self, dispatcher):
        self.dispatcher = dispatcher
        self.entries: dict = {}

    def __call__(self, key, *args):
        entry = self.entries.get(key)
        if entry is not None:
            return entry(*args)
        result = self.dispatcher(*args)  # compiles or loads the overload, types checked
        sig = tuple(self.dispatcher.typeof_pyval(a) for a in args)
        compiled = self.dispatcher.overloads.get(sig)
        self.entries[key] = compiled.entry_point if compiled is not None else self.dispatcher
        return result


def array_key(a) -> tuple | None:
    """What numba's type of an array argument depends on (None for None)."""
    if a is None:
        return None
    f = a.flags
    return (a.dtype, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned)
