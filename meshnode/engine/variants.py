"""The compiled variants of the kernels: numba compiles a kernel once per combination of
argument types, and the engine passes an absent kind, lights or transmitters as None, so
each scene's mix of objects selects one variant. `meshnode warmup` compiles them all ahead;
the engine, the warm-up and the tests name them from here."""

import itertools
from typing import NamedTuple

from meshnode.engine.tables import Tables
from protocols.scene import OBJECT_KINDS

# What `Engine.warmup` compiles, one numba specialisation each: one node's tracing kernel, a
# mesh node's (segments clipped to its box, those leaving it returned), the probe's nearest hits.
KERNELS = ("trace", "passing", "probe")


class Variant(NamedTuple):
    """What one compiled variant of the kernels holds code for: numba compiles a kernel once
    per combination of argument types, and an absent kind, lights or transmitters is None.
    (Grid storage and brute force are values, not types: they share a variant.)"""

    kinds: tuple[str, ...]  # primitive kinds present, in OBJECT_KINDS order
    smooth: bool  # some triangle has vertex normals
    shadows: bool  # there are lights
    refraction: bool  # some object transmits

    @property
    def name(self) -> str:
        return "/".join(
            [
                "+".join(self.kinds) or "empty",
                "smooth" if self.smooth else "flat",
                "shadows" if self.shadows else "no-shadows",
                "refraction" if self.refraction else "no-refraction",
            ]
        )

    @classmethod
    def parse(cls, name: str) -> "Variant":
        """The variant whose `name` this is (`meshnode warmup --variant`), or the engine's
        `kernel_variant` with its storage after it (storages share a variant); ValueError
        for a name no variant has."""
        parts = name.split("/")
        if len(parts) == 5 and parts[4] in ("csr", "hash", "bvh", "brute-force"):
            parts, name = parts[:4], name.rsplit("/", 1)[0]
        if len(parts) == 4:
            kinds = () if parts[0] == "empty" else tuple(parts[0].split("+"))
            flags = (parts[1] == "smooth", parts[2] == "shadows", parts[3] == "refraction")
            variant = cls(kinds, *flags)
            if variant.name == name and variant in all_variants():
                return variant
        raise ValueError(
            f"no kernel variant is named {name!r}: KINDS/smooth|flat/shadows|no-shadows/"
            "refraction|no-refraction, KINDS one or more of "
            f"{'+'.join(OBJECT_KINDS)} in that order, or empty"
        )


def variant_of(tables: Tables) -> Variant:
    """The variant the engine compiles for these tables: the engine's one choice function."""
    return Variant(
        tuple(tables.kinds),
        tables.tri_normals is not None,
        tables.lights is not None,
        bool(tables.transmitters),
    )


def all_variants() -> list[Variant]:
    """Every variant `variant_of` can choose: any set of kinds, smooth only with triangles,
    refraction only with some object; lights or not (what `meshnode warmup` compiles)."""
    out = []
    for n in range(len(OBJECT_KINDS) + 1):
        for kinds in itertools.combinations(OBJECT_KINDS, n):
            for smooth, shadows, refraction in itertools.product((False, True), repeat=3):
                if (smooth and "triangles" not in kinds) or (refraction and not kinds):
                    continue
                out.append(Variant(kinds, smooth, shadows, refraction))
    return out
