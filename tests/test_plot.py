"""Figures from a synthetic result file: which PNGs are written (real images), what each figure
draws (the file's data, read back from the matplotlib artists), and errors are UserErrors."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from matplotlib.image import imread

from dynfab.errors import UserError
from dynfab.results.friction_states import friction_states
from dynfab.plots.figures import (friction_yarns, plot_contact_force, plot_friction, plot_results,
                         plot_shape, plot_traction, shape_steps, yarn_labels)
from dynfab.results.file import ResultFile, read_results

LENGTH, SEGMENTS, AMPLITUDE = 0.01, 32, 1e-4


def write_synthetic(path: Path, *, yarns=2, steps=3, crossings=4, friction=True) -> Path:
    """A result file for sine-shaped yarns straightening under load, some crossings sliding."""
    x = np.linspace(0.0, LENGTH, SEGMENTS + 1)
    nodes = (np.arange(crossings) * 2 + 1) * SEGMENTS // (2 * crossings) if crossings else np.zeros(0, int)
    phase = np.array([(-1) ** k for k in range(yarns)])[:, None]
    z = AMPLITUDE * np.sin(np.pi * x / LENGTH * crossings) if crossings else 0 * x
    reference = np.stack([np.broadcast_to(x, (yarns, x.size)), phase * z], axis=-1)
    out = ResultFile.create(
        path,
        attrs={
            "scene": "title = 'synthetic'\n",
            "solver": "static",
            "load_control": "force",
            "projected_length": LENGTH,
            "width_per_yarn": 5e-4,
            "reference_state": "as_woven",
            "title": "synthetic",
            "yarn_labels": [f"warp.kawabata_K={0.02 * (k + 1):g}" for k in range(yarns)],
        },
        reference={"positions": reference, "crossing_nodes": nodes},
    )
    for n in range(steps):
        load = 0.5 * (n + 1) * np.ones(yarns)
        strain = 0.01 * (n + 1) * (1 + 0.2 * np.arange(yarns))
        positions = reference.copy()
        positions[..., 0] *= 1 + strain[:, None]
        positions[..., 1] *= 1 - 0.25 * (n + 1) / steps
        contact = np.outer(load, 1 + 0.1 * np.arange(crossings)) * 0.3
        if crossings and n == steps - 1:
            contact[:, 0] = 0.0  # the first crossing opens at the last step
        sliding = np.zeros((yarns, crossings), bool)
        sliding[:, crossings // 2 :] = n >= 1
        step = {
            "load": load,
            "end_force": load,
            "end_displacement": strain * LENGTH,
            "positions": positions,
            "energy/stretch": 1e-5 * (n + 1) * np.ones(yarns),
            "wall_time": 0.1,
        }
        if crossings:
            step |= {
                "contact_force": contact,
                "friction_limit": (0.3 if friction else 0.0) * contact,
                "friction_force": 0.2 * contact,
                "sliding": sliding,
            }
        out.append_step(step)
    return path


def assert_image(path: Path) -> None:
    """``path`` is a non-empty PNG of reasonable size that is not a single colour."""
    assert path.is_file() and path.stat().st_size > 0
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 500
    pixels = image.reshape(-1, image.shape[-1])
    assert np.ptp(pixels, axis=0).max() > 0.5, f"{path.name} is a single colour"


def test_all_figures(tmp_path):
    source = write_synthetic(tmp_path / "run.h5")
    written = plot_results(source, tmp_path / "figures")
    assert [p.name for p in written] == ["traction.png", "contact_force.png", "shape.png", "friction.png"]
    for path in written:
        assert path.parent == tmp_path / "figures"
        assert_image(path)


def test_traction_draws_each_yarns_force_against_strain_and_displacement(tmp_path):
    results = read_results(write_synthetic(tmp_path / "run.h5", yarns=2))
    left, right = plot_traction(results).axes
    force, displacement = results.steps["end_force"], results.steps["end_displacement"]
    for k, label in enumerate(yarn_labels(results)):
        strain_line, displacement_line = left.get_lines()[k], right.get_lines()[k]
        assert strain_line.get_label() == displacement_line.get_label() == label
        assert np.array_equal(strain_line.get_xdata(), 100 * displacement[:, k] / LENGTH)
        assert np.array_equal(strain_line.get_ydata(), force[:, k] / 5e-4)  # width_per_yarn
        assert np.array_equal(displacement_line.get_xdata(), 1e3 * displacement[:, k])
        assert np.array_equal(displacement_line.get_ydata(), force[:, k])


def test_contact_force_draws_the_largest_and_the_mean_over_the_crossings(tmp_path):
    results = read_results(write_synthetic(tmp_path / "run.h5", yarns=2))
    lines = plot_contact_force(results).axes[0].get_lines()
    contact = results.steps["contact_force"]
    for k in range(2):  # the last step opens crossing 0: the mean drops, the largest does not
        largest, mean = lines[2 * k], lines[2 * k + 1]
        assert np.array_equal(largest.get_xdata(), 1e3 * results.steps["end_displacement"][:, k])
        assert np.array_equal(largest.get_ydata(), contact[:, k].max(axis=1))
        assert np.array_equal(mean.get_ydata(), contact[:, k].mean(axis=1))
        assert largest.get_linestyle() == "-" and mean.get_linestyle() == "--"


def test_shape_draws_the_first_yarn_at_the_shape_steps_with_sliding_crossings_hollow(tmp_path):
    results = read_results(write_synthetic(tmp_path / "run.h5", steps=3))
    lines = plot_shape(results).axes[0].get_lines()
    positions, nodes = results.steps["positions"], results.reference["crossing_nodes"]
    sliding = results.steps["sliding"].astype(bool)
    assert np.array_equal(lines[0].get_ydata(), 1e3 * results.reference["positions"][0, :, 1])
    for n, step in enumerate(shape_steps(3)):  # a curve, its sticking dots, its sliding rings
        curve, solid, hollow = lines[1 + 3 * n: 4 + 3 * n]
        assert np.array_equal(curve.get_xdata(), 1e3 * positions[step, 0, :, 0])
        assert np.array_equal(curve.get_ydata(), 1e3 * positions[step, 0, :, 1])
        slide = sliding[step, 0]
        assert np.array_equal(solid.get_xdata(), 1e3 * positions[step, 0, nodes[~slide], 0])
        assert np.array_equal(hollow.get_xdata(), 1e3 * positions[step, 0, nodes[slide], 0])
        assert hollow.get_markerfacecolor() == "white"


def test_one_step(tmp_path):
    source = write_synthetic(tmp_path / "one.h5", steps=1)
    written = plot_results(str(source), str(tmp_path))
    assert {p.name for p in written} == {"traction.png", "contact_force.png", "shape.png", "friction.png"}
    for path in written:
        assert_image(path)


def test_plain_rod_skips_contact_and_friction(tmp_path):
    source = write_synthetic(tmp_path / "rod.h5", yarns=1, crossings=0)
    written = plot_results(source, tmp_path)
    assert [p.name for p in written] == ["traction.png", "shape.png"]
    for path in written:
        assert_image(path)


def test_no_friction_figure_without_friction(tmp_path):
    source = write_synthetic(tmp_path / "smooth.h5", friction=False)
    names = [p.name for p in plot_results(source, tmp_path)]
    assert names == ["traction.png", "contact_force.png", "shape.png"]


def test_friction_states_are_open_sticking_sliding(tmp_path):
    states = friction_states(read_results(write_synthetic(tmp_path / "run.h5")))
    np.testing.assert_array_equal(states, [[1, 1, 1, 1], [1, 1, 2, 2], [0, 1, 2, 2]])


def test_shape_steps():
    assert shape_steps(1) == [0]
    assert shape_steps(3) == [0, 1, 2]
    assert shape_steps(10) == [0, 3, 6, 9]


def test_missing_or_foreign_file_is_a_scene_error(tmp_path):
    with pytest.raises(UserError, match="does not exist"):
        plot_results(tmp_path / "missing.h5", tmp_path)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as h5:
        h5["x"] = np.arange(3)
    with pytest.raises(UserError, match="not a dynfab result"):
        plot_results(foreign, tmp_path)
    empty = tmp_path / "empty.h5"
    write_synthetic(empty, steps=0)
    with pytest.raises(UserError, match="no finished load step"):
        plot_results(empty, tmp_path)
    assert not list(tmp_path.glob("*.png"))


def test_a_file_of_a_model_this_dynfab_does_not_know_is_one_line(tmp_path):
    # a file from a newer dynfab (another kind of model): the figures and the summary are
    # chosen by the file's kind (`figures.KINDS`, `summary.KINDS`), and say so in one line
    from dynfab.results.summary import print_summary

    path = write_synthetic(tmp_path / "run.h5")
    with h5py.File(path, "r+") as h5:
        h5.attrs["model"] = "knit"
    for show in (lambda: plot_results(path, tmp_path), lambda: print_summary(read_results(path))):
        with pytest.raises(UserError, match="'knit'") as error:
            show()
        assert "\n" not in str(error.value)
    assert not list(tmp_path.glob("*.png"))


def test_friction_figure_has_a_panel_per_friction_yarn_numbered_from_1(tmp_path):
    """A sweep over friction shows every yarn with friction (not only the first), and the
    crossings are numbered 1..count as in messages and reports."""
    results = read_results(write_synthetic(tmp_path / "run.h5", yarns=3))
    fig = plot_friction(results)
    axes = [ax for ax in fig.axes if ax.images]
    assert [ax.get_title() for ax in axes] == yarn_labels(results)
    for k, ax in enumerate(axes):
        image = ax.images[0]
        assert image.get_extent()[2:] == [0.5, 4.5]  # rows 1..4, centred on the integers
        np.testing.assert_array_equal(image.get_array(), friction_states(results, k).T)


def test_a_yarn_without_friction_gets_no_panel(tmp_path):
    path = write_synthetic(tmp_path / "run.h5", yarns=2)
    with h5py.File(path, "r+") as h5:
        limit = h5["steps/friction_limit"][...]
        limit[:, 0] = 0.0
        h5["steps/friction_limit"][...] = limit
    assert friction_yarns(read_results(path)) == [1]


def test_a_fabric_file_draws_loads_per_width_from_the_origin_and_its_shape(tmp_path):
    """`dynfab plot` on a fabric (docs/model.md section 10), the balanced cell at 1:1 whose
    families coincide: fabric.png draws each family's `steps/stress` [N/m] against its strain
    and its crimp against the larger of the two loads, from the as-woven state (0, 0), in
    line styles and markers of their own, so both stay visible; shape.png draws the
    deformed cell as the `dynfab fabric` report does, from the file's positions."""
    from dynfab.model.geometry import crimp
    from dynfab.plots.figures import plot_fabric, plot_fabric_shape
    from dynfab.run import run_to_file
    from dynfab.scene import load_scene

    path = tmp_path / "cell.h5"
    run_to_file(load_scene(Path(__file__).resolve().parents[1] / "runs" / "fabric_biaxial.toml"),
                "static", path)
    assert [p.name for p in plot_results(path, tmp_path / "plots")] == ["fabric.png", "shape.png"]
    results = read_results(path)
    steps = results.steps
    traction, crimp_ax = plot_fabric(results).axes[:2]
    lines = traction.get_lines()
    assert [line.get_label() for line in lines] == ["warps (mean of the loaded)",
                                                    "wefts (mean of the loaded)"]
    assert lines[0].get_linestyle() != lines[1].get_linestyle()
    assert lines[0].get_marker() != lines[1].get_marker()
    woven = [crimp(results.reference[name]).mean() for name in ("positions", "weft_positions")]
    for column, (line, crimp_line) in enumerate(zip(lines, crimp_ax.get_lines())):
        np.testing.assert_array_equal(line.get_xdata(),
                                      100 * np.append(0, steps["strain"][:, column]))
        np.testing.assert_array_equal(line.get_ydata(), np.append(0, steps["stress"][:, column]))
        np.testing.assert_array_equal(crimp_line.get_xdata(),
                                      np.append(0, steps["stress"].max(axis=1)))
        np.testing.assert_array_equal(crimp_line.get_ydata(),
                                      100 * np.append(woven[column], steps["crimp"][:, column]))
    np.testing.assert_array_equal(steps["stress"], steps["load"] / results.attrs["width_per_yarn"])
    shape = plot_fabric_shape(results)
    for step in shape_steps(results.step_count):
        for family, nodes in (("warp", steps["positions"][step, 0]),
                              ("weft", steps["weft_positions"][step, 0])):
            drawn = [line for ax in shape.axes for line in ax.get_lines()
                     if line.get_gid() == f"step {step + 1} {family} shape"]
            assert len(drawn) == 1
            np.testing.assert_array_equal(drawn[0].get_xydata(), 1e3 * nodes)


