"""Scene keys of the spatial fabric's in-plane shear specimens (issue 20, docs/model.md
section 11): the bias extension and the picture frame as external checks write them, their
resolved defaults, the round trip through `scene_to_toml`, and one test per refusal (one
line naming the key; exit status 2 from `dynfab run`).
"""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from dynfab.errors import UserError
from dynfab.scene import (
    PAPER_FRICTION,
    TORSION_RADIUS_PER_WIDTH,
    Friction,
    parse_scene_text,
    scene_to_toml,
    validate_scene,
    with_key,
)
from test_scene import DELETE, edited


FAMILY = {"spacing": 5.18e-3, "amplitude": 0.3e-3, "width": 4.2e-3, "EA": 2.0e4, "EI": 1e-5,
          "EI_lateral": 1e-5, "kawabata_C": 0.2e-3, "kawabata_K": 0.2}
BIAS = {
    "geometry": {"model": "fabric", "kinematics": "spatial"},
    "specimen": {"test": "bias_extension", "width": 0.06, "height": 0.12,
                 "segments_per_spacing": 4},
    "crossing": {"preload": 0.1, "shear_stiffness": 5e-3, "torsion_radius": 2e-5},
    "warp": dict(FAMILY),
    "weft": dict(FAMILY),
    "load": {"control": "displacement", "values": [0.001, 0.002]},
}
"""The bias-extension scene of issue 20, "The specimens", key for key."""
FRAME = {"specimen": {"test": "picture_frame", "side": 0.06, "segments_per_spacing": 4}}
"""Its picture-frame variant (edits of BIAS)."""
PLANAR = {
    "geometry": {"model": "fabric", "length": 0.1, "segments": 32, "crossings": 4,
                 "amplitude": 0.5e-3},
    "warp": {"EA": 13.72, "EI": 1.47e-7, "kawabata_C": 0.2e-3, "kawabata_K": 0.2},
    "weft": {"EI": 1.47e-7, "amplitude": 0.5e-3, "kawabata_C": 0.2e-3, "kawabata_K": 0.2,
             "count": 4, "segments": 32, "EA": 13.72},
    "load": {"control": "displacement", "values": [0.001, 0.002]},
}
"""A planar 4 x 4 fabric, as tests/test_scene.py's."""
YARN = {
    "geometry": {"length": 0.1, "segments": 224, "crossings": 16, "amplitude": 0.5e-3},
    "warp": PLANAR["warp"],
    "weft": {k: v for k, v in PLANAR["weft"].items() if k in ("EI", "amplitude", "kawabata_C",
                                                               "kawabata_K")},
    "load": PLANAR["load"],
}
"""The one-yarn model."""


def text_of(edits: dict | None = None, base: dict = BIAS) -> str:
    """`base` with edits as TOML (`test_scene.edited`)."""
    return edited(edits or {}, base)


def parse(edits: dict | None = None, base: dict = BIAS):
    return parse_scene_text(text_of(edits, base))


def refusal(edits: dict, base: dict = BIAS) -> str:
    """The one-line message of the UserError that parsing `base` with `edits` raises."""
    with pytest.raises(UserError) as info:
        parse(edits, base)
    message = str(info.value)
    assert "\n" not in message
    return message


# --------------------------------------------------------------------------
# The specimens parse, as written.


def test_the_bias_extension_of_the_issue_parses_key_for_key():
    scene = parse()
    g, s, c = scene.geometry, scene.specimen, scene.crossing
    assert (g.model, g.kinematics, g.boundary) == ("fabric", "spatial", "clamped")
    assert (s.test, s.width, s.height, s.side, s.segments_per_spacing) == \
        ("bias_extension", 0.06, 0.12, None, 4)
    assert (c.preload, c.shear_stiffness, c.torsion_radius) == (0.1, 5e-3, 2e-5)
    for family in (scene.warp, scene.weft):
        assert (family.spacing, family.amplitude, family.width) == (5.18e-3, 0.3e-3, 4.2e-3)
        assert (family.EA, family.EI, family.EI_lateral) == (2.0e4, 1e-5, 1e-5)
        assert (family.kawabata_C, family.kawabata_K) == (0.2e-3, 0.2)
    assert scene.load.control == "displacement" and scene.load.values == (0.001, 0.002)
    # the specimen sets the layout: no patch lengths, counts or segments, no yarn planes
    assert (g.length, g.segments, g.crossings, g.amplitude, g.planes) == (None,) * 5
    assert (scene.weft.length, scene.weft.count, scene.weft.segments) == (None,) * 3


