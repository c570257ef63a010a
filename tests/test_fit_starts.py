"""dynfab fit --starts K (dynfab/fitting/starts.py): the starting points and the best of K fits
on a local Dask cluster, on the fit example (runs/fit_example: a quarter yarn with
friction, 10 data points, about 50 ms a fit)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import dynfab
from dynfab.fitting.fit import make_parameters
from dynfab.fitting.starts import REACHED, SPREAD, fit_from_starts, start_points

EXAMPLE = Path(__file__).resolve().parents[1] / "runs" / "fit_example"
KEYS = ["warp.EA", "friction.alpha"]


def test_the_first_start_is_the_fit_s_own_and_the_others_fill_their_boxes():
    scene = dynfab.load_scene(EXAMPLE / "scene.toml")
    parameters = make_parameters(scene, KEYS, bounds={"friction.alpha": (0.05, 0.5)})
    count = 9
    points = start_points(parameters, count)
    assert points[0] == {"warp.EA": 10.0, "friction.alpha": 0.1}  # the scene's values
    ea = np.log([p["warp.EA"] for p in points[1:]])  # log-fitted, no bounds: 10 x either way
    alpha = np.array([p["friction.alpha"] for p in points[1:]])  # fitted in p, its bounds
    assert not parameters[1].log
    for values, (low, high) in ((ea, (math.log(10 / SPREAD), math.log(10 * SPREAD))),
                                (alpha, (0.05, 0.5))):
        strata = np.floor((values - low) / (high - low) * (count - 1)).astype(int)
        assert sorted(strata) == list(range(count - 1))  # one start per stratum of the box
    assert start_points(parameters, 1) == points[:1]
    assert start_points(parameters, count) == points  # seeded


def test_a_fit_from_several_starts_keeps_the_best_and_counts_who_reached_it(tmp_path):
    """The example's minimum is unique over these boxes: every start reaches it, and the
    best is at least as good as the one-start fit (the same optimiser from the same first
    start, on a worker)."""
    scene = dynfab.load_scene(EXAMPLE / "scene.toml")
    one = dynfab.fit(scene, EXAMPLE / "curve.csv", KEYS)  # compiles into the cache first
    lines = []
    best = fit_from_starts(scene, EXAMPLE / "curve.csv", KEYS, starts=3, workers=2,
                           progress=lines.append, out=tmp_path / "fit")
    assert best.cost <= one.cost * (1 + REACHED)
    assert best.starts["count"] == 3 and best.starts["failed"] == 0
    assert best.starts["reached_best"] == 3
    first = best.starts["points"][0]
    assert first["start"] == {"warp.EA": 10.0, "friction.alpha": 0.1}
    assert first["cost"] == pytest.approx(one.cost, rel=REACHED)
    assert sorted(line.split(" from ")[0] for line in lines) == [f"fit start {i}/3" for i in (1, 2, 3)]
    report = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert report["starts"]["reached_best"] == 3 and report["cost"] == best.cost
    assert "starts: 3; 3 reached the best cost" in best.table()
