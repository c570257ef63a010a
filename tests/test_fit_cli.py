"""`dynfab fit` on the command line: the example of runs/fit_example, outputs, exit statuses."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from dynfab.cli import main
from dynfab.scene import load_scene
from dynfab.fitting.sensitivity import solve_path

EXAMPLE = Path(__file__).resolve().parent.parent / "runs" / "fit_example"
NUMBER = re.compile(r"[-+]?\d+\.?\d*(?:e[-+]?\d+)?")


def assert_quoted(printed: str, readme: str) -> None:
    """Every line of a fit's printed table stands in the README, its words as printed and each
    number to within one unit of its last printed digit: a change below that digit (the
    linear algebra library's rounding, from one machine's packages to another's) may flip the
    digit a number is rounded to, and the quote stays the command's output."""
    quoted = readme.splitlines()
    for line in printed.splitlines():
        words = NUMBER.sub("#", line)
        same = [q for q in quoted if NUMBER.sub("#", q) == words]
        assert any(all(abs(float(a) - float(b)) <= 1.01 * _last_digit(a)
                       for a, b in zip(NUMBER.findall(line), NUMBER.findall(q))) for q in same), line


def _last_digit(number: str) -> float:
    """One unit of the last digit `number` was printed with (0.0599726: 1e-7; 4.994e-05: 1e-8);
    0 for an integer (a count is not rounded)."""
    if "." not in number and "e" not in number:
        return 0.0
    mantissa, _, exponent = number.partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (int(exponent or 0) - decimals)


def test_fit_example_writes_report_scene_and_figures(tmp_path, capsys):
    out = tmp_path / "fit"
    main(["fit", str(EXAMPLE / "scene.toml"), "--data", str(EXAMPLE / "curve.csv"),
          "--fit", "warp.EA,friction.alpha", "--out", str(out)])
    captured = capsys.readouterr()
    assert "warp.EA" in captured.out and "95 % interval" in captured.out
    progress = [line for line in captured.err.splitlines() if line.startswith("fit iteration")]
    report = json.loads((out / "fit.json").read_text())
    assert len(progress) >= report["iterations"] >= 1
    assert all("cost" in line and "step" in line and "friction.alpha" in line for line in progress)
    assert set(report) >= {"parameters", "correlation", "residual_rms", "dof", "iterations",
                           "identifiable", "warnings"}
    assert report["identifiable"] and report["dof"] == 8
    # the README quotes this command's output: each table line as printed here
    readme = (EXAMPLE.parent.parent / "README.md").read_text()
    assert "--fit warp.EA,friction.alpha --out fit_example" in readme
    assert_quoted(captured.out, readme)
    for name in ("fit_curve.png", "fit_correlation.png"):
        assert (out / name).stat().st_size > 0
    # the fitted scene runs as it is, and gives back the fitted curve
    fitted = load_scene(out / "fitted.toml")
    assert fitted.warp.EA == report["parameters"]["warp.EA"]["value"]
    main(["run", str(out / "fitted.toml"), "--out", str(tmp_path / "fitted.h5"), "--quiet"])
    assert (tmp_path / "fitted.h5").exists()


@pytest.mark.parametrize("args, words", [
    (["--fit", "geometry.segments"], "cannot be fitted"),
    (["--fit", "warp.EA", "--bounds", "warp.EA=20:30"], "start value"),
    (["--fit", "warp.EA", "--bounds", "warp.EA"], "KEY=LOWER:UPPER"),
    (["--fit", "warp.EA", "--substeps", "0"], "substeps"),
])
def test_bad_fit_options_exit_2_with_one_line(args, words, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["fit", str(EXAMPLE / "scene.toml"), "--data", str(EXAMPLE / "curve.csv"),
              "--out", "unused", *args])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dynfab: error:") and words in err[0]


def test_bad_curve_file_exits_2(tmp_path, capsys):
    curve = tmp_path / "curve.csv"
    curve.write_text("end_displacement [m],end_force [N]\n1e-3,0.1\n2e-3,nan\n")
    with pytest.raises(SystemExit) as exit_:
        main(["fit", str(EXAMPLE / "scene.toml"), "--data", str(curve), "--fit", "warp.EA",
              "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2
    assert "row 3" in capsys.readouterr().err


def test_example_curve_is_the_documented_one():
    """curve.csv comes from make_curve.py: EA = 13.72, alpha = 0.2 plus 0.2 % noise; the noise-free
    curve lies within 5 sigma of every point (a regenerated or edited file would show)."""
    import numpy as np
    from dynfab.results.measured_curve import read_curve
    from dynfab.scene import with_key

    data = read_curve(EXAMPLE / "curve.csv", "displacement")
    scene = with_key(with_key(load_scene(EXAMPLE / "scene.toml"), "warp.EA", 13.72),
                     "friction.alpha", 0.2)
    force = solve_path(with_key(scene, "load.values", list(data.load))).observables["end_force"]
    sigma = 2e-3 * np.abs(force).max()
    assert np.abs(force - data.measured["end_force"]).max() < 5 * sigma


def test_fabric_example_writes_report_scene_and_figures(tmp_path, capsys):
    """`dynfab fit` on the fabric example (runs/fit_example/fabric_scene.toml, a periodic 2 x 2
    cell; fabric_curve.csv): exits normally, writes the four files, says in fit.json and in a
    warning that its Jacobian is a finite difference; the fitted scene runs."""
    out = tmp_path / "fabric_fit"
    main(["fit", str(EXAMPLE / "fabric_scene.toml"), "--data", str(EXAMPLE / "fabric_curve.csv"),
          "--fit", "warp.EA,weft.EA", "--out", str(out)])
    captured = capsys.readouterr()
    assert "weft.EA" in captured.out and "95 % interval" in captured.out
    report = json.loads((out / "fit.json").read_text())
    assert report["jacobian"] == "finite-difference"
    assert report["warnings"][0].startswith("finite-difference Jacobian")
    assert report["identifiable"] and report["dof"] == 4 * 10 - 2
    progress = [line for line in captured.err.splitlines() if line.startswith("fit iteration")]
    assert len(progress) >= report["iterations"] >= 1
    # the README quotes this command's output: each table line as printed here
    readme = (EXAMPLE.parent.parent / "README.md").read_text()
    assert "--fit warp.EA,weft.EA --out fabric_fit" in readme
    assert_quoted(captured.out, readme)
    for name in ("fit_curve.png", "fit_correlation.png"):
        assert (out / name).stat().st_size > 0
    fitted = load_scene(out / "fitted.toml")
    assert fitted.weft.EA == report["parameters"]["weft.EA"]["value"]
    assert len(fitted.load.weft_values) == len(fitted.load.values)  # the refined path
    main(["run", str(out / "fitted.toml"), "--out", str(tmp_path / "fitted.h5"), "--quiet"])
    assert (tmp_path / "fitted.h5").exists()


def test_frame_example_fits_the_woven_in_contact(tmp_path, capsys):
    """`dynfab fit` on the shear example (runs/fit_example/frame_scene.toml, a 30 mm picture
    frame of the Cao fabric; frame_curve.csv made at crossing.preload = 0.06 N plus 0.2 %
    noise): it gets the preload back within its 95 % interval, and the README quotes its
    table as printed."""
    out = tmp_path / "frame_fit"
    main(["fit", str(EXAMPLE / "frame_scene.toml"), "--data", str(EXAMPLE / "frame_curve.csv"),
          "--fit", "crossing.preload", "--out", str(out)])
    captured = capsys.readouterr()
    report = json.loads((out / "fit.json").read_text())
    low, high = report["parameters"]["crossing.preload"]["ci95"]
    assert low <= 0.06 <= high and report["identifiable"]
    readme = (EXAMPLE.parent.parent / "README.md").read_text()
    assert "--fit crossing.preload --out frame_fit" in readme
    assert_quoted(captured.out, readme)
