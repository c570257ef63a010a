"""The line "compiling kernels (first run only)" (`dynfab.compiling`): said once, before a
compile that really happens (numba's or Warp's), and never when the caches hold the code.

Compiling dynfab's kernels from empty caches takes a minute or more, so these tests watch
tiny functions and kernels of their own: numba functions compiled here (not cached, or
cached in a folder of the test's), a Warp module looked up in an empty kernel cache (its
load replaced by a recorder, so nothing is compiled), and the command line's wiring with
a probe compiled inside a run.
"""

import importlib
import sys
import uuid
from pathlib import Path

import numba
import numpy as np
import pytest
import warp as wp

import dynfab.run  # noqa: F401 (the module, for sys.modules)
from dynfab import cli
from dynfab.compiling import MESSAGE, announcing, will_compile
from dynfab.kernels.structure_relaxation import StructureRelaxation
from dynfab.kernels.runtime import initialize
from dynfab.model.fabric.model import FabricModel
from dynfab.reports.fabric_data import paper_patch_scene

ROOT = Path(__file__).resolve().parents[1]
FIG5 = ROOT / "runs" / "paper_fig5.toml"
HERE = (__name__.split(".")[0],)
"""This module's package, for `announcing(packages=...)`: its numba functions count."""


def test_a_numba_compile_is_announced_once_before_it_runs():
    said, order = [], []

    def add(x):
        return x + 1

    def twice(x):
        return 2 * x

    with announcing(lambda text: (said.append(text), order.append("said")), packages=HERE):
        assert numba.njit(add)(1) == 2
        order.append("compiled")
        assert numba.njit(twice)(2) == 4  # a second compile: nothing more
    assert said == [MESSAGE] and order == ["said", "compiled"]


def test_a_numba_function_of_another_package_is_not_announced():
    """numba's own helpers compile in every process: announcing them would make "first run
    only" untrue, so only the given packages' functions count (dynfab's, by default)."""
    said = []
    with announcing(said.append, packages=("not_" + HERE[0],)):
        assert numba.njit(lambda x: x - 1)(1) == 0
    assert said == []


def test_a_numba_function_loaded_from_its_cache_is_not_announced(tmp_path, monkeypatch):
    """A `cache=True` function compiled by one import is loaded by the next one (a later
    process's) from its cache, without a compile: nothing is said."""
    name = f"probe_{uuid.uuid4().hex[:8]}"
    (tmp_path / f"{name}.py").write_text("import numba\n\n\n@numba.njit(cache=True)\n"
                                         "def add(x):\n    return x + 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    said = []
    for expected in ([MESSAGE], []):
        module = importlib.import_module(name)
        with announcing(said.append, packages=(name,)):
            assert module.add(1) == 2
        assert said == expected
        said.clear()
        del sys.modules[name]


@pytest.fixture
def warp_ready():
    initialize("cpu")
    return wp


def test_a_warp_module_missing_from_the_kernel_cache_is_announced_before_its_load(
        warp_ready, tmp_path, monkeypatch):
    """A module whose binary is not in Warp's kernel cache (here an empty one) will compile:
    the line comes before its load, once; Warp's load is given back after the block."""
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))

    @wp.kernel(module="unique")
    def halve(values: wp.array(dtype=float)):
        i = wp.tid()
        values[i] = 0.5 * values[i]

    assert will_compile(halve.module, "cpu") and will_compile(halve.module, "cpu", 1)
    events = []
    monkeypatch.setattr(wp.Module, "load", lambda module, device, block_dim=None, **more:
                        events.append(("load", module.name)))  # records; compiles nothing
    recorder = wp.Module.load
    with announcing(lambda text: events.append(("said", text))):
        halve.module.load("cpu")
        halve.module.load("cpu")
    assert events == [("said", MESSAGE), ("load", halve.module.name),
                      ("load", halve.module.name)]
    assert wp.Module.load is recorder


def test_a_loaded_warp_module_is_not_announced(warp_ready):
    """A kernel already compiled (launched before: loaded from the kernel cache, or compiled
    then) launches again without a word: the return map of a frictionless patch (the one-pass
    kernel the fabric tests build)."""
    scene = paper_patch_scene(2, 2, load={"values": [0.1]})
    structure = FabricModel.from_scene(scene).structure
    relaxation = StructureRelaxation(structure)
    anchors = relaxation.as_woven_anchors()
    before, _ = relaxation.return_map(structure.rest_position, anchors)
    said = []
    with announcing(said.append):
        again, _ = relaxation.return_map(structure.rest_position, anchors)
    assert said == []
    np.testing.assert_array_equal(again, before)


def probe():
    """A numba function of dynfab's, compiled fresh inside a run (no cache)."""

    def step(x):
        return x + 1

    step.__module__ = "dynfab.probe"
    return numba.njit(step)


@pytest.mark.parametrize("quiet", [False, True])
def test_the_run_command_says_it_before_the_compile_into_a_pipe(tmp_path, monkeypatch, capsys,
                                                                quiet):
    """`dynfab run` with stderr not a terminal (as captured here): the line comes before
    the step lines, once, as a line of its own; with --quiet nothing is written."""
    run_module = sys.modules["dynfab.run"]  # the module (`dynfab.run` is the function)
    real = run_module.run_to_file

    def compiling_run(*args, **kwargs):
        assert probe()(np.int64(1)) == 2
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "run_to_file", compiling_run)
    cli.main(["run", str(FIG5), "--out", str(tmp_path / "fig5.h5"),
              *(["--quiet"] if quiet else [])])
    lines = capsys.readouterr().err.splitlines()
    if quiet:
        assert lines == []
        return
    assert lines[0] == MESSAGE and lines.count(MESSAGE) == 1
    assert lines[1].startswith("[ 1/40]") and "\r" not in "".join(lines)


def test_the_compile_clock_times_a_real_compile_and_not_a_call():
    # a numba function compiled here (no cache): the clock grows by its compile, then not by
    # its calls
    import numba

    from dynfab.compiling import compile_seconds, start_clock

    start_clock()

    @numba.njit
    def square(x):
        return x * x

    before = compile_seconds()
    square(3.0)
    compiled = compile_seconds()
    assert compiled > before
    square(4.0)
    assert compile_seconds() == compiled


def test_the_summary_says_the_solver_time_and_the_compiling_apart():
    # "40 load steps, 67.6 s in the solver" for millisecond steps was the compiles': the
    # summary says the two apart (steps/compile_time, of steps/wall_time)
    from dynfab.results.summary import _solver_time

    steps = {"wall_time": np.array([30.2, 0.01, 0.02]),
             "compile_time": np.array([30.0, 0.0, 0.0])}
    assert _solver_time(steps) == "0.230 s in the solver and 30.0 s compiling kernels " \
                                  "(first run only)"
    assert _solver_time({"wall_time": np.array([0.5])}) == "0.500 s in the solver"


def test_a_run_records_what_each_step_spent_compiling(tmp_path):
    from dynfab import load_scene, run

    steps = run(load_scene(ROOT / "runs" / "paper_fig5.toml"), solver="static").steps
    assert steps["compile_time"].shape == steps["wall_time"].shape
    assert np.all(steps["compile_time"] >= 0.0)
    assert np.all(steps["compile_time"] <= steps["wall_time"])