def test_the_picture_frame_variant_parses_and_its_fabric_side_is_its_side():
    scene = parse(FRAME)
    s = scene.specimen
    assert (s.test, s.side, s.width, s.height) == ("picture_frame", 0.06, None, None)
    assert s.fabric_side == 0.06  # default: the side (Cao et al. eq. 10 with L_fabric = L)
    assert parse({**FRAME, "specimen.fabric_side": 0.05}).specimen.fabric_side == 0.05


def test_segments_per_spacing_defaults_to_four():
    assert parse({"specimen.segments_per_spacing": DELETE}).specimen.segments_per_spacing == 4


# --------------------------------------------------------------------------
# Resolved defaults: what a result file stores is what runs.


def test_the_torsion_radius_defaults_to_the_mean_distance_in_a_square_of_the_smaller_width():
    """rho = 0.3826 w (issue 20): checked against the mean distance to the centre of a unit
    square by the midpoint rule on a 1000 x 1000 grid, whose error is O(h^2) ~ 1e-6 (the
    integrand's kink at the centre lies on cell corners)."""
    h = 1e-3
    u = (np.arange(1000) + 0.5) * h - 0.5
    mean_distance = np.hypot(u[:, None], u[None, :]).mean()
    assert TORSION_RADIUS_PER_WIDTH == pytest.approx(mean_distance, abs=1e-6)
    assert round(TORSION_RADIUS_PER_WIDTH, 4) == 0.3826
    scene = parse({"crossing.torsion_radius": DELETE, "weft.width": 4.5e-3})
    assert scene.crossing.torsion_radius == pytest.approx(0.3826 * 4.2e-3, rel=1e-4)
    assert scene.crossing.torsion_radius == TORSION_RADIUS_PER_WIDTH * 4.2e-3  # the smaller


def test_lateral_bending_defaults_to_each_familys_bending_stiffness():
    scene = parse({"warp.EI_lateral": DELETE, "weft.EI_lateral": DELETE, "weft.EI": 3e-5})
    assert (scene.warp.EI_lateral, scene.weft.EI_lateral) == (1e-5, 3e-5)


def test_lateral_stiffness_defaults_to_the_core_stiffness():
    """The fabric's default core stiffness is 1e5 N/m (docs/model.md section 10), the
    constant the fabric builder uses; contact.core_stiffness where the scene gives one."""
    from dynfab.scene import DEFAULT_CORE_STIFFNESS

    scene = parse()
    assert scene.warp.lateral_stiffness == scene.weft.lateral_stiffness == 1e5
    assert DEFAULT_CORE_STIFFNESS == 1e5
    scene = parse({"contact": {"core_stiffness": 3e4}, "weft.lateral_stiffness": 7e3})
    assert (scene.warp.lateral_stiffness, scene.weft.lateral_stiffness) == (3e4, 7e3)


def test_a_specimen_without_friction_takes_the_papers_gralen_law():
    """docs/model.md section 7: alpha 0.2, beta 1e3 N/m^2, ell 2e-3 m, r_f 1e-3 m (Fig. 5's
    friction-on curve). A specimen without friction slides apart, so the table's absence is
    not frictionless; alpha = beta = 0 written out switches friction off."""
    scene = parse()
    f = scene.friction
    assert (f.alpha, f.beta, f.contact_length, f.fiber_radius) == (0.2, 1e3, 2e-3, 1e-3)
    assert f == PAPER_FRICTION and f.stick_stiffness is None and f.onset_force == 1e-5
    off = {"alpha": 0.0, "beta": 0.0, "contact_length": 2e-3, "fiber_radius": 1e-3}
    assert parse({"friction": off}).friction == Friction(**off)
    # a planar fabric keeps "no [friction] table, no friction"
    assert parse(base=PLANAR).friction is None


def test_given_values_are_kept_and_defaults_do_not_follow_with_key():
    """Resolved at validation, as geometry.planes: a later with_key leaves them (documented
    on with_key, as weft.length after geometry.length)."""
    scene = parse({"warp.EI_lateral": DELETE})
    changed = with_key(scene, "warp.EI", 2e-5)
    assert changed.warp.EI == 2e-5 and changed.warp.EI_lateral == 1e-5