def specimen_file(tmp_path, specimen: str, values, name: str):
    """A specimen's result file: the 60 mm test scene (tests/test_shear_specimens.py) with
    `specimen` and the load path `values` [m]."""
    from dynfab import run
    from dynfab.scene import parse_scene_text
    from test_shear_specimens import scene_text

    out = tmp_path / f"{name}.h5"
    run(parse_scene_text(scene_text(specimen, values)), solver="static", out=out)
    return read_results(out)


def test_a_frame_force_is_drawn_linearly_from_the_origin_and_its_wall_apart(tmp_path):
    """The 22 mm frame sheared past its yarns' meeting (35.8 degrees at d = 7.8 mm) on the
    linear lateral contact: the force past it rises a hundredfold. The force and the normalised
    force are drawn on linear axes from 0, cut at 1.5 x the largest before the meeting (the
    points past it apart, a note saying where the last lies); the whole path on a fourth,
    logarithmic panel; the meeting marked on the angle axis."""
    from test_shear_specimens import FRAME

    from dynfab.plots.specimen import CLIP_HEAD, plot_shear_force
    results = specimen_file(tmp_path, FRAME.replace("side = 0.06", "side = 0.022"),
                            [2e-3, 5e-3, 7.5e-3, 8.5e-3, 9.2e-3], "frame")
    force = results.steps["clamp_force"]
    fig = plot_shear_force(results)
    by_d, by_angle, _, whole = fig.axes[:4]
    before = force[:4]  # d <= 7.5 mm: below the meeting
    assert force[-1] > 5 * before.max()  # the wall the panels are cut for
    for ax in (by_d, by_angle):
        assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0.0
        labels = ax.get_legend_handles_labels()[1]
        assert "past the yarns' meeting" in labels
        assert any(t.get_text().startswith("cut: ") for t in ax.texts)
    assert by_d.get_ylim()[1] == pytest.approx(CLIP_HEAD * before.max())
    assert "yarns meet (35.8 deg)" in by_angle.get_legend_handles_labels()[1]
    assert whole.get_yscale() == "log" and whole.get_title() == "the whole path"


