"""`host camera`: what a photographer asks of a camera file or lens table (focal length,
pupil, field of view, hyperfocal distance), as text or JSON; the figures are
`host.camera.lens.describe`'s.
"""

import json
import math
import sys

from host.camera.lens import CameraError, describe, with_f_number
from host.camera.lensfile import read_camera


def command(args) -> int:
    """Print the camera's figures; 2 if it cannot be read."""
    try:
        cam = read_camera(args.camera, args.film_size)
        if args.f_number is not None:
            cam = with_f_number(cam, args.f_number)
        d = describe(cam, args.focus, args.coc)
    except (CameraError, ValueError, OSError) as e:
        print(f"host: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(_finite(d), indent=2, allow_nan=False))
        return 0
    fov = d["field_of_view_deg"]
    mm = 1000.0
    print(
        f"effective focal length  {d['effective_focal_length_m'] * mm:.2f} mm\n"
        f"principal planes        front z = {d['front_principal_plane_z_m'] * mm:.2f} mm, "
        f"rear z = {d['rear_principal_plane_z_m'] * mm:.2f} mm\n"
        f"front focal distance    {d['front_focal_distance_m'] * mm:.2f} mm\n"
        f"back focal distance     {d['back_focal_distance_m'] * mm:.2f} mm\n"
        f"f-number                f/{d['f_number']:.2f} (entrance pupil "
        f"{d['entrance_pupil_diameter_m'] * mm:.2f} mm)\n"
        f"focus distance          {d['focus_distance_m']:g} m -> film at z = "
        f"{d['film_z_m'] * mm:.3f} mm\n"
        f"field of view           {fov['horizontal']:.1f} x {fov['vertical']:.1f} deg "
        f"({fov['diagonal']:.1f} diagonal)\n"
        f"hyperfocal distance     {d['hyperfocal_distance_m']:.2f} m (circle of confusion "
        f"{d['circle_of_confusion_m'] * mm:.3f} mm)"
    )
    return 0


def _finite(value):
    """JSON has no Infinity: infinite figures (focus at infinity) are written "infinity"."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return "infinity" if value > 0 else "-infinity" if value < 0 else "nan"
    return value