# --------------------------------------------------------------------------
# The round trip.


@pytest.mark.parametrize("edits", [{}, FRAME, {"crossing.torsion_radius": DELETE,
                                               "warp.EI_lateral": DELETE,
                                               "contact": {"core_stiffness": 3e4},
                                               "friction": {"alpha": 0.0, "beta": 0.0,
                                                            "contact_length": 0.0,
                                                            "fiber_radius": 0.0}}],
                         ids=["bias", "frame", "defaults"])
def test_scene_to_toml_round_trips_a_specimen(edits):
    scene = parse(edits)
    text = scene_to_toml(scene)
    assert parse_scene_text(text) == replace(scene, text=text)
    for absent in ("\nlength =", "\nsegments =", "\ncrossings =", "\nplanes =", "\ncount ="):
        assert absent not in text


def test_a_planar_fabric_writes_no_spatial_key():
    text = scene_to_toml(parse(base=PLANAR))
    assert 'kinematics = "planar"' in text
    for absent in ("spacing", "width", "lateral", "[crossing]", "[specimen]", "[friction]"):
        assert absent not in text
    assert "kinematics" not in scene_to_toml(parse(base=YARN))  # a one-yarn scene as before


# --------------------------------------------------------------------------
# Refusals: one line naming the key (issue 20, "Bad input").

