"""The records that describe a render: every one survives its wire form (through real msgpack
frames), every bad value is refused naming the record, the field and the value, and each
setting has one definition the command line shows."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from host.camera.setup import Focus
from host.cli import _parser
from protocols import dtypes
from protocols.camera import CameraSampling, CameraSpec
from protocols.framing import FrameDecoder, encode
from protocols.partition import Partition
from protocols.render import EngineSpec, ImageSpec, MeshPlan, RenderSpec
from protocols.spec import SpecError, default


def lens() -> np.ndarray:
    e = np.zeros(2, dtypes.ELEMENT)
    e["kind"] = dtypes.THIN_LENS, dtypes.DIAPHRAGM
    e["z"], e["focal"], e["ax"], e["ay"] = (0.0, 0.001), (0.05, 0.0), (0.01, 0.005), (0.01, 0.005)
    return e


def over_the_wire(record):
    """The record as a peer reads it: wire form, msgpack frame, decoded, from_wire."""
    (message,) = FrameDecoder().feed(encode({"k": 2, "r": record.to_wire()}))
    return type(record).from_wire(message["r"])


images = st.builds(
    ImageSpec,
    width=st.integers(1, 4096),
    height=st.integers(1, 4096),
    spp=st.integers(1, 64),
    depth=st.integers(1, 64),
    seed=st.integers(0, 2**63 - 1),
)
engines = st.builds(
    EngineSpec,
    storage=st.sampled_from(["auto", "csr", "hash"]),
    density=st.floats(0.01, 100),
    threads=st.integers(0, 64),
)
plans = st.builds(
    MeshPlan,
    rows=st.integers(1, 8),
    cols=st.integers(1, 8),
    overlap=st.floats(0, 100),
    balance=st.sampled_from(["even", "cost"]),
)
samplings = st.builds(
    CameraSampling,
    generation=st.integers(0, 7),
    sampling=st.sampled_from(["uniform", "jittered", "random", "adaptive"]),
    threshold=st.floats(0, 1),
    film_area=st.sampled_from(["ellipse", "rectangle"]),
    special=st.booleans(),
)


@settings(max_examples=60, deadline=None)
@given(images, engines, plans, samplings, st.booleans())
def test_every_record_round_trips_through_its_wire_form(image, engine, plan, sampling, cam):
    camera = CameraSpec(lens(), 0.036, 0.024, -0.0513, sampling) if cam else None
    spec = RenderSpec(image, engine, plan, camera)
    for record in (image, engine, plan, sampling, spec, *([camera] if cam else [])):
        assert over_the_wire(record) == record


def test_partition_round_trips_and_checks_its_shapes():
    part = Partition.make(
        [(0, 20, 0, 30), (20, 40, 0, 30)],
        np.zeros((2, 3)),
        np.ones((2, 3)),
        (np.full(3, -1.0), np.full(3, 2.0)),
    )
    assert over_the_wire(part) == part
    assert part.boxes[0].shape == (2, 3) and part.nodes == 2
    with pytest.raises(SpecError, match=r"Partition\.his"):
        Partition.make([(0, 1, 0, 1)], np.ones((1, 3)), np.zeros((1, 3)), (np.zeros(3),) * 2)
    with pytest.raises(SpecError, match=r"Partition\.los"):
        Partition(
            ((0, 1, 0, 1),),
            (0,),
            ((0, 0),),
            ((1, 1, 1),),
            (0, 0, 0),
            (1, 1, 1),
            ((0, 0, 0),),
            ((1, 1, 1),),
        )
    with pytest.raises(SpecError, match=r"Partition\.rects"):
        Partition(
            ((5, 1, 0, 1),),
            (0,),
            ((0, 0, 0),),
            ((1, 1, 1),),
            (0, 0, 0),
            (1, 1, 1),
            ((0, 0, 0),),
            ((1, 1, 1),),
        )
    with pytest.raises(SpecError, match=r"Partition\.owner"):
        Partition(
            ((0, 1, 0, 1),),
            (3,),
            ((0, 0, 0),),
            ((1, 1, 1),),
            (0, 0, 0),
            (1, 1, 1),
            ((0, 0, 0),),
            ((1, 1, 1),),
        )
    with pytest.raises(SpecError, match=r"Partition\.cell_his"):  # a cell outside its box
        Partition.make(
            [(0, 1, 0, 1)],
            np.zeros((1, 3)),
            np.ones((1, 3)),
            (np.zeros(3),) * 2,
            cells=(np.zeros((1, 3)), np.full((1, 3), 2.0)),
        )
    grown = Partition.make(
        [(0, 1, 0, 1)],
        np.zeros((1, 3)),
        np.ones((1, 3)),
        (np.zeros(3),) * 2,
        cells=(np.full((1, 3), 0.25), np.full((1, 3), 0.75)),
    )
    assert over_the_wire(grown) == grown and grown.cells[0].tolist() == [[0.25] * 3]
    tiled = Partition.make(
        [(0, 2, 0, 2), (2, 4, 0, 2), (0, 4, 2, 4)],
        np.zeros((2, 3)),
        np.ones((2, 3)),
        (np.zeros(3), np.ones(3)),
        owner=[0, 1, 0],
    )
    assert over_the_wire(tiled) == tiled and tiled.nodes == 2
    assert tiled.rects_of(0) == [(0, 2, 0, 2), (0, 4, 2, 4)]


@pytest.mark.parametrize(
    "record,field,value",
    [
        (ImageSpec, "depth", 0),
        (ImageSpec, "depth", 1000),
        (ImageSpec, "spp", 0),
        (ImageSpec, "width", -3),
        (ImageSpec, "width", 10**9),
        (ImageSpec, "seed", -1),
        (ImageSpec, "spp", "4"),
        (ImageSpec, "spd", 1),
        (ImageSpec, "depth", True),
        (EngineSpec, "density", 0.0),
        (EngineSpec, "density", float("nan")),
        (EngineSpec, "storage", "btree"),
        (EngineSpec, "threads", -1),
        (MeshPlan, "rows", 0),
        (MeshPlan, "cols", 100_000),
        (MeshPlan, "overlap", -1.0),
        (MeshPlan, "overlap", float("inf")),
        (MeshPlan, "balance", "magic"),
        (CameraSampling, "generation", 8),
        (CameraSampling, "sampling", "lucky"),
        (CameraSampling, "threshold", -0.1),
        (CameraSampling, "film_area_size", 0.0),
        (CameraSampling, "adaptation", "some"),
        (Focus, "distance", -2.0),
        (Focus, "distance", "soon"),
        (Focus, "coc", 0.0),
    ],
)
def test_bad_values_are_refused_naming_the_field(record, field, value):
    with pytest.raises(
        SpecError,
        match=rf"{record.__name__}\.{field} = {value!r}".replace("(", r"\(").replace(")", r"\)"),
    ) as e:
        record(**{field: value})
    assert str(e.value).split(": ", 1)[1]  # says what is allowed, never empty


def test_rules_across_fields_are_refused_by_name():
    with pytest.raises(SpecError, match=r"ImageSpec\.depth = 3: the SPD rules"):
        ImageSpec(spd=True, depth=3)
    with pytest.raises(SpecError, match=r"MeshPlan\.cols"):
        MeshPlan(100, 100)  # 10,000 nodes
    with pytest.raises(SpecError, match=r"CameraSampling\.special"):
        CameraSampling(special=True, film_area="centre")
    with pytest.raises(SpecError, match=r"RenderSpec\.image"):
        RenderSpec(ImageSpec())  # not sized
    corners = ImageSpec(spd=True, spp=4).sized(None)  # the SPD rules' corner rays: one each
    with pytest.raises(SpecError, match=r"ImageSpec\.spp = 4: the SPD rules fix it at 1"):
        RenderSpec(corners)
    RenderSpec(corners, camera=CameraSpec(lens(), 1, 1, -0.05))  # a camera's rays per pixel
    with pytest.raises(SpecError, match=r"CameraSpec\.elements"):
        CameraSpec(np.zeros(0, dtypes.ELEMENT), 0.036, 0.024, -0.05)


def test_rays_per_pixel_are_the_images_through_every_camera():
    """One field: ImageSpec.spp, which the camera's generation type traces all of, a fixed
    pattern's points of, or one of; adaptive sampling needs three or more. A peer's camera
    still carrying its own rays (protocol 11) is refused by name."""
    adaptive = CameraSpec(lens(), 0.036, 0.024, -0.05, CameraSampling(sampling="adaptive"))
    for spp, books in ((2, False), (9, True)):
        spec = RenderSpec(ImageSpec(width=4, height=4, spp=spp), camera=adaptive)
        assert (spec.rays_per_pixel, spec.adaptive, spec.ids_per_cell) == (spp, books, 1)
    traced = [CameraSampling(generation=g).per_pixel(9) for g in (0, 1, 2, 3, 4, 6)]
    assert traced == [1, 1, 9, 9, 5, 9]
    assert CameraSampling(generation=1, film_area="rectangle").per_pixel(9) == 9
    wire = CameraSampling().to_wire()
    with pytest.raises(SpecError, match=r"unknown fields \['rays'\]"):
        CameraSampling.from_wire({**wire, "rays": 16})


def test_a_peers_record_with_missing_or_unknown_fields_is_refused_by_name():
    wire = EngineSpec().to_wire()
    with pytest.raises(SpecError, match=r"missing fields \['density'\]"):
        EngineSpec.from_wire({k: v for k, v in wire.items() if k != "density"})
    with pytest.raises(SpecError, match=r"unknown fields \['box'\]"):
        EngineSpec.from_wire({**wire, "box": [0, 1]})
    with pytest.raises(SpecError, match="must be a map"):
        RenderSpec.from_wire([1, 2])
    wire = RenderSpec(ImageSpec(width=8, height=8)).to_wire()
    wire["image"]["depth"] = -5
    with pytest.raises(SpecError, match=r"ImageSpec\.depth = -5"):
        RenderSpec.from_wire(wire)


def test_sample_grid_is_corners_under_the_spd_rules_only():
    spd = ImageSpec(spd=True).sized(None)
    assert spd.size == (512, 512) and spd.sample_grid() == (513, 513)
    assert spd.sample_grid(camera=True) == (512, 512)  # a camera makes pixel rays
    assert ImageSpec(width=40, height=30, spp=4).sample_grid() == (40, 30)


@pytest.mark.parametrize(
    "flag,record,name",
    [
        ("--depth", ImageSpec, "depth"),
        ("--generation", CameraSampling, "generation"),
        ("--overlap", MeshPlan, "overlap"),
        ("--density", EngineSpec, "density"),
    ],
)
def test_the_command_line_shows_and_uses_the_records_defaults(flag, record, name):
    render = _parser()._subparsers._group_actions[0].choices["render"]
    (action,) = [a for a in render._actions if flag in a.option_strings]
    assert action.dest == f"{record.__name__}.{name}"
    assert f"(default {default(record, name)})" in action.help
    args = render.parse_args(["scene.nff"])
    assert not hasattr(args, action.dest)  # unset: the record's own default applies