def test_a_bias_force_names_its_step_0_and_is_drawn_from_it_too(tmp_path):
    """The bias curve starts at the relaxed woven state's reaction on the clamps (docs/model.md
    section 11.7): step 0's point says so, and the force less step 0's (a load cell zeroed at
    the start) is drawn beside it and recorded (steps/clamp_force_from_step_0)."""
    from test_shear_specimens import BIAS

    from dynfab.plots.specimen import plot_shear_force
    results = specimen_file(tmp_path, BIAS, [1e-3, 2e-3], "bias")
    steps = results.steps
    np.testing.assert_allclose(steps["clamp_force_from_step_0"],
                               steps["clamp_force"] - steps["clamp_force"][0], rtol=0, atol=0)
    by_d = plot_shear_force(results).axes[0]
    assert "from step 0 (load cell zeroed)" in by_d.get_legend_handles_labels()[1]
    assert any(t.get_text().startswith("step 0: the woven state's reaction") for t in by_d.texts)
    assert by_d.get_ylim()[0] == 0.0 and len(results.steps["load"]) == 3

def test_plot_data_draws_a_measured_curve_over_the_computed_one(tmp_path):
    """`dynfab plot FILE --data CURVE.csv`: the curve read with the columns `dynfab fit --data`
    takes for the file's scene (a shear specimen: clamp_force [N] against end_displacement
    [m]), drawn over the computed force against d, its legend the file's name."""
    from test_shear_specimens import FRAME

    from dynfab.cli import main
    specimen_file(tmp_path, FRAME.replace("side = 0.06", "side = 0.022"), [1e-3, 2e-3], "frame")
    curve = tmp_path / "lab_curve.csv"
    curve.write_text("end_displacement [m],clamp_force [N]\n0.001,0.05\n0.002,0.07\n")
    main(["plot", str(tmp_path / "frame.h5"), "--out", str(tmp_path / "figures"), "--data",
          str(curve)])
    from dynfab.plots.measured import measured_points
    from dynfab.plots.specimen import plot_shear_force
    results = read_results(tmp_path / "frame.h5")
    by_d = plot_shear_force(results, measured_points(results, curve)).axes[0]
    drawn = [line for line in by_d.get_lines() if line.get_label() == "measured: lab_curve"]
    assert len(drawn) == 1
    np.testing.assert_allclose(drawn[0].get_xydata(), [[1.0, 0.05], [2.0, 0.07]])
    assert "measured: lab_curve" in by_d.get_legend_handles_labels()[1]
    assert (tmp_path / "figures" / "shear_force.png").exists()


