"""The SPD author's published ray counts (the scenes folder's README) and how far our default's
counts are from them: an exactness check independent of our own engine's configurations."""

from pathlib import Path

# The SPD author's published counts (scenes README) are checked to this relative difference;
# teapot's generator has changed since the table was made.
PUBLISHED_TOLERANCE = {"teapot": 0.005}
TOLERANCE = 0.001
PUBLISHED_COLUMNS = {
    "eye rays that hit": "eye_hits",
    "reflected rays": "reflected_rays",
    "refracted rays": "refracted_rays",
    "shadow rays": "shadow_rays",
}


def parse_published(text: str) -> dict[str, dict[str, int]]:
    """The 'Published ray counts' table of the scenes folder's README (the SPD author's counts,
    513x513 corner rays, depth 5): {scene: {count key: n}}; {} if the README has none."""
    _, found, rest = text.partition("Published ray counts")
    lines = [ln.strip() for ln in rest.split("\n## ")[0].splitlines()]
    rows = [[x.strip() for x in ln.strip("|").split("|")] for ln in lines if ln.startswith("|")]
    rows = [r for r in rows if not all(set(x) <= set("-: ") for x in r)]  # the rule under header
    if not found or not rows:
        return {}
    keys = [PUBLISHED_COLUMNS.get(h.lower()) for h in rows[0][1:]]
    return {
        r[0]: {k: int(v.replace(",", "")) for k, v in zip(keys, r[1:], strict=True) if k}
        for r in rows[1:]
    }


def read_published(scenes: Path) -> dict[str, dict[str, int]]:
    """The published counts of the scenes folder's README.md ({} without one)."""
    readme = scenes / "README.md"
    return parse_published(readme.read_text()) if readme.exists() else {}


def compare_published(name: str, counts: dict, published: dict | None) -> dict | None:
    """Relative difference of each of our counts from the published one (over max(published, 1):
    a published 0 stays finite) and whether all are within the scene's tolerance."""
    if not published:
        return None
    tolerance = PUBLISHED_TOLERANCE.get(name, TOLERANCE)
    relative = {k: (counts[k] - n) / max(n, 1) for k, n in published.items()}
    return {
        "published": published,
        "relative": relative,
        "tolerance": tolerance,
        "within": all(abs(d) <= tolerance for d in relative.values()),
    }
