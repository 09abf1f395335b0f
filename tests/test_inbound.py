"""What a neighbour's RAYS may hold: every ray the engine cannot trace is refused, by index,
before it joins a batch; extreme finite numbers and an infinite t_max are traceable."""

import numpy as np
import pytest

from meshnode.service.inbound import check_rays, checked_cell
from protocols.dtypes import RAY, SHADOW
from protocols.errors import BadFrame


def _rays(n=64):
    r = np.zeros(n, RAY)
    r["d"][:, 2], r["t_max"], r["w"], r["depth"] = 1.0, np.inf, 1.0, 1
    return r


@pytest.mark.parametrize(
    "field,column,value",
    [
        ("o", 0, np.nan),
        ("o", 2, np.inf),
        ("d", 1, -np.inf),
        ("w", 2, np.nan),
        ("t_min", None, np.inf),
        ("t_max", None, np.nan),
        ("depth", None, 0),
        ("kind", None, SHADOW + 1),
    ],
)
def test_a_ray_the_engine_cannot_trace_is_refused_by_its_index(field, column, value):
    rays = _rays()
    check_rays({"dest": 1, "cell": 1, "rays": rays}, 4)  # the batch as made is traceable
    at = 37
    if column is None:
        rays[field][at] = value
    else:
        rays[field][at, column] = value
    with pytest.raises(BadFrame, match=f"RAYS: ray {at} of 64 cannot be traced"):
        check_rays({"dest": 1, "cell": 1, "rays": rays}, 4)


def test_extreme_finite_rays_and_an_empty_message_pass():
    rays = _rays(3)
    rays["o"][0], rays["w"][1], rays["t_min"][2] = 1e300, -1e-300, 1e308
    rays["kind"] = SHADOW
    check_rays({"dest": 0, "cell": 0, "rays": rays}, 1)
    check_rays({"dest": 0, "cell": 0, "rays": np.zeros(0, RAY)}, 1)
    with pytest.raises(BadFrame, match="RAYS.dest = 4: no such node"):
        check_rays({"dest": 4, "cell": 0, "rays": rays}, 4)


def test_rays_for_no_cell_or_for_a_cell_the_node_does_not_hold_are_refused_by_name():
    rays = _rays(2)
    with pytest.raises(BadFrame, match=r"RAYS.cell = 4: no such cell"):
        check_rays({"dest": 1, "cell": 4, "rays": rays}, 4)
    with pytest.raises(BadFrame, match=r"RAYS.cell = -1: no such cell"):
        check_rays({"dest": 1, "cell": -1, "rays": rays}, 4)
    assert checked_cell({"cell": 3}, 1, [1, 3]) == 3
    with pytest.raises(BadFrame, match=r"RAYS.cell = 2: node 1 holds no engine of that cell"):
        checked_cell({"cell": 2}, 1, [1, 3])