def test_plot_data_with_the_wrong_columns_names_those_expected_and_found(tmp_path, capsys):
    from test_shear_specimens import FRAME

    from dynfab.cli import main
    specimen_file(tmp_path, FRAME.replace("side = 0.06", "side = 0.022"), [1e-3], "frame")
    curve = tmp_path / "curve.csv"
    curve.write_text("end_displacement [m],end_force [N]\n0.001,0.05\n")
    with pytest.raises(SystemExit) as stop:
        main(["plot", str(tmp_path / "frame.h5"), "--out", str(tmp_path / "f"), "--data",
              str(curve)])
    assert stop.value.code == 2
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and "clamp_force" in line and "end_force" in line


def synthetic_study_table():
    """A 2 x 2 grid study's table (dynfab.studies.table's layout): keys a [m] and b (no
    units), a per-family path observable `strain` (warp, weft) and its last-step value."""
    import xarray as xr
    a, b = np.repeat([1.0, 2.0], 2), np.tile([0.1, 0.2], 2)
    steps = np.arange(1, 4) / 3.0
    strain = a[:, None, None] * steps[None, :, None] * np.array([1.0, 0.5]) + b[:, None, None]
    return xr.Dataset(
        {"strain": (("case", "step", "strain_1"), strain,
                    {"units": "-", "at": "path", "dataset": "steps/strain"}),
         "final": (("case", "final_1"), strain[:, -1],
                   {"units": "-", "at": "last", "dataset": "steps/strain"}),
         "load": (("case", "step"), np.tile(steps, (4, 1)), {"units": "N"}),
         "status": (("case",), np.array(["finished"] * 4)),
         "steps_done": (("case",), np.full(4, 3))},
        coords={"case": np.arange(4), "a": ("case", a, {"units": "m"}), "b": ("case", b)},
        attrs={"parameters": "a\nb", "design": "grid", "title": "synthetic"})


