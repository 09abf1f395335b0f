"""The SPD benchmark's printed report: each scene's configurations, the published counts,
POV-Ray side by side, whole-process times and the summary, apart from the measuring code."""

from bench.spd_povray import GENERATED, goal, goal_line
from bench.spd_published import PUBLISHED_COLUMNS
from bench.spd_runs import COUNT_KEYS, COUNT_LABELS, default_density


def table(headers: list[str], rows: list[list[str]]) -> str:
    """Right-aligned text table."""
    widths = [max(len(str(x)) for x in col) for col in zip(headers, *rows, strict=True)]
    lines = [headers, ["-" * w for w in widths], *rows]
    return "\n".join(
        "  ".join(str(x).rjust(w) for x, w in zip(ln, widths, strict=True)) for ln in lines
    )


def print_scene(r: dict) -> None:
    """Counts line and per-configuration table of one scene; counts go into the table (and a
    mismatch is flagged) when they differ between configurations."""
    c = r["counts"]
    loads = ", ".join(f"{k} {v:.2f} s" for k, v in r["kernel_load_seconds"].items())
    print(
        f"\n== {r['scene']}  ({r['objects']} objects, best of {r['repeats']}; kernel load {loads})"
    )
    pairs = list(zip(COUNT_LABELS, COUNT_KEYS, strict=True))
    if r["count_error"] is None:
        print(
            "rays (identical in every configuration): "
            + "  ".join(f"{lab} {c[k]}" for lab, k in pairs)
        )
    headers = [
        "config",
        "structure",
        "prep s",
        "wall trace s",
        "Mrays/s",
        "tests/ray",
        "steps/ray",
        "struct bytes",
    ]
    rows = [
        [
            x["label"],
            _shape(x),
            f"{x['preprocess_seconds']:.3f}",
            f"{x['trace_seconds']:.3f}",
            f"{x['rays_per_second'] / 1e6:.3f}",
            f"{x['tests_per_ray']:.2f}",
            f"{x['steps_per_ray']:.2f}",
            f"{x['structure_bytes']:,}",
        ]
        for x in r["configs"]
    ]
    if r["count_error"] is not None:
        headers += [lab for lab, _ in pairs]
        rows = [
            row + [x["rays"][k] for _, k in pairs]
            for row, x in zip(rows, r["configs"], strict=True)
        ]
    print(table(headers, rows))
    print(
        "(steps/ray: voxel steps, or node visits in the hierarchy, four boxes each; "
        f"default {r['default']}: {r['default_reason']})"
    )
    if r["count_error"] is not None:
        print("COUNT MISMATCH: the ray counts differ between configurations (engine bug)")
    for w in r["warnings"]:
        print("WARNING:", w)


def _shape(c: dict) -> str:
    """The structure's size: grid resolution, or the hierarchy's inner nodes and leaves."""
    if c["bvh"] is not None:
        return f"{c['bvh']['inner_nodes']:,} nodes {c['bvh']['leaves']:,} leaves"
    return "x".join(map(str, c["resolution"]))


def print_published(results: list[dict]) -> None:
    """Our default's counts against the SPD author's, per scene with a published row."""
    rows = []
    for r in results:
        p = r.get("published")
        if p is None:
            continue
        cells = []
        for k in PUBLISHED_COLUMNS.values():
            cells += (
                [r["spd_counts"][k], p["published"][k], f"{p['relative'][k]:+.3%}"]
                if k in p["published"]
                else ["-"] * 3
            )
        off = [k for k, d in p["relative"].items() if abs(d) > p["tolerance"]]
        rows.append(
            [
                r["scene"],
                *cells,
                f"{p['tolerance']:.1%}",
                "yes" if p["within"] else "NO: " + ", ".join(off),
            ]
        )
    if not rows:
        return
    print(
        "\n== ray counts of the default against the SPD author's published table "
        "(scenes README; 513x513 corner rays, depth 5; refracted counts total internal "
        "reflections, as the author's counter does)"
    )
    headers = [
        "scene",
        "hits",
        "SPD",
        "diff",
        "reflected",
        "SPD",
        "diff",
        "refracted",
        "SPD",
        "diff",
        "shadow",
        "SPD",
        "diff",
        "tolerance",
        "within",
    ]
    print(table(headers, rows))


