"""Scene files: parsing, defaults, load paths, sweeps, and one test per user mistake.

Fast: imports only dynfab.scene and dynfab.errors (no numba, no Warp).
"""

import copy
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from dynfab.errors import UserError
from dynfab import scene as scene_module
from dynfab.scene import (
    Dynamic,
    Static,
    check_dynamic_options,
    expand_sweep,
    load_scene,
    markdown_table,
    parse_scene_text,
    scene_to_toml,
    validate_scene,
    with_key,
    yarn_count,
)
from toml_writer import toml_text

RUNS = Path(__file__).resolve().parent.parent / "runs"

DELETE = object()
"""Marker in an edit: remove the key (or table)."""

BASE = {
    "title": "a test yarn",
    "geometry": {"length": 0.1, "segments": 224, "crossings": 16, "amplitude": 0.5e-3},
    "warp": {"EA": 13.72, "EI": 1.47e-7, "kawabata_C": 0.2e-3, "kawabata_K": 0.2},
    "weft": {"EI": 1.47e-7, "amplitude": 0.5e-3, "kawabata_C": 0.2e-3, "kawabata_K": 0.2},
    "load": {"control": "displacement", "values": [0.001, 0.002]},
}
FRICTION = {"alpha": 0.2, "beta": 1e3, "contact_length": 2e-3, "fiber_radius": 1e-3}


def edited(edits: dict, base: dict = BASE) -> str:
    """`base` (BASE) with edits {"table.key": value or DELETE, "table": {...} or DELETE} as
    TOML."""
    scene = copy.deepcopy(base)
    for path, value in edits.items():
        table, _, key = path.partition(".")
        target, name = (scene.setdefault(table, {}), key) if key else (scene, table)
        if value is DELETE:
            del target[name]
        else:
            target[name] = copy.deepcopy(value)
    return toml_text(scene)


def parse(edits: dict | None = None):
    """Parse BASE with edits."""
    return parse_scene_text(edited(edits or {}))


# --------------------------------------------------------------------------
# Valid scenes.


def test_base_scene_round_trips_with_every_default():
    text = edited({})
    scene = parse_scene_text(text)
    assert scene.text == text
    assert scene.title == "a test yarn"
    g = scene.geometry
    assert (g.length, g.segments, g.crossings, g.amplitude) == (0.1, 224, 16, 0.5e-3)
    assert g.reference == "as_woven" and g.yarns == 1
    assert (scene.warp.EA, scene.warp.EI) == (13.72, 1.47e-7)
    assert (scene.warp.kawabata_C, scene.warp.kawabata_K) == (0.2e-3, 0.2)
    assert scene.warp.linear_density == 3e-5
    w = scene.weft
    assert (w.EI, w.amplitude, w.kawabata_C, w.kawabata_K) == (1.47e-7, 0.5e-3, 0.2e-3, 0.2)
    assert w.length == g.length and w.count == g.crossings and w.tension == 0.0
    assert scene.friction is None and scene.gravity is None
    assert scene.load.control == "displacement" and scene.load.values == (0.001, 0.002)
    assert scene.sweep == () and scene.static == Static() and scene.dynamic == Dynamic()
    assert scene.static.tolerance == 1e-11 and scene.static.max_iterations == 200
    assert yarn_count(scene) == 1 and expand_sweep(scene) == [scene]


def test_title_defaults_to_empty_and_load_control_to_force():
    scene = parse({"title": DELETE, "load.control": DELETE})
    assert scene.title == "" and scene.load.control == "force"


def test_optional_tables_and_explicit_values():
    scene = parse({"friction": dict(FRICTION, stick_stiffness=5e3), "gravity": {},
                   "geometry.reference": "prestressed", "geometry.yarns": 2,
                   "weft.length": 0.2, "weft.count": 8, "weft.tension": 0.01,
                   "static": {"tolerance": 1e-9, "max_iterations": 50}})
    assert scene.friction.alpha == 0.2 and scene.friction.stick_stiffness == 5e3
    assert scene.gravity.g == 9.81
    assert scene.geometry.reference == "prestressed" and yarn_count(scene) == 2
    assert (scene.weft.length, scene.weft.count, scene.weft.tension) == (0.2, 8, 0.01)
    assert scene.static == Static(tolerance=1e-9, max_iterations=50)


def test_friction_stick_stiffness_defaults_to_none():
    assert parse({"friction": FRICTION}).friction.stick_stiffness is None


def test_friction_onset_force_defaults_to_1e_5_and_zero_is_the_literal_law():
    # docs/model.md section 4: R_0 = friction.onset_force [N], default 1e-5 N, >= 0.
    assert parse({"friction": FRICTION}).friction.onset_force == 1e-5
    assert parse({"friction": dict(FRICTION, onset_force=0.0)}).friction.onset_force == 0.0


def test_onset_force_is_sweepable_and_round_trips():
    scene = parse({"friction": FRICTION, "sweep": {"friction.onset_force": [1e-5, 0.0]}})
    assert [s.friction.onset_force for s in expand_sweep(scene)] == [1e-5, 0.0]
    assert parse_scene_text(scene_to_toml(scene)) == replace(scene, text=scene_to_toml(scene))


def test_contact_core_stiffness_is_absent_by_default_and_sweepable():
    # docs/model.md section 3: contact.core_stiffness [N/m], default none in the one-yarn model.
    assert parse().contact is None
    scene = parse({"contact": {"core_stiffness": 1e5}})
    assert scene.contact.core_stiffness == 1e5
    swept = parse({"contact": {}, "sweep": {"contact.core_stiffness": [1e4, 1e5]}})
    assert [s.contact.core_stiffness for s in expand_sweep(swept)] == [1e4, 1e5]
    assert parse_scene_text(scene_to_toml(scene)).contact == scene.contact


def test_ints_are_accepted_for_real_keys():
    scene = parse({"warp.EA": 14, "geometry.amplitude": 0})
    assert scene.warp.EA == 14.0 and isinstance(scene.warp.EA, float)
    assert scene.geometry.amplitude == 0.0


