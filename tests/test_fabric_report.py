"""The fabric report (`dynfab fabric --quick`): the physics its figures show, read back from
``fabric.json`` and from the lines the figures drew.

The cell is balanced (the same yarn both ways) and frictionless, so:
- at equal loads warp and weft respond alike, and the 2:1 and 1:2 paths are each other's
  mirror (docs/model.md section 10: the map (x, y, z) -> (y, x, -z)), to the solver's error bound;
- each step is a stable equilibrium of a conservative system under dead loads, so along a
  proportional path the work-conjugate stretch r_wa eps_wa + r_we eps_we increases with the
  load (a positive-definite stiffness has a positive-definite compliance);
- crimp interchange: pulling the warp (weft nearly free) straightens it and pushes the
  weft's crimp above its as-woven value.
"""

import json

import numpy as np
import pytest

from dynfab.cli import main
from dynfab.reports.fabric_data import PAPER_YARN, PATHS, QUICK, SPACING, YARNS
from dynfab.reports.fabric_plots import plot_biaxial, plot_crimp


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("fabric")
    main(["fabric", "--quick", "--quiet", "--out", str(out)])
    for name in ("fabric_biaxial.png", "fabric_crimp.png", "fabric_cell.png", "fabric.md"):
        assert (out / name).stat().st_size > 0
    return json.loads((out / "fabric.json").read_text())


def series(data, path, name):
    return np.asarray(data["paths"][path][name], float)


def strain_bound(data, path):
    """A strain's error bound [%]: the step's bound on the end position over the cell length."""
    return 100 * series(data, path, "position_bound_m") / data["cell"]["length_m"]


def test_equal_loads_give_equal_strains_and_crimps(data):
    bound = 2 * strain_bound(data, "1:1")  # two end positions, each within its bound
    warp = series(data, "1:1", "warp_strain_percent")
    weft = series(data, "1:1", "weft_strain_percent")
    assert np.all(np.abs(warp - weft) <= bound)
    assert warp[-1] > 1.0  # a real stretch, not two zeros
    # crimp: each of N segments' lengths moves by at most 2 sqrt(2) b with its two nodes
    # within b, the projected length by b; over the cell length, for each family
    segments = YARNS * QUICK.segments_per_crossing
    crimp_bound = 2 * (2 * np.sqrt(2) * segments + 1) * strain_bound(data, "1:1")
    crimp_gap = (series(data, "1:1", "warp_crimp_percent")
                 - series(data, "1:1", "weft_crimp_percent"))
    assert np.all(np.abs(crimp_gap) <= crimp_bound)


def test_mirror_paths_swap_warp_and_weft(data):
    bound = strain_bound(data, "2:1") + strain_bound(data, "1:2")
    for family, other in (("warp", "weft"), ("weft", "warp")):
        assert np.array_equal(series(data, "2:1", f"{family}_load_N_per_m"),
                              series(data, "1:2", f"{other}_load_N_per_m"))
        gap = series(data, "2:1", f"{family}_strain_percent") - series(
            data, "1:2", f"{other}_strain_percent")
        assert np.all(np.abs(gap) <= bound)


def test_every_step_is_stable_and_the_path_stretch_increases(data):
    for name, (r_warp, r_weft) in PATHS.items():
        assert all(data["paths"][name]["stable"])
        stretch = (r_warp * series(data, name, "warp_strain_percent")
                   + r_weft * series(data, name, "weft_strain_percent"))
        assert np.all(np.diff(stretch) > 0), name
    # under equal loads the stretch is twice each strain: both curves rise
    assert np.all(np.diff(series(data, "1:1", "warp_strain_percent")) > 0)


def test_crimp_interchange_near_uniaxial(data):
    warp, weft = (series(data, "1:0.05", f"{f}_crimp_percent") for f in ("warp", "weft"))
    assert np.all(np.diff(warp) < 0)  # the loaded family straightens
    assert np.all(weft[1:] > weft[0])  # the other takes the crimp it gives up
    assert warp[-1] < 0.1 * warp[0]


def test_lateral_tension_resists_the_warp(data):
    # Maxwell reciprocity of the conservative cell (equal lengths and widths):
    # d eps_wa / d P_we = d eps_we / d P_wa, and pulling the warp shortens the weft (the
    # crimp interchange), so at a given warp load less weft load leaves more warp strain.
    # The three paths share their warp loads step by step.
    loads = [series(data, n, "warp_load_N_per_m") for n in ("1:0.05", "2:1", "1:1")]
    assert np.array_equal(loads[0], loads[1]) and np.array_equal(loads[1], loads[2])
    strains = [series(data, n, "warp_strain_percent")[1:] for n in ("1:0.05", "2:1", "1:1")]
    assert np.all(strains[0] > strains[1]) and np.all(strains[1] > strains[2])


def test_as_woven_crimp_is_the_sine_polyline(data):
    # the first point of every crimp curve: the as-woven chain (docs/model.md section 10), computed
    # here from its formula, z = A sin(n pi x / L) at x_i = i L / N
    n, per = YARNS, QUICK.segments_per_crossing
    length = n * SPACING
    x = np.linspace(0.0, length, n * per + 1)
    z = PAPER_YARN["amplitude"] * np.sin(n * np.pi * x / length)
    crimp = 100 * (np.hypot(np.diff(x), np.diff(z)).sum() - length) / length
    for name in PATHS:
        for family in ("warp", "weft"):
            first = series(data, name, f"{family}_crimp_percent")[0]
            assert first == pytest.approx(crimp, rel=1e-12)


def test_side_views_span_the_stretched_cell(data):
    # each side view's yarn spans the cell: the end node minus node 0 is L (1 + strain)
    length = data["cell"]["length_m"]
    for name, path in data["paths"].items():
        for family in ("warp", "weft"):
            nodes = np.asarray(path["last"][family])
            strain = series(data, name, f"{family}_strain_percent")[-1] / 100
            assert nodes[-1, 0] - nodes[0, 0] == pytest.approx(length * (1 + strain), rel=1e-12)


def test_figures_draw_the_data(data):
    for fig, ordinate in ((plot_biaxial(data), None), (plot_crimp(data), "crimp")):
        lines = {line.get_gid(): line for ax in fig.axes for line in ax.get_lines()
                 if line.get_gid()}
        for name in PATHS:
            for family in ("warp", "weft"):
                line = lines[f"{name} {family}"]
                if ordinate is None:
                    assert np.array_equal(line.get_xdata(),
                                          series(data, name, f"{family}_strain_percent"))
                    assert np.array_equal(line.get_ydata(),
                                          series(data, name, f"{family}_load_N_per_m"))
                else:
                    assert np.array_equal(line.get_ydata(),
                                          series(data, name, f"{family}_crimp_percent"))
