"""A kernel bound to the argument types of its calls, so repeated calls skip numba's typing.

numba's dispatcher types every argument on every call to find the compiled overload; for the
tracing kernel's named tuples of tables that took ~13 us of a ~45 us call (one ray, tetra),
and a mesh node makes thousands of calls per render, many on a few dozen passed rays. An
engine's tables are the same objects on every call, so only the arrays made per batch need a
key: the overload found for a key is called directly from then on.

The first call of each engine typed every argument too (about a millisecond for the tracing
kernel's forty arrays and tuples), and the cost pre-pass builds engines by the hundred, each
called first on a few dozen rays. Engines of one kernel variant pass arguments of the same
types, so the overload found for one is kept for all (`_SHARED`), keyed by a structural key of
every argument (`type_key`: what numba's type of each depends on, read off in Python).
"""

import numpy as np

# (dispatcher, type_key of every argument) -> compiled entry point, for every Bound
_SHARED: dict = {}


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
        if entry is None:
            entry = self.entries[key] = self._entry(args)
        return entry(*args)

    def _entry(self, args):
        """The callable for `args`' types: an overload another Bound found for the same
        types, else the dispatcher's (compiled or loaded now if need be)."""
        shared = type_key(args)
        entry = _SHARED.get((self.dispatcher, shared)) if shared is not None else None
        if entry is not None:
            return entry
        sig = tuple(self.dispatcher.typeof_pyval(a) for a in args)
        if sig not in self.dispatcher.overloads:
            self.dispatcher.compile(sig)  # loads it from the disk cache where it is there
        compiled = self.dispatcher.overloads.get(sig)
        if compiled is None:  # found only by converting types: the dispatcher decides
            return self.dispatcher
        if shared is not None:
            _SHARED[(self.dispatcher, shared)] = compiled.entry_point
        return compiled.entry_point


def array_key(a) -> tuple | None:
    """What numba's type of an array argument depends on (None for None)."""
    if a is None:
        return None
    f = a.flags
    return (a.dtype, a.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned)


def type_key(value):
    """What numba's type of `value` depends on, as a hashable key (None where that is not
    known here: the value is typed by numba): arrays by `array_key` and their dtype's
    alignment, tuples (named ones by their class) item by item, scalars by their class (a
    Python int by whether it fits in 64 signed bits too)."""
    if isinstance(value, np.ndarray):
        return (np.ndarray, value.dtype.isalignedstruct, *array_key(value))
    if isinstance(value, tuple):
        items = tuple(type_key(v) for v in value)
        return None if any(i is None for i in items) else (type(value), items)
    if isinstance(value, bool) or value is None or isinstance(value, float | np.generic):
        return (type(value),)
    if isinstance(value, int):
        return (int, -(2**63) <= value < 2**63)
    return None