def test_plain_rod_without_weft():
    scene = parse({"geometry.crossings": 0, "geometry.segments": 3,
                   "geometry.amplitude": 0.0, "weft": DELETE})
    assert scene.weft is None and scene.geometry.segments == 3


def test_load_max_and_steps_expand_to_max_k_over_steps():
    scene = parse({"load.values": DELETE, "load.max": 0.01, "load.steps": 4})
    assert scene.load.values == tuple(0.01 * k / 4 for k in range(1, 5))
    assert scene.load.values[-1] == 0.01


def test_negative_displacement_and_force_values_are_allowed():
    assert parse({"load.values": [-0.001, 0.0, 2.5]}).load.values == (-0.001, 0.0, 2.5)
    compression = parse({"load.values": DELETE, "load.max": -0.002, "load.steps": 2})
    assert compression.load.values == (-0.001, -0.002)


def test_transient_dynamic_table():
    scene = parse({"dynamic": {"mode": "transient", "duration": 0.02,
                               "output_interval": 2e-4, "damping_coefficient": 3.0,
                               "masses": "physical", "safety": 1.5}})
    assert scene.dynamic.mode == "transient" and scene.dynamic.duration == 0.02
    assert scene.dynamic.safety == 1.5 and scene.dynamic.damping_coefficient == 3.0


def test_sweep_expands_to_one_scene_per_entry():
    scene = parse({"friction": FRICTION,
                   "sweep": {"warp.kawabata_K": [0.02, 0.2, 1.0],
                             "friction.alpha": [0.0, 0.1, 0.3],
                             "geometry.amplitude": [1e-4, 2e-4, 3e-4]}})
    assert yarn_count(scene) == 3
    scenes = expand_sweep(scene)
    assert len(scenes) == 3
    for i, one in enumerate(scenes):
        assert one.sweep == () and yarn_count(one) == 1
        assert one.warp.kawabata_K == [0.02, 0.2, 1.0][i]
        assert one.friction.alpha == [0.0, 0.1, 0.3][i]
        assert one.geometry.amplitude == [1e-4, 2e-4, 3e-4][i]
        assert one.weft == scene.weft and one.load == scene.load
        assert one.warp.EA == scene.warp.EA and one.friction.beta == scene.friction.beta
        assert one.text == scene.text


def test_sweep_key_may_be_left_out_of_its_table_or_written_unquoted():
    text = edited({"warp.kawabata_K": DELETE})
    text += "[sweep]\nwarp.kawabata_K = [0.02, 1.0]\n"
    scene = parse_scene_text(text)
    assert scene.sweep == (("warp.kawabata_K", (0.02, 1.0)),)
    assert scene.warp.kawabata_K == 0.02
    assert [s.warp.kawabata_K for s in expand_sweep(scene)] == [0.02, 1.0]


def test_with_key_sets_one_key_and_revalidates():
    scene = parse()
    changed = with_key(scene, "warp.kawabata_K", 0.02)
    assert changed.warp.kawabata_K == 0.02 and changed.warp.EA == scene.warp.EA
    assert with_key(scene, "geometry.amplitude", 0).geometry.amplitude == 0.0
    with pytest.raises(UserError, match=r"warp\.EA = -1\.0: must be a positive number \[N\]"):
        with_key(scene, "warp.EA", -1.0)
    with pytest.raises(UserError, match=r"unknown key 'warp\.kawabata_k'; did you mean "
                                         r"'warp\.kawabata_K'\?"):
        with_key(scene, "warp.kawabata_k", 0.1)
    with pytest.raises(UserError, match=r"no \[friction\] table"):
        with_key(scene, "friction.alpha", 0.1)


def test_validate_scene_checks_a_scene_built_in_python():
    scene = parse()
    assert validate_scene(scene) is scene
    with pytest.raises(UserError, match=r"weft\.count = 0: must be a positive integer"):
        validate_scene(replace(scene, weft=replace(scene.weft, count=0)))
    with pytest.raises(UserError, match=r"missing required table \[weft\]"):
        validate_scene(replace(scene, weft=None))


def test_with_key_reaches_keys_that_cannot_be_swept():
    scene = parse()
    assert with_key(scene, "geometry.segments", 448).geometry.segments == 448
    assert with_key(scene, "load.values", [0.5]).load.values == (0.5,)
    with pytest.raises(UserError, match=r"geometry\.segments = 100: must be a positive "
                                         r"multiple .* nearest valid: 96"):
        with_key(scene, "geometry.segments", 100)


@pytest.mark.parametrize("path", sorted(p for p in RUNS.glob("*.toml")
                                         if not p.name.startswith("study_")),
                         ids=lambda p: p.name)
def test_every_scene_in_runs_parses(path):
    # runs/study_*.toml are study files (dynfab study), tested in tests/test_study.py
    scene = load_scene(path)
    assert scene.title
    assert all(one.sweep == () for one in expand_sweep(scene))


def test_paper_scenes():
    fig3 = load_scene(RUNS / "paper_fig3.toml")
    assert fig3.geometry.reference == "prestressed" and fig3.weft.count == 16
    assert fig3.load.control == "displacement" and len(fig3.load.values) == 40
    assert fig3.load.values[-1] == 0.01
    assert [(s.warp.kawabata_K, s.weft.kawabata_K) for s in expand_sweep(fig3)] == [
        (0.02, 0.02), (0.2, 0.2), (1.0, 1.0)]
    fig5 = expand_sweep(load_scene(RUNS / "paper_fig5.toml"))
    assert [(s.friction.alpha, s.friction.beta) for s in fig5] == [(0.2, 1e3), (0.0, 0.0)]
    relax = load_scene(RUNS / "relax.toml")
    assert relax.load.values == (0.0,) and relax.dynamic.mode == "transient"
    assert (relax.dynamic.duration, relax.dynamic.output_interval) == (0.02, 2e-4)