def test_a_study_figure_names_every_line_in_its_legend_in_its_colour_with_units():
    """Every line in the legend (the dashed components were not), a group's components in
    the legend's colour, a style entry per component (warp, weft), units on every axis
    label (a key without units says [-])."""
    from dynfab.studies.plots import _against_keys, _along_path, _per_case
    table = synthetic_study_table()
    fig = _against_keys(table, ["a", "b"], "final", table["final"],
                        _per_case(table, table["final"]))
    for ax in fig.axes:
        handles, labels = ax.get_legend_handles_labels()
        shown = ax.get_legend().legend_handles
        texts = [t.get_text() for t in ax.get_legend().get_texts()]
        assert "warp" in texts and "weft" in texts  # the line styles say whose
        groups = [line for line in ax.get_lines() if line.get_label() in labels]
        for line in ax.get_lines():  # a dashed line shares its group's labelled colour
            assert line.get_color() in {g.get_color() for g in groups}
        for handle, text in zip(shown, texts):
            if text in labels:
                match = [g for g in groups if g.get_label() == text][0]
                assert handle.get_color() == match.get_color()
        assert ax.get_xlabel().endswith("]") and ax.get_ylabel().endswith("[-]")
    assert fig.axes[1].get_xlabel() == "b [-]" and fig.axes[0].get_xlabel() == "a [m]"
    path = _along_path(table, ["a", "b"], "strain", table["strain"]).axes[0]
    assert path.get_xlabel() == "load [N]" and path.get_ylabel() == "strain [-]"
    assert [t.get_text() for t in path.get_legend().get_texts()] == ["warp", "weft"]
