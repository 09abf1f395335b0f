"""Records that describe a render: frozen dataclasses with defaults, checks and a wire form.

Every setting of a render is one field of one record, with its default written once, on the
field. A record checks itself when built (from the command line, from Python, or from a
peer's CONFIG), and a bad value raises SpecError naming the record, the field and the value.
The wire form is a plain dict of the fields (nested records as dicts, arrays as wire arrays),
so `from_wire(to_wire(r)) == r`; `from_wire` refuses missing and unknown fields by name.
"""

import math
from dataclasses import MISSING, dataclass, fields
from typing import ClassVar

import numpy as np


class SpecError(ValueError):
    """A setting of a render has a bad value; the message names the field and the value."""


def default(record: type, name: str):
    """The default of one field (the command line shows and uses it; never a copy)."""
    f = record.__dataclass_fields__[name]
    return f.default if f.default is not MISSING else f.default_factory()


@dataclass(frozen=True)
class Spec:
    """Base of every render record: checks on construction, a dict wire form."""

    NESTED: ClassVar[dict] = {}  # field -> record class, for fields that are records themselves

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Raise SpecError for the first bad field (subclasses say what is allowed)."""

    def fail(self, name: str, want: str):
        raise SpecError(f"{type(self).__name__}.{name} = {getattr(self, name)!r}: {want}")

    def want_int(self, name: str, lo: int, hi: int, optional: bool = False) -> None:
        v = getattr(self, name)
        if optional and v is None:
            return
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or not lo <= v <= hi:
            self.fail(name, f"must be an integer from {lo} to {hi}")

    def want_number(
        self, name: str, lo: float, hi: float, open_lo: bool = False, optional: bool = False
    ) -> None:
        v = getattr(self, name)
        if optional and v is None:
            return
        ok = isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool)
        ok = ok and math.isfinite(v) and (lo < v if open_lo else lo <= v) and v <= hi
        if not ok:
            self.fail(
                name, f"must be a finite number {'>' if open_lo else '>='} {lo:g} and <= {hi:g}"
            )

    def want_choice(self, name: str, choices) -> None:
        value = getattr(self, name)
        if not isinstance(value, str | int) or isinstance(value, bool) or value not in choices:
            self.fail(name, f"must be one of {', '.join(map(str, choices))}")

    def want_bool(self, name: str) -> None:
        if not isinstance(getattr(self, name), bool):
            self.fail(name, "must be true or false")

    def to_wire(self) -> dict:
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, Spec):
                v = v.to_wire()
            elif isinstance(v, tuple):
                v = [list(x) if isinstance(x, tuple) else x for x in v]
            elif isinstance(v, np.ndarray):
                v = np.ascontiguousarray(v)
            out[f.name] = v
        return out

    @classmethod
    def from_wire(cls, d):
        """The record a peer sent, checked; SpecError names what is missing or unknown."""
        if not isinstance(d, dict):
            raise SpecError(f"{cls.__name__} must be a map of fields, got {type(d).__name__}")
        names = {f.name for f in fields(cls)}
        missing, extra = names - set(d), set(d) - names
        if missing or extra:
            raise SpecError(
                f"{cls.__name__}: missing fields {sorted(missing)}, unknown "
                f"fields {sorted(map(str, extra))}"
            )
        values = dict(d)
        for name, record in cls.NESTED.items():
            if values[name] is not None:
                values[name] = record.from_wire(values[name])
        return cls(**cls.decode(values))

    @classmethod
    def decode(cls, values: dict) -> dict:
        """Field values from their wire form (lists back to tuples, arrays to dtypes)."""
        return values