PLANAR_FABRIC = 'but geometry.kinematics = "planar"'
REFUSALS = {
    # kinematics and the models
    "spatial on the one-yarn model": (
        {"geometry.kinematics": "spatial"}, YARN,
        'geometry.kinematics = "spatial": a key of the woven fabric (docs/model.md section 10), '
        'but geometry.model = "yarn"'),
    "spatial without a specimen": (
        {"specimen": DELETE}, BIAS,
        'geometry.kinematics = "spatial": spatial kinematics runs a [specimen] test '
        "(bias_extension or picture_frame"),
    "a specimen with planar kinematics": (
        {"geometry.kinematics": "planar"}, BIAS,
        '[specimen] given but geometry.kinematics = "planar": a specimen is sheared in plane '
        '(docs/model.md section 11); set geometry.kinematics = "spatial"'),
    "a specimen with kinematics left out": (
        {"geometry.kinematics": DELETE}, BIAS, "set geometry.kinematics = \"spatial\""),
    "a specimen on the one-yarn model": (
        {"specimen": BIAS["specimen"]}, YARN, 'specimen.test = "bias_extension": a key of the '
        'woven fabric'),
    "an empty crossing table on the one-yarn model": (
        {"crossing": {}}, YARN, '[crossing] given but geometry.model = "yarn"'),
    "a periodic specimen": (
        {"geometry.boundary": "periodic"}, BIAS,
        'geometry.boundary = "periodic": a [specimen] is a finite piece of fabric'),
    "planes on a specimen": (
        {"geometry.planes": "fixed"}, BIAS, 'geometry.planes = "fixed": the yarns\' planes are '
        "the planar fabric's"),
    "a pull-out of a specimen": (
        {"pullout": {"warp": 1}}, BIAS, "[pullout] given with [specimen]"),
    # the specimen's size
    "bias without width": (
        {"specimen.width": DELETE}, BIAS,
        'missing required key specimen.width [m] (needed with specimen.test = "bias_extension")'),
    "bias without height": (
        {"specimen.height": DELETE}, BIAS, "missing required key specimen.height [m]"),
    "bias with side": (
        {"specimen.side": 0.06}, BIAS,
        'specimen.side = 0.06: not a key of specimen.test = "bias_extension"; remove it'),
    "bias with fabric_side": (
        {"specimen.fabric_side": 0.06}, BIAS, "specimen.fabric_side = 0.06: not a key of"),
    "frame without side": (
        {**FRAME, "specimen.side": DELETE}, BIAS,
        'missing required key specimen.side [m] (needed with specimen.test = "picture_frame")'),
    "frame with width": (
        {**FRAME, "specimen.width": 0.06}, BIAS,
        'specimen.width = 0.06: not a key of specimen.test = "picture_frame"; remove it'),
    "frame with height": (
        {**FRAME, "specimen.height": 0.12}, BIAS, "specimen.height = 0.12: not a key of"),
    "frame fabric larger than the frame": (
        {**FRAME, "specimen.fabric_side": 0.07}, BIAS,
        "specimen.fabric_side = 0.07: must be at most specimen.side = 0.06 m"),
    "H below 2W": (
        {"specimen.height": 0.1}, BIAS,
        "specimen.height = 0.1: must be at least 2 x specimen.width = 0.12 m: H/W = 1.67 < 2"),
    "no test": ({"specimen.test": DELETE}, BIAS, "missing required key specimen.test"),
    "an unknown test": (
        {"specimen.test": "bias_extention"}, BIAS,
        'specimen.test = "bias_extention": must be one of '
        '"bias_extension", "picture_frame"; did you mean "bias_extension"?'),
    "zero segments per spacing": (
        {"specimen.segments_per_spacing": 0}, BIAS,
        "specimen.segments_per_spacing = 0: must be a positive integer"),
    # the families
    "warp width not below its spacing": (
        {"warp.width": 5.18e-3}, BIAS,
        "warp.width = 0.00518: must be below warp.spacing = 0.00518 m"),
    "weft width above its spacing": (
        {"weft.width": 6e-3}, BIAS, "weft.width = 0.006: must be below weft.spacing"),
    "no warp spacing": (
        {"warp.spacing": DELETE}, BIAS,
        "missing required key warp.spacing [m] (needed with [specimen])"),
    "no weft spacing": ({"weft.spacing": DELETE}, BIAS, "missing required key weft.spacing [m]"),
    "no warp width": ({"warp.width": DELETE}, BIAS, "missing required key warp.width [m]"),
    "no weft width": ({"weft.width": DELETE}, BIAS, "missing required key weft.width [m]"),
    "no warp amplitude": (
        {"warp.amplitude": DELETE}, BIAS, "missing required key warp.amplitude [m]"),
    "no weft amplitude": (
        {"weft.amplitude": DELETE}, BIAS, "missing required key weft.amplitude [m]"),
    "no weft EA": ({"weft.EA": DELETE}, BIAS, "missing required key weft.EA [N]"),
    "no weft table": ({"weft": DELETE}, BIAS, "missing required table [weft]"),
    "EI_lateral not positive": (
        {"warp.EI_lateral": -1e-5}, BIAS,
        "warp.EI_lateral = -1e-05: must be a positive number [N m^2]"),
    "lateral_stiffness zero": (
        {"weft.lateral_stiffness": 0.0}, BIAS,
        "weft.lateral_stiffness = 0.0: must be a positive number [N/m]"),
    # the crossings
    "a negative preload": (
        {"crossing.preload": -0.1}, BIAS,
        "crossing.preload = -0.1: must be a non-negative number [N]"),
    "a zero preload": (
        {"crossing.preload": 0.0}, BIAS,
        "crossing.preload = 0.0: a specimen needs crossing.preload > 0: without it every "
        "friction limit is zero"),
    "no crossing table": (
        {"crossing": DELETE}, BIAS,
        "a specimen needs crossing.preload > 0: without it every friction limit is zero"),
    "torsion radius zero": (
        {"crossing.torsion_radius": 0.0}, BIAS,
        "crossing.torsion_radius = 0.0: must be a positive number [m]"),
    "torsion radius negative": (
        {"crossing.torsion_radius": -2e-5}, BIAS, "crossing.torsion_radius = -2e-05: must be a "
        "positive number [m]"),
    "negative shear stiffness": (
        {"crossing.shear_stiffness": -1.0}, BIAS,
        "crossing.shear_stiffness = -1.0: must be a non-negative number [N m/rad]"),
    # the load
    "force control": (
        {"load.control": "force"}, BIAS,
        'load.control = "force": a specimen is loaded by its clamp displacement: '
        'load.control = "displacement"'),
    "weft values": (
        {"load.weft_values": [0.0, 0.0]}, BIAS, "load.weft_values = [0.0, 0.0]: a specimen is "
        "loaded by its clamp (frame corner) displacement alone"),
    "warp factors": ({"load.warp_factors": [1.0]}, BIAS, "load.warp_factors = [1.0]: a specimen"),
    "weft factors": ({"load.weft_factors": [1.0]}, BIAS, "load.weft_factors = [1.0]: a specimen"),
    "a sweep": (
        {"sweep": {"warp.EA": [1e4, 2e4]}}, BIAS,
        '[sweep] given but geometry.model = "fabric": a patch is one coupled group'),
    # the layout the specimen sets
    **{f"{key} on a specimen": ({key: value}, BIAS,
                                f"[specimen] sets the layout: {key} is not used; remove it")
       for key, value in (("geometry.length", 0.1), ("geometry.segments", 32),
                          ("geometry.crossings", 4), ("geometry.amplitude", 0.3e-3),
                          ("weft.length", 0.1), ("weft.count", 4), ("weft.segments", 32))},
    # the spatial keys on a planar fabric (of [crossing], all but the woven-in preload)
    **{f"{key} on a planar fabric": ({key: value}, PLANAR,
                                     f"{key} = {value!r}: a key of the spatial fabric "
                                     f'(geometry.kinematics = "spatial", docs/model.md '
                                     f"section 11), {PLANAR_FABRIC}")
       for key, value in (("warp.spacing", 5e-3), ("warp.width", 4e-3),
                          ("warp.EI_lateral", 1e-5), ("warp.lateral_stiffness", 1e5),
                          ("warp.amplitude", 3e-4), ("weft.spacing", 5e-3),
                          ("weft.width", 4e-3), ("weft.EI_lateral", 1e-5),
                          ("weft.lateral_stiffness", 1e5), ("crossing.shear_stiffness", 5e-3),
                          ("crossing.torsion_radius", 2e-5))},
}


