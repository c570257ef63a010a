"""Run options: the Python API takes every option the command line takes, with the same
one-line errors, refuses an option its solver would ignore, and records the scene actually
run (options applied) in the result file's `scene` attribute."""

import subprocess
import sys
from pathlib import Path

import pytest

import dynfab
from dynfab.options import ALL_OPTIONS, apply_run_options
from dynfab.scene import parse_scene_text

ROOT = Path(__file__).resolve().parents[1]
ROD = """
[geometry]
length = 0.1
segments = 8
crossings = 0
amplitude = 0.0
[warp]
EA = 13.72
EI = 1.47e-7
kawabata_C = 0.2e-3
kawabata_K = 0.2
[load]
values = [0.01]
"""


def cli(*args):
    return subprocess.run([sys.executable, "-m", "dynfab.cli", *map(str, args)],
                          capture_output=True, text=True)


def test_every_cli_flag_is_an_api_option():
    from dynfab.cli import RUN_FLAGS

    assert {flag[2:].replace("-", "_") for flag in RUN_FLAGS} == set(ALL_OPTIONS)


def test_static_tolerance_reaches_the_file_scene(tmp_path):
    out = tmp_path / "rod.h5"
    dynfab.run(parse_scene_text(ROD), solver="static", out=out, tolerance=1e-6)
    recorded = parse_scene_text(dynfab.read_results(out).attrs["scene"])
    assert recorded.static.tolerance == 1e-6
    assert dynfab.read_results(out).attrs["static_tolerance"] == 1e-6


def test_dynamic_options_from_python_are_taken():
    scene = apply_run_options(parse_scene_text(ROD), "dynamic", method="semi_implicit",
                              tolerance=1e-9, max_steps=50)
    assert (scene.dynamic.method, scene.dynamic.tolerance, scene.dynamic.max_steps) == (
        "semi_implicit", 1e-9, 50)


@pytest.mark.parametrize("solver, options, words", [
    ("static", {"damping": "fire"}, "--damping fire: an option of the dynamic solver"),
    ("dynamic", {"max_iterations": 3}, "--max-iterations 3: an option of the static solver"),
    ("static", {"tolerence": 1e-6}, "did you mean 'tolerance'"),
    ("dynamic", {"method": "implicit"}, "dynamic.method"),
    ("newton", {}, "solver = 'newton'"),
])
def test_an_option_the_solver_does_not_take_is_a_scene_error(solver, options, words):
    with pytest.raises(dynfab.UserError, match=words.replace("(", r"\(").replace(".", r"\.")):
        dynfab.run(parse_scene_text(ROD), solver=solver, **options)


def test_cli_refuses_a_dynamic_flag_with_the_static_solver(tmp_path):
    scene = tmp_path / "rod.toml"
    scene.write_text(ROD)
    done = cli("run", scene, "--solver", "static", "--damping", "fire", "--out", tmp_path / "r.h5")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "dynfab: error: --damping fire: an option of the dynamic solver; the static solver does "
        "not use it (pass --solver dynamic, or drop it)"]
    assert not (tmp_path / "r.h5").exists()


def test_cli_refuses_a_device_for_the_static_solver(tmp_path):
    scene = tmp_path / "rod.toml"
    scene.write_text(ROD)
    done = cli("run", scene, "--device", "cuda", "--out", tmp_path / "r.h5")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "the static solver runs on the CPU" in done.stderr


def test_a_transient_scene_with_the_static_solver_is_refused_in_one_line(tmp_path):
    """runs/relax.toml asks for a transient ([dynamic] mode), which the default static solver
    would otherwise have run as one quasi-static load step, silently."""
    relax = Path(__file__).resolve().parent.parent / "runs" / "relax.toml"
    done = cli("run", relax, "--out", tmp_path / "r.h5")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines() == [
        'dynfab: error: dynamic.mode = "transient" integrates in time, which the static solver '
        "does not: run it with --solver dynamic (or remove the mode for a quasi-static run)"]
    assert not (tmp_path / "r.h5").exists()


def test_each_flag_takes_its_keys_type_and_names_their_units():
    """The flags are written from the scene keys: an option of both solvers has one kind,
    and its help gives each key's unit (so `--help` and docs/scene.md cannot disagree)."""
    from dynfab.cli import RUN_FLAGS
    from dynfab.scene import RUN_OPTIONS

    kinds = {"float": float, "int": int, "str": str}
    for flag, (kind, text) in RUN_FLAGS.items():
        name = flag[2:].replace("-", "_")
        specs = [options[name] for options in RUN_OPTIONS.values() if name in options]
        assert {kinds[spec.kind] for spec in specs} == {kind}, flag
        for spec in specs:
            assert not spec.unit or f"[{spec.unit}]" in text, flag
            assert all(choice in text for choice in spec.choices), flag
