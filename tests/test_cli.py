"""The `dynfab` command: crash safety under kill -9, resume, the API, bad input.

A run killed at any moment must leave a readable file with every finished
step, and `--resume` must reproduce the uninterrupted run exactly: the static
solver is deterministic from the stored state (positions, anchors,
dissipation), so the comparison is exact, not within a tolerance.
"""

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

import dynfab

ROOT = Path(__file__).resolve().parents[1]
FIG5 = ROOT / "runs" / "paper_fig5.toml"  # friction on and off: anchors must survive a resume


def dynfab_cli(*args, **kwargs):
    """Run `python -m dynfab.cli ...` in a subprocess (the console script's code)."""
    return subprocess.run([sys.executable, "-m", "dynfab.cli", *map(str, args)],
                          capture_output=True, text=True, **kwargs)


def step_arrays(path) -> dict:
    """Every steps/* dataset but the wall time (which differs run to run)."""
    results = dynfab.read_results(path)
    return {k: v for k, v in results.steps.items() if k != "wall_time"}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    path = tmp_path_factory.mktemp("full") / "fig5.h5"
    done = dynfab_cli("run", FIG5, "--out", path, "--quiet")
    assert done.returncode == 0, done.stderr
    return path


def test_kill_minus_9_leaves_a_readable_file_and_resume_is_exact(uninterrupted, tmp_path):
    expected = step_arrays(uninterrupted)
    total = expected["load"].shape[0]
    rng = random.Random(20071)
    out = tmp_path / "killed.h5"
    for attempt in range(4):
        args = [sys.executable, "-m", "dynfab.cli", "run", str(FIG5), "--out", str(out), "--quiet",
                "--resume" if out.exists() else "--overwrite"]
        child = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.6, 1.6))
        child.send_signal(signal.SIGKILL)
        child.wait()
        if not out.exists():
            continue
        with h5py.File(out, "r") as f:  # readable, every dataset with the same step count
            counts = {f[f"steps/{name}"].shape[0] for name in ("load", "positions", "anchors")}
            assert len(counts) == 1
    finished = dynfab_cli("run", FIG5, "--out", out, "--quiet",
                          "--resume" if out.exists() else "--overwrite")
    assert finished.returncode == 0, finished.stderr
    resumed = step_arrays(out)
    assert resumed["load"].shape[0] == total
    for name, value in expected.items():
        np.testing.assert_array_equal(resumed[name], value, err_msg=name)


def test_python_api_returns_the_file_arrays(uninterrupted):
    results = dynfab.run(dynfab.load_scene(FIG5), solver="static")
    for name, value in step_arrays(uninterrupted).items():
        np.testing.assert_array_equal(results.steps[name], value, err_msg=name)


def test_summary_table_and_plots(tmp_path):
    out = tmp_path / "fig3.h5"
    done = dynfab_cli("run", ROOT / "runs" / "paper_fig3.toml", "--out", out)
    assert done.returncode == 0, done.stderr
    assert "max R [N]" in done.stdout and "[40/40]" in done.stderr
    plotted = dynfab_cli("plot", out, "--out", tmp_path / "plots")
    assert plotted.returncode == 0, plotted.stderr
    assert {p.name for p in (tmp_path / "plots").iterdir()} >= {"traction.png", "contact_force.png",
                                                                 "shape.png"}


BAD_SCENE = '''
[geometry]
length = 0.1
segments = 30
crossings = 4
amplitude = 0.5e-3
[warp]
EA = 13.72
EI = 1.47e-7
kawabata_C = 0.2e-3
kawabata_K = 0.2
[weft]
EI = 1.47e-7
amplitude = 0.5e-3
kawabata_C = 0.2e-3
kawabata_K = 0.2
[load]
values = [0.1]
'''


@pytest.mark.parametrize("case, text, needle", [
    ("missing", None, "not found"),
    ("not_toml", "[geometry\nlength = ", "TOML"),
    ("mesh", BAD_SCENE, "geometry.segments"),
    ("typo", BAD_SCENE.replace("segments = 30", "segments = 32").replace("EA =", "Ea ="), "warp.EA"),
])
def test_bad_input_is_one_line_and_exit_status_2(tmp_path, case, text, needle):
    scene = tmp_path / f"{case}.toml"
    if text is not None:
        scene.write_text(text)
    done = dynfab_cli("run", scene, "--out", tmp_path / "x.h5")
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and needle in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.h5").exists()


def test_existing_output_is_refused_and_untouched(tmp_path):
    out = tmp_path / "keep.h5"
    out.write_bytes(b"precious")
    done = dynfab_cli("run", FIG5, "--out", out)
    assert done.returncode == 2 and "--overwrite" in done.stderr
    assert out.read_bytes() == b"precious"


def test_result_file_stores_the_scene_actually_run(tmp_path):
    """The `scene` attribute parses back to the scene that ran, command-line overrides
    included, so a result file documents its own run; `scene_source` keeps the file."""
    out = tmp_path / "fig5.h5"
    done = dynfab_cli("run", FIG5, "--out", out, "--quiet", "--tolerance", "1e-10")
    assert done.returncode == 0, done.stderr
    attrs = dynfab.read_results(out).attrs
    ran = dynfab.parse_scene_text(attrs["scene"])
    assert ran.static.tolerance == 1e-10
    assert attrs["scene_source"] == FIG5.read_text()
    expected = dynfab.load_scene(FIG5)
    assert ran.load == expected.load and ran.sweep == expected.sweep
    assert ran.friction == expected.friction and ran.geometry == expected.geometry
    resumed = dynfab_cli("run", FIG5, "--out", out, "--quiet", "--resume")  # other tolerance
    assert resumed.returncode == 2 and "different scene" in resumed.stderr


def test_scene_to_toml_round_trips_every_scene_in_runs():
    from dataclasses import replace

    from dynfab.scene import scene_to_toml

    for path in sorted((ROOT / "runs").glob("*.toml")):
        scene = dynfab.load_scene(path)
        again = dynfab.parse_scene_text(scene_to_toml(scene))
        assert replace(again, text="") == replace(scene, text=""), path.name