@pytest.mark.parametrize("edits, base, message", REFUSALS.values(), ids=REFUSALS.keys())
def test_bad_specimen_input_is_refused_in_one_line_naming_the_key(edits, base, message):
    assert message in refusal(edits, base)


def test_a_planar_fabrics_warp_crimp_is_named_where_warp_amplitude_is_refused():
    assert refusal({"warp.amplitude": 3e-4}, PLANAR).endswith(
        "a planar fabric's warp crimp is geometry.amplitude")


def test_a_specimen_layout_key_set_in_python_is_refused_as_in_a_file():
    """Scenes built in Python (with_key, scene_from_tables) pass the same checks."""
    scene = parse()
    with pytest.raises(UserError, match=r"\[specimen\] sets the layout: geometry.length"):
        with_key(scene, "geometry.length", 0.1)
    with pytest.raises(UserError, match="crossing.preload = 0.0: a specimen needs"):
        with_key(scene, "crossing.preload", 0.0)
    with pytest.raises(UserError, match=r"specimen.height = 0.1: must be at least 2 x"):
        with_key(scene, "specimen.height", 0.1)
    with pytest.raises(UserError, match=r'\[specimen\] given but geometry.kinematics = "planar"'):
        validate_scene(replace(scene, geometry=replace(scene.geometry, kinematics="planar")))
    with pytest.raises(UserError, match=r"missing required key geometry.length \[m\]"):
        validate_scene(replace(scene, specimen=None,
                               geometry=replace(scene.geometry, kinematics="planar")))


def test_the_planar_layout_keys_stay_required_without_a_specimen():
    assert refusal({"geometry.length": DELETE}, PLANAR) == \
        "missing required key geometry.length [m]"
    assert refusal({"geometry.amplitude": DELETE}, YARN) == \
        "missing required key geometry.amplitude [m]"


def dynfab_run(tmp_path, text: str):
    """`dynfab run` (the console script's code) on a scene file holding `text`."""
    scene = tmp_path / "scene.toml"
    scene.write_text(text)
    out = tmp_path / "x.h5"
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "run", str(scene), "--out",
                           str(out)], capture_output=True, text=True)
    assert not out.exists()
    return done


@pytest.mark.parametrize("edits, base, needle", [
    ({"specimen.height": 0.1}, BIAS, "H/W = 1.67 < 2"),
    ({"geometry.kinematics": "spatial"}, YARN, "geometry.kinematics"),
    ({"crossing.preload": 0.0}, BIAS, "crossing.preload"),
], ids=["H below 2W", "spatial yarn", "no preload"])
def test_dynfab_run_refuses_a_bad_specimen_with_exit_status_2_and_one_line(tmp_path, edits, base,
                                                                         needle):
    done = dynfab_run(tmp_path, text_of(edits, base))
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and needle in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
