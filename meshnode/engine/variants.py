"""The compiled variants of the kernels: numba compiles a kernel once per combination of
argument types, and the engine passes an absent kind, lights, transmitters or structure as
None, so each node's mix of objects and its structure select one variant. `meshnode warmup`
compiles them all ahead; the engine, the warm-up and the tests name them from here."""

import itertools
from typing import NamedTuple

from meshnode.engine.tables import Tables
from protocols.scene import OBJECT_KINDS

# What `Engine.warmup` compiles, one numba specialisation each: one node's tracing kernel, a
# mesh node's (segments clipped to its box, those leaving it returned), the probe's nearest hits.
KERNELS = ("trace", "passing", "probe")


# The structures a variant is compiled for: the tracing kernels walk one, the other is passed
# as None and compiled out (a hierarchy's kernel carried the grid walk and brute force, a
# grid's the hierarchy walk and the packets: tetra's cold tracing kernel took 13 s of CPU
# to compile, 9 s now; balls' on a grid 13 s, 6.5 s now; docs/measurements.md).
# Brute force (the tests' reference) is a value of the grid's variant: it bounds its rays
# by the grid's box and shares the grid's compiled kernels.
STRUCTURES = ("grid", "bvh")
# A render's statistics name a variant with the engine's storage in the structure's place
# (`Engine.variant`): each storage's structure.
STORAGES = {"csr": "grid", "hash": "grid", "brute-force": "grid", "grid": "grid", "bvh": "bvh"}


class Variant(NamedTuple):
    """What one compiled variant of the kernels holds code for: numba compiles a kernel once
    per combination of argument types, and an absent kind, lights, transmitters or structure
    is None. (The grid's storages and brute force are values, not types: they share the
    grid's variant.)"""

    kinds: tuple[str, ...]  # primitive kinds present, in OBJECT_KINDS order
    smooth: bool  # some triangle has vertex normals
    shadows: bool  # there are lights
    refraction: bool  # some object transmits
    structure: str  # of STRUCTURES: the one the tracing kernels walk

    @property
    def name(self) -> str:
        return "/".join(
            [
                "+".join(self.kinds) or "empty",
                "smooth" if self.smooth else "flat",
                "shadows" if self.shadows else "no-shadows",
                "refraction" if self.refraction else "no-refraction",
                self.structure,
            ]
        )

    @classmethod
    def parse(cls, name: str) -> "Variant":
        """The variant whose `name` this is (`meshnode warmup --variant`), or whose the
        engine's `kernel_variant` is (the grid's storage, csr, hash or brute-force, in the
        structure's place); ValueError for a name no variant has."""
        parts = name.split("/")
        if len(parts) == 5 and parts[4] in STORAGES:
            kinds = () if parts[0] == "empty" else tuple(parts[0].split("+"))
            flags = (parts[1] == "smooth", parts[2] == "shadows", parts[3] == "refraction")
            variant = cls(kinds, *flags, STORAGES[parts[4]])
            if variant.name == "/".join([*parts[:4], variant.structure]):
                if variant in all_variants():
                    return variant
        raise ValueError(
            f"no kernel variant is named {name!r}: KINDS/smooth|flat/shadows|no-shadows/"
            "refraction|no-refraction/STRUCTURE, KINDS one or more of "
            f"{'+'.join(OBJECT_KINDS)} in that order, or empty, STRUCTURE grid or bvh "
            "(or the grid's storage, csr, hash or brute-force)"
        )


def variant_of(tables: Tables, structure: str) -> Variant:
    """The variant the engine compiles for these tables and `structure` (of STRUCTURES): the
    engine's one choice function."""
    return Variant(
        tuple(tables.kinds),
        tables.tri_normals is not None,
        tables.lights is not None,
        bool(tables.transmitters),
        structure,
    )


def all_variants() -> list[Variant]:
    """Every variant `variant_of` can choose: any set of kinds, smooth only with triangles,
    refraction only with some object; lights or not; either structure (what `meshnode
    warmup` compiles)."""
    out = []
    for n in range(len(OBJECT_KINDS) + 1):
        for kinds in itertools.combinations(OBJECT_KINDS, n):
            for smooth, shadows, refraction in itertools.product((False, True), repeat=3):
                if (smooth and "triangles" not in kinds) or (refraction and not kinds):
                    continue
                out.extend(Variant(kinds, smooth, shadows, refraction, s) for s in STRUCTURES)
    return out
