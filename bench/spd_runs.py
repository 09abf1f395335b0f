"""The SPD benchmark's in-process runs: one scene traced under each configuration (structure,
grid storage, density) on an engine built once, best of N. Kept apart from the report and the
POV-Ray side so every other part of the benchmark reuses the same measurement."""

import time
from pathlib import Path

from host.planning.request import Request
from meshnode.engine.counters import RAY_COUNTS

STORAGES = ("csr", "hash")
COUNT_KEYS = RAY_COUNTS
COUNT_LABELS = ("eye", "hits", "reflected", "refracted", "shadow", "blocked")


def default_density() -> float:
    """The density `host render` uses when not told."""
    from protocols.render import EngineSpec
    from protocols.spec import default

    return default(EngineSpec, "density")


def default_storage() -> str:
    """The grid storage `host render` uses when not told."""
    from protocols.render import EngineSpec
    from protocols.spec import default

    return default(EngineSpec, "storage")


class CountMismatchError(AssertionError):
    """Ray counts differ between configurations of one scene (an engine bug: grid and
    hierarchy are both exact)."""


def warm_kernels(scene) -> dict:
    """Load grid-build, eye-ray and tracing kernels for both storages on a coarse grid and for
    the hierarchy, so the first measured configuration pays no kernel loading; returns the load
    seconds per storage and 'bvh' (the grid is asked for: auto might build a hierarchy)."""
    from meshnode.engine import Engine
    from meshnode.engine.camera import eye_rays
    from protocols.render import ImageSpec

    eye_rays(scene.view, ImageSpec(spd=True).sized(scene.view), rows=(0, 1))
    loads = {}
    for name, kw in [
        *((s, {"structure": "grid", "storage": s, "density": 0.05}) for s in STORAGES),
        ("bvh", {"structure": "bvh"}),
    ]:
        start = time.perf_counter()
        Engine(scene, **kw).warmup()
        loads[name] = time.perf_counter() - start
    return loads


def config_plan(structures: list[str], densities: list[float]) -> list[tuple[str, str, float]]:
    """(structure, storage, density) of each configuration of one scene: the grid's storages x
    densities, the hierarchy (storage and density unused), and last always the default."""
    plan = [("grid", s, d) for s in STORAGES for d in densities] if "grid" in structures else []
    if "bvh" in structures:
        plan.append(("bvh", default_storage(), default_density()))
    return plan + [("auto", default_storage(), default_density())]


def build(scene, structure: str, storage: str, density: float):
    """The engine of one configuration, built once for all its repeats (SPD shells' grid
    takes tens of seconds to build)."""
    from meshnode.engine import Engine

    return Engine(scene, structure=structure, storage=storage, density=density)


def run_config(
    scene,
    structure: str,
    storage: str,
    density: float,
    repeats: int,
    built=None,
    size: int | None = None,
) -> dict:
    """Render `repeats` times with one configuration; keep the best tracing time.
    `built`: that configuration's engine, reused (a big scene's structure is built once);
    `size`: image side under the SPD rules (default 512)."""
    from host.run.oneprocess import render
    from protocols.render import EngineSpec, ImageSpec

    image = ImageSpec(spd=True, width=size, height=size)
    engine = EngineSpec(threads=1, structure=structure, storage=storage, density=density)
    runs = [render(Request(scene, image, engine), built=built)[1] for _ in range(repeats)]
    best = min(runs, key=lambda s: s["trace_seconds"])
    stats = best["engine"]
    is_grid = stats["structure"] == "grid"  # a hierarchy's grid is only a one-voxel box
    c = {
        "structure": structure,
        "used_structure": stats["structure"],
        "structure_reason": stats["structure_reason"],
        "storage": storage,
        "used_storage": stats["grid"]["storage"] if is_grid else None,
        "density": density,
        "resolution": stats["grid"]["resolution"] if is_grid else None,
        "bvh": stats["bvh"],
        "preprocess_seconds": min(s["preprocess_seconds"] for s in runs),  # one if built
        "trace_seconds": best["trace_seconds"],
        "trace_seconds_all": [s["trace_seconds"] for s in runs],
        # the tracing thread's CPU seconds (what the POV-Ray ratios compare), best of the runs
        "trace_cpu_seconds": min(s["trace_cpu_seconds"] for s in runs),
        "trace_cpu_seconds_all": [s["trace_cpu_seconds"] for s in runs],
        "total_rays": best["total_rays"],
        "rays_per_second": best["total_rays"] / best["trace_seconds"],
        "tests_per_ray": best["tests_per_ray"],
        "steps_per_ray": best["steps_per_ray"],
        "structure_bytes": stats["structure_bytes"],
        "kernel_load_seconds": stats.get("kernel_load_seconds"),
        "rays": best["rays"],
        "variant": stats["kernel_variant"],
    }
    return {"label": _label(c), **c}