# --------------------------------------------------------------------------
# Files.


def test_missing_file(tmp_path):
    missing = tmp_path / "x.toml"
    with pytest.raises(UserError, match=r"scene file '.*x\.toml' not found"):
        load_scene(missing)


def test_not_toml_names_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[geometry\nlength = 0.1\n")
    with pytest.raises(UserError, match=r"bad\.toml: not valid TOML: .*line 1") as info:
        load_scene(bad)
    assert "\n" not in str(info.value)


def test_load_scene_reads_a_file(tmp_path):
    good = tmp_path / "good.toml"
    good.write_text(edited({}))
    assert load_scene(good) == parse()


# --------------------------------------------------------------------------
# User mistakes: each raises UserError, one line, naming the key.

NAN, INF = float("nan"), float("inf")
TRANSIENT = {"mode": "transient", "duration": 0.02, "output_interval": 2e-4}

BAD = {
    # unknown or misspelt keys and tables, at any level
    "misspelt key": ({"warp.kawabata_k": 0.2},
                     r"unknown key 'warp\.kawabata_k'; did you mean 'warp\.kawabata_K'\?"),
    "misspelt table": ({"geomtry": {"length": 0.1}},
                       r"unknown key 'geomtry'; did you mean 'geometry'\?"),
    "key outside its table": ({"segments": 224},
                              r"unknown key 'segments'; did you mean 'geometry\.segments' "
                              r"\(segments under \[geometry\]\)\?"),
    "misspelt top key": ({"titel": "x"}, r"unknown key 'titel'; did you mean 'title'\?"),
    "key in the wrong table": ({"warp.count": 16}, r"unknown key 'warp\.count'; did you mean"
                               r" 'weft\.count'\?"),
    "nested unknown table": ({"warp.extra": {"a": 1}}, r"unknown key 'warp\.extra'"),
    "unknown static key": ({"static": {"tolerence": 1e-9}},
                           r"did you mean 'static\.tolerance'\?"),
    "unknown dynamic key": ({"dynamic": {"damp": "viscous"}},
                            r"unknown key 'dynamic\.damp'; did you mean 'dynamic\.damping'\?"),
    "unknown load key": ({"load.value": [1.0]},
                         r"unknown key 'load\.value'; did you mean 'load\.values'\?"),
    "unknown sweep key": ({"sweep": {"warp.kawabata_k": [0.1, 0.2]}},
                          r"unknown key 'sweep\.\"warp\.kawabata_k\"'; did you mean "
                          r"'sweep\.\"warp\.kawabata_K\"'\?"),
    # wrong types
    "string for a number": ({"warp.EA": "13.72"},
                            r'warp\.EA = "13\.72": must be a number \[N\], not a string'),
    "float for an int": ({"geometry.segments": 224.5},
                         r"geometry\.segments = 224\.5: must be an integer"),
    "float for an int with no fraction": ({"geometry.crossings": 16.0},
                                          r"geometry\.crossings = 16\.0: must be an integer"),
    "bool for a number": ({"warp.EI": True}, r"warp\.EI = true: must be a number .*boolean"),
    "bool for an int": ({"geometry.yarns": True}, r"geometry\.yarns = true: must be an integer"),
    "number for a string": ({"geometry.reference": 1}, r"geometry\.reference = 1: must be a "
                            r"string, not an integer"),
    "bad choice": ({"geometry.reference": "as-woven"},
                   r'geometry\.reference = "as-woven": must be one of "as_woven", '
                   r'"prestressed"; did you mean "as_woven"\?'),
    "bad load control": ({"load.control": "displace"}, r'load\.control = "displace"'),
    "title not a string": ({"title": 3}, r"title = 3: must be a string"),
    "table given a value": ({"warp": 3}, r"warp = 3: must be a table \[warp\]"),
    "list for a number": ({"warp.EA": [1.0]}, r"warp\.EA = \[1\.0\]: must be a number"),
    "string in load values": ({"load.values": [0.001, "x"]}, r'load\.values\[1\] = "x"'),
    "load values not a list": ({"load.values": 0.001},
                               r"load\.values = 0\.001: must be a non-empty list"),
    # missing required keys and tables
    "missing geometry": ({"geometry": DELETE}, r"missing required table \[geometry\]"),
    "missing warp": ({"warp": DELETE}, r"missing required table \[warp\]"),
    "missing load": ({"load": DELETE}, r"missing required table \[load\]"),
    "missing weft with crossings": ({"weft": DELETE},
                                    r"missing required table \[weft\] \(geometry\.crossings"),
    "missing geometry.length": ({"geometry.length": DELETE},
                                r"missing required key geometry\.length \[m\]"),
    "missing geometry.segments": ({"geometry.segments": DELETE},
                                  r"missing required key geometry\.segments"),
    "missing geometry.crossings": ({"geometry.crossings": DELETE},
                                   r"missing required key geometry\.crossings"),
    "missing geometry.amplitude": ({"geometry.amplitude": DELETE},
                                   r"missing required key geometry\.amplitude"),
    "missing warp.EA": ({"warp.EA": DELETE}, r"missing required key warp\.EA \[N\]"),
    "missing warp.EI": ({"warp.EI": DELETE}, r"missing required key warp\.EI"),
    "missing warp.kawabata_C": ({"warp.kawabata_C": DELETE},
                                r"missing required key warp\.kawabata_C"),
    "missing warp.kawabata_K": ({"warp.kawabata_K": DELETE},
                                r"missing required key warp\.kawabata_K"),
    "missing weft.EI": ({"weft.EI": DELETE}, r"missing required key weft\.EI"),
    "missing weft.amplitude": ({"weft.amplitude": DELETE},
                               r"missing required key weft\.amplitude"),
    "missing weft.kawabata_C": ({"weft.kawabata_C": DELETE},
                                r"missing required key weft\.kawabata_C"),
    "missing weft.kawabata_K": ({"weft.kawabata_K": DELETE},
                                r"missing required key weft\.kawabata_K"),
    "missing friction.alpha": ({"friction": {"beta": 1e3, "contact_length": 2e-3,
                                             "fiber_radius": 1e-3}},
                               r"missing required key friction\.alpha"),
    "missing load path": ({"load.values": DELETE},
                          r"missing required key load\.values \(or load\.max and load\.steps\)"),
    "load max without steps": ({"load.values": DELETE, "load.max": 0.01},
                               r"missing required key load\.steps"),
    "load steps without max": ({"load.values": DELETE, "load.steps": 4},
                               r"missing required key load\.max"),
    "load values and max": ({"load.max": 0.01, "load.steps": 4},
                            r"load\.values and load\.max both given"),
    "missing transient duration": ({"dynamic": {"mode": "transient", "output_interval": 1e-3}},
                                   r"missing required key dynamic\.duration"),
    "missing transient output_interval": ({"dynamic": {"mode": "transient", "duration": 1.0}},
                                          r"missing required key dynamic\.output_interval"),
    # segments and crossings
    "segments not a multiple": ({"geometry.segments": 225},
                                r"geometry\.segments = 225: must be a positive multiple of "
                                r"2 x geometry\.crossings = 32 \(crossings = 16\); "
                                r"nearest valid: 224"),
    "segments below 2 crossings": ({"geometry.segments": 8},
                                   r"geometry\.segments = 8: .*nearest valid: 32"),
    "segments zero": ({"geometry.segments": 0}, r"geometry\.segments = 0: must be a positive"),
    "rod with one segment": ({"geometry.crossings": 0, "geometry.segments": 1,
                              "geometry.amplitude": 0.0, "weft": DELETE},
                             r"geometry\.segments = 1: a plain rod"),
    "rod with crimp": ({"geometry.crossings": 0, "weft": DELETE},
                       r"geometry\.amplitude = 0\.0005: a plain rod"),
    "negative crossings": ({"geometry.crossings": -16},
                           r"geometry\.crossings = -16: must be a non-negative integer"),
    "weft on a rod": ({"geometry.crossings": 0, "geometry.amplitude": 0.0},
                      r"\[weft\] given but geometry\.crossings = 0"),
    "friction on a rod": ({"geometry.crossings": 0, "geometry.amplitude": 0.0,
                           "weft": DELETE, "friction": FRICTION},
                          r"\[friction\] given but geometry\.crossings = 0"),
    # ranges
    "zero length": ({"geometry.length": 0.0}, r"geometry\.length = 0\.0: must be a positive "
                    r"number \[m\]"),
    "negative weft length": ({"weft.length": -0.1}, r"weft\.length = -0\.1: must be a positive"),
    "negative EA": ({"warp.EA": -1.0}, r"warp\.EA = -1\.0: must be a positive number \[N\]"),
    "zero warp EI": ({"warp.EI": 0}, r"warp\.EI = 0: must be a positive number \[N m\^2\]"),
    "negative weft EI": ({"weft.EI": -1e-7}, r"weft\.EI = -1e-07: must be a positive"),
    "zero stick stiffness": ({"friction": dict(FRICTION, stick_stiffness=0.0)},
                             r"friction\.stick_stiffness = 0\.0: must be a positive"),
    "zero warp C": ({"warp.kawabata_C": 0.0}, r"warp\.kawabata_C = 0\.0: must be a positive"),
    "negative warp K": ({"warp.kawabata_K": -0.2}, r"warp\.kawabata_K = -0\.2: must be a posit"),
    "zero weft C": ({"weft.kawabata_C": 0.0}, r"weft\.kawabata_C = 0\.0: must be a positive"),
    "zero weft K": ({"weft.kawabata_K": 0.0}, r"weft\.kawabata_K = 0\.0: must be a positive"),
    "zero linear density": ({"warp.linear_density": 0.0},
                            r"warp\.linear_density = 0\.0: must be a positive number \[kg/m\]"),
    "zero weft count": ({"weft.count": 0}, r"weft\.count = 0: must be a positive integer"),
    "zero yarns": ({"geometry.yarns": 0}, r"geometry\.yarns = 0: must be a positive integer"),
    "negative alpha": ({"friction": dict(FRICTION, alpha=-0.1)},
                       r"friction\.alpha = -0\.1: must be a non-negative number"),
    "negative beta": ({"friction": dict(FRICTION, beta=-1.0)}, r"friction\.beta = -1\.0"),
    "negative contact length": ({"friction": dict(FRICTION, contact_length=-1e-3)},
                                r"friction\.contact_length = -0\.001"),
    "negative fiber radius": ({"friction": dict(FRICTION, fiber_radius=-1e-3)},
                              r"friction\.fiber_radius = -0\.001"),
    "negative onset force": ({"friction": dict(FRICTION, onset_force=-1e-5)},
                             r"friction\.onset_force = -1e-05: must be a non-negative number \[N\]"),
    "zero core stiffness": ({"contact": {"core_stiffness": 0.0}},
                            r"contact\.core_stiffness = 0\.0: must be a positive number \[N/m\]"),
    "negative core stiffness": ({"contact": {"core_stiffness": -1e5}},
                                r"contact\.core_stiffness = -100000\.0"),
    "contact on a rod": ({"geometry.crossings": 0, "geometry.amplitude": 0.0,
                          "weft": DELETE, "contact": {"core_stiffness": 1e5}},
                         r"\[contact\] given but geometry\.crossings = 0"),
    "negative amplitude": ({"geometry.amplitude": -1e-4},
                           r"geometry\.amplitude = -0\.0001: must be a non-negative"),
    "negative weft amplitude": ({"weft.amplitude": -1e-4}, r"weft\.amplitude = -0\.0001"),
    "zero static tolerance": ({"static": {"tolerance": 0.0}}, r"static\.tolerance = 0\.0"),
    "zero max_iterations": ({"static": {"max_iterations": 0}}, r"static\.max_iterations = 0"),
    "zero dt": ({"dynamic": {"dt": 0.0}}, r"dynamic\.dt = 0\.0: must be a positive number \[s\]"),
    "zero safety": ({"dynamic": {"safety": 0.0}}, r"dynamic\.safety = 0\.0"),
    "negative damping coefficient": ({"dynamic": {"damping": "viscous",
                                                  "damping_coefficient": -1.0}},
                                     r"dynamic\.damping_coefficient = -1\.0"),
    "zero dynamic tolerance": ({"dynamic": {"tolerance": 0.0}}, r"dynamic\.tolerance = 0\.0"),
    "zero max_steps": ({"dynamic": {"max_steps": 0}}, r"dynamic\.max_steps = 0"),
    "float max_steps": ({"dynamic": {"max_steps": 1e6}}, r"dynamic\.max_steps = 1000000\.0: "
                        r"must be an integer"),
    "bad precision": ({"dynamic": {"precision": "float16"}}, r'dynamic\.precision = "float16"'),
    "bad method": ({"dynamic": {"method": "implicit"}}, r'dynamic\.method = "implicit"'),
    "bad damping": ({"dynamic": {"damping": "none"}}, r'dynamic\.damping = "none"'),
    "bad masses": ({"dynamic": {"masses": "real"}}, r'dynamic\.masses = "real"'),
    "bad mode": ({"dynamic": {"mode": "static"}}, r'dynamic\.mode = "static"'),
    "zero load max": ({"load.values": DELETE, "load.max": 0.0, "load.steps": 4},
                      r"load\.max = 0\.0: must be a non-zero number"),
    "zero load steps": ({"load.values": DELETE, "load.max": 0.01, "load.steps": 0},
                        r"load\.steps = 0: must be a positive integer"),
    "float load steps": ({"load.values": DELETE, "load.max": 0.01, "load.steps": 4.0},
                         r"load\.steps = 4\.0: must be an integer"),
    # NaN and infinity
    "nan length": ({"geometry.length": NAN}, r"geometry\.length = nan: must be a finite"),
    "inf EA": ({"warp.EA": INF}, r"warp\.EA = inf: must be a finite number \[N\]"),
    "nan tension": ({"weft.tension": NAN}, r"weft\.tension = nan: must be a finite"),
    "inf gravity": ({"gravity": {"g": -INF}}, r"gravity\.g = -inf: must be a finite"),
    "nan in load values": ({"load.values": [0.001, NAN]}, r"load\.values\[1\] = nan"),
    "inf load max": ({"load.values": DELETE, "load.max": INF, "load.steps": 2},
                     r"load\.max = inf"),
    "nan in sweep": ({"sweep": {"warp.EA": [13.0, NAN]}}, r'sweep\."warp\.EA"\[1\] = nan'),
    # load path
    "empty load path": ({"load.values": []}, r"load\.values = \[\]: must be a non-empty list"),
    # weft buckling
    "weft at buckling": ({"weft.tension": -math.pi**2 * 1.47e-7 / 0.1**2},
                         r"weft\.tension = -0\.000145.*: must be > -0\.000145083 N = -pi\^2"),
    "weft beyond buckling": ({"weft.tension": -1.0},
                             r"weft\.tension = -1\.0: must be > -0\.000145083 N .*buckles"),
    # sweeps
    "sweep with yarns": ({"geometry.yarns": 2, "sweep": {"warp.EA": [13.0, 14.0]}},
                         r"geometry\.yarns = 2: a scene with a \[sweep\]"),
    "sweep segments": ({"sweep": {"geometry.segments": [224, 448]}},
                       r'sweep\."geometry\.segments": this key cannot be swept'),
    "sweep crossings": ({"sweep": {"geometry.crossings": [16, 8]}},
                        r'sweep\."geometry\.crossings": this key cannot be swept'),
    "sweep yarns": ({"sweep": {"geometry.yarns": [1, 2]}},
                    r'sweep\."geometry\.yarns": this key cannot be swept'),
    "sweep weft count": ({"sweep": {"weft.count": [16, 8]}},
                         r'sweep\."weft\.count": this key cannot be swept'),
    "sweep load": ({"sweep": {"load.values": [1.0, 2.0]}},
                   r'sweep\."load\.values": this key cannot be swept'),
    "sweep load max": ({"load.values": DELETE, "load.max": 0.01, "load.steps": 2,
                        "sweep": {"load.max": [0.01, 0.02]}},
                       r'sweep\."load\.max": this key cannot be swept'),
    "sweep absent friction": ({"sweep": {"friction.alpha": [0.1, 0.2]}},
                              r'sweep\."friction\.alpha": the scene has no \[friction\] table'),
    "sweep absent gravity": ({"sweep": {"gravity.g": [9.81, 0.0]}},
                             r'sweep\."gravity\.g": the scene has no \[gravity\] table'),
    "sweep unequal lengths": ({"sweep": {"warp.EA": [13.0, 14.0, 15.0],
                                         "weft.EI": [1e-7, 2e-7]}},
                              r'sweep\."weft\.EI" has 2 entries but sweep\."warp\.EA" has 3'),
    "sweep empty list": ({"sweep": {"warp.EA": []}},
                         r'sweep\."warp\.EA" = \[\]: must be a non-empty list'),
    "sweep scalar": ({"sweep": {"warp.EA": 13.0}},
                     r'sweep\."warp\.EA" = 13\.0: must be a non-empty list'),
    "sweep empty table": ({"sweep": {}}, r"\[sweep\] is empty"),
    "sweep negative EA": ({"sweep": {"warp.EA": [13.0, -1.0]}},
                          r"sweep entry 1: warp\.EA = -1\.0: must be a positive number \[N\]"),
    "sweep negative amplitude": ({"sweep": {"geometry.amplitude": [-1e-4, 1e-4]}},
                                 r"sweep entry 0: geometry\.amplitude = -0\.0001"),
    "sweep buckling tension": ({"sweep": {"weft.tension": [0.0, -1.0]}},
                               r"sweep entry 1: weft\.tension = -1\.0: must be >"),
    "sweep string": ({"sweep": {"warp.EA": [13.0, "x"]}},
                     r'sweep\."warp\.EA"\[1\] = "x": must be a number \[N\]'),
    # [dynamic] combinations
    "transient fictitious masses": ({"dynamic": dict(TRANSIENT, masses="fictitious")},
                                    r'dynamic\.masses = "fictitious": not allowed with '
                                    r'dynamic\.mode = "transient"'),
    "transient kinetic damping": ({"dynamic": dict(TRANSIENT, damping="kinetic")},
                                  r'dynamic\.damping = "kinetic": not allowed with dynamic\.mode'),
    "transient fire damping": ({"dynamic": dict(TRANSIENT, damping="fire")},
                               r'dynamic\.damping = "fire": not allowed'),
    "transient zero duration": ({"dynamic": dict(TRANSIENT, duration=0.0)},
                                r"dynamic\.duration = 0\.0: must be a positive"),
    "transient zero output interval": ({"dynamic": dict(TRANSIENT, output_interval=0.0)},
                                       r"dynamic\.output_interval = 0\.0: must be a positive"),
    "output interval beyond duration": ({"dynamic": dict(TRANSIENT, output_interval=0.1)},
                                        r"dynamic\.output_interval = 0\.1: must be <= "
                                        r"dynamic\.duration = 0\.02"),
    "duration without transient": ({"dynamic": {"duration": 0.02}},
                                   r'dynamic\.duration = 0\.02: only used with dynamic\.mode'),
    "damping coefficient with kinetic": ({"dynamic": {"damping_coefficient": 1.0}},
                                         r"dynamic\.damping_coefficient = 1\.0: only used with"),
    "semi_implicit with kinetic damping": ({"dynamic": {"method": "semi_implicit",
                                                        "damping": "kinetic"}},
                                           r'dynamic\.damping = "kinetic": not available with '
                                           r'dynamic\.method = "semi_implicit"'),
    "semi_implicit with fire damping": ({"dynamic": {"method": "semi_implicit", "damping": "fire"}},
                                        r'dynamic\.damping = "fire": not available with '
                                        r'dynamic\.method = "semi_implicit"'),
}


@pytest.mark.parametrize("edits, match", BAD.values(), ids=BAD.keys())
def test_bad_input_raises_one_line_scene_error(edits, match):
    with pytest.raises(UserError, match=match) as info:
        parse(edits)
    message = str(info.value)
    assert "\n" not in message and message.strip() == message


COMBINATIONS = ["transient fictitious masses", "transient kinetic damping",
                "transient fire damping", "output interval beyond duration", "duration without transient",
                "damping coefficient with kinetic", "semi_implicit with kinetic damping",
                "semi_implicit with fire damping"]
"""The BAD cases that combine [dynamic] keys (not one value out of its range)."""


@pytest.mark.parametrize("name", COMBINATIONS)
def test_solver_options_built_in_python_meet_the_scene_rules_word_for_word(name):
    """DynamicSolver's options given in code go through the scene's own combination rules:
    the same refusal, byte for byte, as the same keys written in a scene file."""
    edits, _ = BAD[name]
    with pytest.raises(UserError) as from_file:
        parse(edits)
    with pytest.raises(UserError) as from_code:
        check_dynamic_options(Dynamic(**edits["dynamic"]))
    assert str(from_code.value) == str(from_file.value)


def test_unset_damping_and_masses_follow_the_mode():
    """The defaults the solver runs with (docs/model.md section 5), written once on Dynamic."""
    assert (Dynamic().damping_used(), Dynamic().masses_used()) == ("kinetic", "fictitious")
    transient = Dynamic(**TRANSIENT)
    assert (transient.damping_used(), transient.masses_used()) == ("viscous", "physical")
    assert Dynamic(damping="fire", masses="physical").damping_used() == "fire"


def test_every_key_is_declared_with_what_it_needs():
    """The schema read from the fields: sweepable keys are reals (a sweep holds reals and
    changes no array shape), run options live in [static] and [dynamic] only, every key
    has a meaning, every real key a unit, and a choice key no range rule."""
    for table, (_, keys) in scene_module._SCHEMA.items():
        for name, spec in keys.items():
            assert spec.doc, f"{table}.{name}"
            assert not spec.sweepable or spec.kind == "float", f"{table}.{name}"
            assert not spec.option or table in ("static", "dynamic"), f"{table}.{name}"
            assert spec.unit or spec.kind != "float", f"{table}.{name}"
            assert not (spec.choices and spec.rule), f"{table}.{name}"


def test_an_unsweepable_key_names_the_sweepable_ones():
    """The list in the message is written from the sweepable flags; this is its wording."""
    with pytest.raises(UserError) as info:
        parse({"sweep": {"weft.count": [16, 32]}})
    assert str(info.value) == ('sweep."weft.count": this key cannot be swept; sweepable are '
                               "geometry.amplitude and the real-valued keys of [warp], [weft], "
                               "[contact], [friction] and [gravity]")


def test_docs_scene_md_is_the_generated_key_table():
    """docs/scene.md is what the command it names prints, row for row with the keys."""
    committed = (RUNS.parent / "docs" / "scene.md").read_text()
    printed = subprocess.run([sys.executable, "-m", "dynfab.scene", "--markdown"],
                             capture_output=True, text=True, check=True).stdout
    assert committed == printed == markdown_table(), (
        "docs/scene.md differs from the scene keys: regenerate it with "
        "`python -m dynfab.scene --markdown > docs/scene.md`")
    for dotted in scene_module._ALL_KEYS:
        assert f"| `{dotted}` |" in committed


# --------------------------------------------------------------------------
# The woven fabric's keys (docs/model.md section 10).

FABRIC = {"geometry.model": "fabric", "geometry.segments": 32, "geometry.crossings": 4,
          "weft.count": 4, "weft.segments": 32, "weft.EA": 13.72,
          "load.weft_values": [0.0, 0.001]}
"""BASE as a 4 x 4 fabric (clamped, displacement control)."""


def fabric(edits: dict | None = None):
    """BASE as a fabric, with edits."""
    return parse({**FABRIC, **(edits or {})})


def test_fabric_scene_keys_and_their_defaults():
    scene = fabric()
    g, load = scene.geometry, scene.load
    assert (g.model, g.boundary, g.planes) == ("fabric", "clamped", "fixed")
    assert (scene.weft.EA, scene.weft.segments, scene.weft.linear_density) == (13.72, 32, None)
    assert load.weft_values == (0.0, 0.001) and load.warp_factors is load.weft_factors is None
    assert parse().geometry.model == "yarn" and parse().load.weft_values is None
    scene = fabric({"geometry.boundary": "periodic",
                    "load.warp_factors": [1, 0, 1, 0], "load.weft_factors": [0, 0, 0, 0],
                    "weft.linear_density": 2e-5})
    assert scene.geometry.planes == "cell"  # a periodic cell's planes move with it
    assert 'planes = "cell"' in scene_to_toml(scene)  # what a result file stores: what ran
    assert fabric({"geometry.boundary": "periodic", "geometry.planes": "cell"}).geometry == \
        scene.geometry
    assert scene.load.warp_factors == (1.0, 0.0, 1.0, 0.0)
    assert scene.load.weft_factors == (0.0,) * 4 and scene.weft.linear_density == 2e-5
    pull = fabric({"pullout": {"warp": 2}})
    assert pull.pullout.warp == 2
    for s in (scene, pull, parse()):
        assert parse_scene_text(scene_to_toml(s)) == replace(s, text=scene_to_toml(s))
    assert "model" not in scene_to_toml(parse())  # a one-yarn scene's text as before


def test_fabric_load_path_from_max_and_steps_keeps_weft_values():
    scene = fabric({"load.values": DELETE, "load.max": 0.002, "load.steps": 2})
    assert scene.load.values == (0.001, 0.002) and scene.load.weft_values == (0.0, 0.001)


@pytest.mark.parametrize("key, value", [
    ("geometry.boundary", "periodic"), ("geometry.planes", "fixed"), ("weft.EA", 13.72),
    ("weft.segments", 32), ("weft.linear_density", 3e-5), ("load.weft_values", [0.0, 0.1]),
    ("load.warp_factors", [1.0]), ("load.weft_factors", [1.0])])
def test_a_fabric_key_in_a_one_yarn_scene_is_refused(key, value):
    with pytest.raises(UserError) as info:
        parse({key: value})
    shown = scene_module._show(value)
    assert str(info.value) == (f'{key} = {shown}: a key of the woven fabric (docs/model.md section '
                               '10), but geometry.model = "yarn": set geometry.model = '
                               '"fabric" or remove it')


def test_a_pullout_in_a_one_yarn_scene_is_refused():
    with pytest.raises(UserError) as info:
        parse({"pullout": {"warp": 1}})
    assert str(info.value) == ('[pullout] given but geometry.model = "yarn": a pull-out is a '
                               'fabric scene (docs/model.md section 10); set geometry.model = '
                               '"fabric" or remove [pullout]')


def test_a_fabric_key_set_in_python_on_a_one_yarn_scene_is_refused():
    with pytest.raises(UserError, match=r'geometry\.boundary = "periodic": a key of the woven '
                                        r'fabric'):
        with_key(parse(), "geometry.boundary", "periodic")


@pytest.mark.parametrize("key, value, why", [
    ("weft.tension", 0.1, "the wefts are chains, loaded by load.weft_values"),
    ("geometry.yarns", 2, "the fabric simulates weft.count warps and geometry.crossings wefts")])
def test_a_one_yarn_key_in_a_fabric_is_refused(key, value, why):
    with pytest.raises(UserError) as info:
        fabric({key: value})
    assert str(info.value) == (f'{key} = {value!r}: means nothing in a fabric (geometry.model = '
                               f'"fabric", docs/model.md section 10): {why}; remove it')
    with pytest.raises(UserError, match="means nothing in a fabric"):
        with_key(fabric(), key, value)  # set in Python


def test_a_sweep_in_a_fabric_is_refused():
    with pytest.raises(UserError) as info:
        fabric({"sweep": {"warp.EA": [13.0, 14.0]}})
    assert str(info.value) == ('[sweep] given but geometry.model = "fabric": a patch is one '
                               'coupled group, not a batch of independent yarns (docs/model.md '
                               'section 10); vary it in a study (dynfab study, a [vary] table: '
                               'runs/study_example.toml)')


def test_a_prestressed_fabric_is_refused():
    with pytest.raises(UserError) as info:
        fabric({"geometry.reference": "prestressed"})
    assert str(info.value) == ('geometry.reference = "prestressed": a fabric\'s stress-free '
                               'state is as woven (docs/model.md section 10); use "as_woven"')


@pytest.mark.parametrize("key, value, what", [("weft.count", 3, "warps"),
                                              ("geometry.crossings", 3, "wefts")])
def test_odd_yarn_counts_on_a_periodic_cell_are_refused(key, value, what):
    segments = {"weft.segments": 36} if key == "weft.count" else {"geometry.segments": 36}
    with pytest.raises(UserError) as info:
        fabric({"geometry.boundary": "periodic", key: value, **segments})
    assert str(info.value) == (f'{key} = 3: a periodic cell (geometry.boundary = "periodic") '
                               f'needs an even number of {what}: the plain-weave repeat is 2 x 2')


def test_gravity_on_a_periodic_cell_is_refused():
    with pytest.raises(UserError) as info:
        fabric({"geometry.boundary": "periodic", "gravity": {}})
    assert str(info.value) == ('[gravity] given with geometry.boundary = "periodic": a periodic '
                               'cell has no gravity (docs/model.md section 10); remove [gravity] or '
                               'use a clamped patch')


@pytest.mark.parametrize("key, value, message", [
    ("load.weft_values", [0.1], "load.weft_values has 1 entries but load.values has 2: give one "
                                "per load step"),
    ("load.warp_factors", [1, 1, 1], "load.warp_factors has 3 entries but weft.count says there "
                                     "are 4 warps: give one per warp"),
    ("load.weft_factors", [1] * 5, "load.weft_factors has 5 entries but geometry.crossings says "
                                   "there are 4 wefts: give one per weft")])
def test_fabric_lists_of_another_length_are_refused(key, value, message):
    with pytest.raises(UserError) as info:
        fabric({key: value})
    assert str(info.value) == message


def test_mixed_control_is_refused():
    with pytest.raises(UserError) as info:
        fabric({"load.weft_control": "force"})
    assert str(info.value) == ('load.weft_control = "force": one load.control for both '
                               'families (docs/model.md section 10): mixed control is refused')


def test_fabric_needs_the_weft_chain_keys():
    with pytest.raises(UserError) as info:
        parse({k: v for k, v in FABRIC.items() if k != "weft.EA"})
    assert str(info.value) == ('missing required key weft.EA [N] (needed with geometry.model = '
                               '"fabric")')
    with pytest.raises(UserError) as info:
        fabric({"weft.segments": 30})
    assert str(info.value) == ("weft.segments = 30: must be a positive multiple of 2 x "
                               "weft.count = 8; nearest valid: 32")


@pytest.mark.parametrize("edits, message", [
    ({"pullout": {"warp": 5}}, "pullout.warp = 5: must name a warp 1..weft.count = 4"),
    ({"pullout": {"warp": 1}, "load.control": "force"},
     'load.control = "force": a pull-out is displacement-controlled (docs/model.md section 10); '
     'use "displacement"'),
    ({"pullout": {"warp": 1}, "geometry.planes": "affine"},
     'geometry.planes = "affine": a pull-out is a clamped patch with fixed planes (docs/model.md '
     'section 10)'),
    ({"pullout": {"warp": 1}, "load.warp_factors": [1, 0, 0, 0]},
     "load.warp_factors = [1.0, 0.0, 0.0, 0.0]: a pull-out sets them (the pulled warp 1, the "
     "others held); remove it")])
def test_a_pullout_outside_its_rules_is_refused(edits, message):
    with pytest.raises(UserError) as info:
        fabric(edits)
    assert str(info.value) == message


PULLOUT_OF_A_CELL = ('geometry.boundary = "periodic": a pull-out is a clamped patch with fixed '
                     'planes (docs/model.md section 10)')
CELL_PLANES_ONLY = ('geometry.planes = "{}": a periodic cell\'s planes always move with the cell '
                    '(docs/model.md section 10); leave the key out or write "cell"')
PERIODIC_REFUSALS = {
    "pullout of a cell, force control": (
        {"geometry.boundary": "periodic", "pullout": {"warp": 1}, "load.control": "force"},
        PULLOUT_OF_A_CELL),
    "pullout of a cell, displacement control": (
        {"geometry.boundary": "periodic", "pullout": {"warp": 1}}, PULLOUT_OF_A_CELL),
    "pullout of a cell with affine planes": (
        {"geometry.boundary": "periodic", "pullout": {"warp": 1}, "geometry.planes": "affine",
         "load.control": "force"}, PULLOUT_OF_A_CELL),
    "affine planes on a cell": ({"geometry.boundary": "periodic", "geometry.planes": "affine"},
                                CELL_PLANES_ONLY.format("affine")),
    "fixed planes on a cell": ({"geometry.boundary": "periodic", "geometry.planes": "fixed"},
                               CELL_PLANES_ONLY.format("fixed")),
    "cell planes on a clamped patch": (
        {"geometry.planes": "cell"},
        'geometry.planes = "cell": the planes of a periodic cell (geometry.boundary = '
        '"periodic"); a clamped patch\'s are "fixed" or "affine"'),
}
"""A periodic cell's refusals: a pull-out for its boundary whatever its control and planes (it
was refused for its control under force control), planes other than the cell's (they were
accepted and ignored)."""


@pytest.mark.parametrize("edits, message", PERIODIC_REFUSALS.values(),
                         ids=PERIODIC_REFUSALS.keys())
def test_a_periodic_cell_is_refused_for_the_key_that_is_wrong(edits, message):
    with pytest.raises(UserError) as info:
        fabric(edits)
    assert str(info.value) == message


@pytest.mark.parametrize("name", ["pullout of a cell, force control", "affine planes on a cell"])
def test_a_periodic_cell_refused_is_one_line_and_exit_status_2(tmp_path, name):
    """The command line: one line naming the key, exit status 2, nothing written."""
    edits, message = PERIODIC_REFUSALS[name]
    scene = tmp_path / "cell.toml"
    scene.write_text(edited({**FABRIC, **edits}))
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "run", str(scene), "--out",
                           str(tmp_path / "cell.h5")], capture_output=True, text=True)
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [f"dynfab: error: {message}"]
    assert not (tmp_path / "cell.h5").exists()


def test_a_periodic_cell_built_in_python_runs_and_stores_the_cell_planes():
    """Built in Python without planes, a fabric gets the planes it runs (validate_scene):
    "cell" on a periodic cell, "fixed" on a clamped patch; with_key to a periodic boundary keeps
    the clamped patch's explicit "fixed", refused."""
    clamped = fabric()
    bare = replace(clamped, geometry=replace(clamped.geometry, planes=None))
    assert validate_scene(bare).geometry.planes == "fixed"
    periodic = replace(bare, geometry=replace(bare.geometry, boundary="periodic"))
    assert validate_scene(periodic).geometry.planes == "cell"
    with pytest.raises(UserError, match=r'^geometry\.planes = "fixed": a periodic cell'):
        with_key(clamped, "geometry.boundary", "periodic")
