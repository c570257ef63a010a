"""`dynfab fit` on a shear specimen (docs/model.md sections 11 and "Fitting parameters"): the
measured column `clamp_force [N]` against the clamp displacement `end_displacement [m]`,
the crossing's keys fittable, step 0 (the preload relaxed) no point of the curve.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynfab import run
from dynfab.errors import UserError
from dynfab.fitting.fit import fit
from dynfab.results.measured_curve import curve_from_columns
from dynfab.fitting.models import FabricFit
from dynfab.scene import parse_scene_text, with_key
from test_shear_specimens import FRAME, scene_text

D = [1e-3, 2e-3, 3e-3]
TRUTH = 5e-3
"""crossing.shear_stiffness [N m/rad] of the synthetic curve."""


def small_frame():
    """A 22 mm picture frame (three crossings across): a few tenths of a second a step."""
    return parse_scene_text(scene_text(FRAME.replace("side = 0.06", "side = 0.022"), D))


def synthetic_curve(scene):
    """The scene's own clamp forces at D, less step 0: the zero-residual curve."""
    force = run(scene, solver="static").steps["clamp_force"][1:]
    return curve_from_columns(["end_displacement [m]", "clamp_force [N]"],
                              np.c_[D, force], "displacement", model="specimen")


def test_a_noise_free_clamp_force_curve_gives_back_the_shear_stiffness():
    """From a start 2x off, on the curve's own load steps (substeps = 1: the friction's return
    map makes the force depend on the steps taken, so a refined path is another path): the
    truth is the zero-residual minimum; the optimiser stops once a step in theta = log K is
    below xtol (1e-8) (1 + |theta|), |theta| ~ 5.3, so 10 x that."""
    scene = small_frame()
    data = synthetic_curve(scene)
    result = fit(scene, data, ["crossing.shear_stiffness"], substeps=1,
                 start={"crossing.shear_stiffness": 2 * TRUTH})
    assert result.converged, result.warnings
    value = result.parameters["crossing.shear_stiffness"]["value"]
    assert abs(math.log(value / TRUTH)) <= 10 * 1e-8 * (1 + abs(math.log(TRUTH)))


def test_the_specimen_offers_its_crossing_keys_and_a_planar_fabric_does_not():
    """A specimen offers its spatial crossing and lateral keys; a planar fabric with a
    [crossing] table (the pull-out's, crossing.motion) offers its woven-in preload, a planar
    key (docs/model.md section 10), and none of the spatial ones."""
    keys = FabricFit.fittable_keys(small_frame())
    assert {"crossing.shear_stiffness", "crossing.preload", "crossing.torsion_radius",
            "warp.lateral_stiffness", "friction.alpha"} <= set(keys)
    from independent import pullout_scene
    planar = set(FabricFit.fittable_keys(pullout_scene()))
    assert "crossing.preload" in planar
    assert not {k for k in planar if k in ("crossing.shear_stiffness", "crossing.torsion_radius")
                or k.endswith((".EI_lateral", ".width", ".lateral_stiffness"))}


def test_a_fabric_column_on_a_specimen_is_refused_in_one_line():
    with pytest.raises(UserError, match="warp_strain.*clamp_force"):
        curve_from_columns(["end_displacement [m]", "warp_strain [-]"], [[1e-3, 0.1]],
                           "displacement", model="specimen")


@pytest.mark.parametrize("model, header, words", [
    ("specimen", ["end_displacement [m]", "weft_load [m]", "clamp_force [N]"],
     ["'weft_load [m]'", "wefts' load", "a shear specimen", "takes no wefts' load"]),
    ("specimen", ["end_displacement [m]", "warp_strain [-]"],
     ["'warp_strain [-]'", "a measurement of the woven fabric", "'clamp_force [N]'"]),
    ("yarn", ["end_displacement [m]", "clamp_force [N]"],
     ["'clamp_force [N]'", "a measurement of a shear specimen", "the one-yarn model"]),
])
def test_a_column_of_another_kind_of_scene_is_named_as_that_kind_s(model, header, words):
    # each kind of curve says as data what it takes (measured_curve.MODELS): a wefts' load
    # column only the fabric's, each measured column its own kind's
    with pytest.raises(UserError) as info:
        curve_from_columns(header, [[1e-3] * len(header)], "displacement", model=model)
    message = str(info.value)
    assert "\n" not in message
    for word in words:
        assert word in message, (word, message)


def test_a_specimen_offers_only_keys_it_takes():
    # weft.length was offered and then refused by the specimen (its [specimen] sets the
    # layout): every key offered is one the scene takes
    scene = small_frame()
    keys = FabricFit.fittable_keys(scene)
    assert "weft.length" not in keys and "geometry.length" not in keys
    for key in keys:
        value = FabricFit.default_value(scene, key)
        table, name = key.split(".")
        current = getattr(getattr(scene, table), name, None)
        with_key(scene, key, current if current is not None else (value or 1.0))


def test_fit_help_names_the_csv_columns_of_every_kind_of_scene():
    import subprocess
    import sys
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "fit", "--help"],
                          capture_output=True, text=True)
    assert done.returncode == 0
    for column in ("load [N]", "end_displacement [m]", "end_force [N]", "warp_stress [N/m]",
                   "weft_load [N]", "clamp_force [N]"):
        assert f"'{column}'" in done.stdout
    assert "a shear specimen (a [specimen] scene) under displacement control" in done.stdout


def test_a_curve_with_the_wrong_columns_names_those_expected_and_found():
    with pytest.raises(UserError) as info:
        curve_from_columns(["d [m]", "force [N]"], [[1e-3, 0.1]], "displacement",
                           model="specimen")
    message = str(info.value)
    assert "\n" not in message
    assert "takes 'end_displacement [m]' first, then one or more of 'clamp_force [N]'" in message
    assert message.endswith("found 'd [m]', 'force [N]'")