def print_pov(results: list[dict], pov: dict) -> None:
    """Side-by-side tracing times and shadow/reflection counts against POV-Ray."""
    if not pov.get("available"):
        return
    print("\n== POV-Ray 3.7 side by side (512x512, 1 thread, trace CPU seconds only)")
    headers = [
        "scene",
        "povray CPU s",
        "ours best",
        "config",
        "ours default",
        "config",
        "pov/best",
        "pov/default",
        "shadow ours",
        "pov",
        "blocked ours",
        "pov",
        "refl ours",
        "pov",
    ]
    rows = []
    for r in results:
        p = pov["scenes"].get(r["scene"])
        if p is None:
            continue
        c = r["counts"]
        rows.append(
            [
                r["scene"],
                _spread(p, "cpu_seconds", 3),
                f"{r['best_trace_cpu_seconds']:.3f}",
                r["best_cpu"],
                _spread(p, "ours_default_cpu_seconds", 3),
                r["default"],
                f"{p['ratio_best']:.2f}",
                _spread(p, "ratio_default", 2),
                c["shadow_rays"],
                p["shadow_rays"],
                c["shadow_rays_blocked"],
                p["shadow_rays_blocked"],
                c["reflected_rays"],
                p["reflected_rays"],
            ]
        )
    print(table(headers, rows))
    generated = [k for k, p in pov["scenes"].items() if p.get("pov_source") == GENERATED]
    if generated:
        print(
            f"POV-Ray version {GENERATED} (bench.pov_scene, the SPD's POV-Ray 3 style; "
            f"no pov/NAME.pov shipped) for: {', '.join(generated)}"
        )
    print(
        f"(CPU seconds of the tracing thread, pinned to one core; POV-Ray and ours' default "
        f"taking turns {pov['repeat']} times: median (least-most), pov/default the median of "
        "the turns' paired ratios; ours best: the best configuration's best of the scene's own "
        "pass, not in turns; ratio > 1: we are faster; ours traces 513x513 "
        "corner rays, POV-Ray 512x512 centres with adc_bailout; default = structure auto, "
        f"storage auto, density {default_density():g})"
    )


def _spread(d: dict, key: str, digits: int) -> str:
    """'median (least-most)' of the figure `key` in `d` (`bench.timing.Figure.fields`)."""
    lo, mid, hi = d[f"{key}_low"], d[key], d[f"{key}_high"]
    return f"{mid:.{digits}f} ({lo:.{digits}f}-{hi:.{digits}f})"


def print_wall(wall: dict) -> None:
    """Whole-process wall seconds, warm and cold numba cache."""
    if not wall:
        return
    print(
        "\n== whole process: python -m host.cli render SCENE --spd --mesh 1x1 --threads 1 --quiet"
    )
    rows = [
        [name, f"{w['warm_seconds']:.2f}", f"{w['cold_seconds']:.2f}"] for name, w in wall.items()
    ]
    print(table(["scene", "warm cache s", "cold cache s"], rows))


def print_summary(results: list[dict], pov: dict, wall: dict) -> None:
    """One line per POV-Ray or wall-timed scene: ratios and wall times; then the goal and
    the published counts each in one line."""
    print("\n== summary")
    for r in results:
        p = pov.get("scenes", {}).get(r["scene"]) if pov else None
        w = wall.get(r["scene"])
        if p is None and w is None:
            continue
        parts = [
            f"{r['scene']}: ours {r['best_trace_seconds']:.3f} s wall ({r['best']}), "
            f"default {r['default_trace_seconds']:.3f} s wall ({r['default']})"
        ]
        if p:
            source = (
                " (its POV-Ray version " + GENERATED + ")"
                if p.get("pov_source") == GENERATED
                else ""
            )
            parts.append(
                f"POV-Ray{source} {p['cpu_seconds']:.3f} CPU s -> pov/ours {p['ratio_best']:.2f}"
                f" best, {p['ratio_default']:.2f} default (CPU)"
            )
        if w:
            parts.append(f"process warm {w['warm_seconds']:.2f} s, cold {w['cold_seconds']:.2f} s")
        print("; ".join(parts))
    total = sum(r["best_trace_seconds"] for r in results)
    print(f"all {len(results)} scenes: best tracing times sum to {total:.3f} s wall")
    if pov.get("available"):
        print(goal_line(goal(pov)))
    checked = [r for r in results if r.get("published")]
    if checked:
        off = [r["scene"] for r in checked if not r["published"]["within"]]
        print(
            f"published counts: {len(checked) - len(off)} of {len(checked)} scenes within "
            f"tolerance" + (f"; outside: {', '.join(off)}" if off else "")
        )