def check_counts(name: str, configs: list[dict]) -> tuple[str | None, list[str]]:
    """Compare the printed ray counts across configurations: a mismatch message (None when
    they agree), and warnings for other counters that differ."""
    counts = [{k: c["rays"][k] for k in COUNT_KEYS} for c in configs]
    error = None
    if any(c != counts[0] for c in counts):
        lines = [f"  {c['label']}: {n}" for c, n in zip(configs, counts, strict=True)]
        error = f"{name}: ray counts differ between configurations:\n" + "\n".join(lines)
    warnings = []
    for key in sorted(set(configs[0]["rays"]) - set(COUNT_KEYS)):
        values = {c["label"]: c["rays"].get(key) for c in configs}
        if len(set(values.values())) > 1:
            warnings.append(f"{name}: counter {key} differs between configurations: {values}")
    return error, warnings


def bench_scene(path: Path, plan: list[tuple[str, str, float]], repeats: int) -> dict:
    """Every configuration of `plan` on one scene, best of `repeats` each; the last is the
    default (structure auto, storage auto, default density)."""
    from host.scene.nff import read_nff
    from meshnode.engine.counters import spd_counts

    scene = read_nff(path)
    loads = warm_kernels(scene)
    configs = [run_config(scene, *c, repeats, built=build(scene, *c)) for c in plan]
    error, warnings = check_counts(path.stem, configs)
    best, dflt = min(configs, key=lambda c: c["trace_seconds"]), configs[-1]
    return {
        "scene": path.stem,
        "file": str(path),
        "objects": scene.n_objects,
        "repeats": repeats,
        "kernel_load_seconds": loads,
        "counts": {k: dflt["rays"][k] for k in COUNT_KEYS},  # the default's
        "spd_counts": spd_counts(dflt["rays"]),  # as the SPD author counts (internal reflections)
        "count_error": error,
        "configs": configs,
        "best": best["label"],
        "best_trace_seconds": best["trace_seconds"],
        "best_trace_cpu_seconds": min(c["trace_cpu_seconds"] for c in configs),
        "best_cpu": min(configs, key=lambda c: c["trace_cpu_seconds"])["label"],
        "default": dflt["label"],
        "default_structure": dflt["used_structure"],
        "default_reason": dflt["structure_reason"],
        "default_trace_seconds": dflt["trace_seconds"],
        "warnings": warnings,
    }


def _label(c: dict) -> str:
    """Short configuration name, e.g. 'grid hash d2', 'grid auto(csr) d1', 'bvh', 'auto(bvh)'
    or 'auto(grid csr d1)': what was asked for, and what auto chose."""
    if c["used_structure"] == "bvh":
        return "bvh" if c["structure"] == "bvh" else "auto(bvh)"
    storage = c["storage"] if c["storage"] != "auto" else f"auto({c['used_storage']})"
    grid = f"grid {storage} d{c['density']:g}"
    return grid if c["structure"] == "grid" else f"auto(grid {c['used_storage']} d{c['density']:g})"
