"""`dynfab run --solver dynamic`: transient frames survive kill -9 and resume exactly;
a divergence or a step limit exits with status 3 and one line, keeping the finished steps.
"""

import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np

import dynfab
from dynfab.results.file import finished_counts
from test_cli import dynfab_cli

ROOT = Path(__file__).resolve().parents[1]
RELAX = ROOT / "runs" / "relax.toml"

SMALL = '''
[geometry]
length = 0.025
segments = 56
crossings = 4
amplitude = 0.5e-3
reference = "prestressed"
[warp]
EA = 13.72
EI = 1.47e-7
kawabata_C = 0.2e-3
kawabata_K = 0.2
[weft]
EI = 1.47e-7
length = 0.1
count = 16
amplitude = 0.5e-3
kawabata_C = 0.2e-3
kawabata_K = 0.2
[load]
control = "force"
values = [0.3, 0.31, 0.0]
'''
"""A quarter paper yarn (same spacing, weft and contact law): loaded, then let go, which
takes the relaxation more time steps than the two loading steps."""


def frame_count(path: Path) -> int:
    """Finished frames in a result file being written (0 if it is not there yet)."""
    counts = finished_counts(path) if path.exists() else None
    return 0 if counts is None else counts[1]


def test_transient_resume_after_kill_equals_the_uninterrupted_run(tmp_path):
    full = tmp_path / "full.h5"
    done = dynfab_cli("run", RELAX, "--solver", "dynamic", "--out", full, "--quiet")
    assert done.returncode == 0, done.stderr
    expected = dynfab.read_results(full).frames
    out = tmp_path / "killed.h5"
    child = subprocess.Popen([sys.executable, "-m", "dynfab.cli", "run", str(RELAX), "--solver",
                              "dynamic", "--out", str(out), "--quiet"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while frame_count(out) < 30 and child.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    child.send_signal(signal.SIGKILL)
    child.wait()
    kept = frame_count(out)
    assert 30 <= kept < expected["time"].shape[0], "the kill must land mid-run"
    resumed = dynfab_cli("run", RELAX, "--solver", "dynamic", "--out", out, "--resume", "--quiet")
    assert resumed.returncode == 0, resumed.stderr
    frames = dynfab.read_results(out).frames
    for name, value in expected.items():  # the same steps from the same state: exact
        np.testing.assert_array_equal(frames[name], value, err_msg=name)


def test_divergence_exits_3_with_the_time_step_against_the_bound(tmp_path):
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL)
    out = tmp_path / "diverged.h5"
    # Physical masses: the bound is about 2 sqrt(m / k) ~ 7e-7 s; 1e-5 s is over 10 x it.
    done = dynfab_cli("run", scene, "--solver", "dynamic", "--masses", "physical", "--dt", "1e-5",
                      "--out", out, "--quiet")
    assert done.returncode == 3, done.stderr
    lines = done.stderr.strip().splitlines()
    assert "Traceback" not in done.stderr
    assert len(lines) == 2 and lines[0].startswith("dynfab: warning:")  # dt above the bound
    message = lines[1]
    assert message.startswith("dynfab: error:")
    assert "load step 1/3" in message and "diverged" in message and "stable dt" in message
    assert dynfab.read_results(out).step_count == 0


def test_step_limit_exits_3_and_keeps_the_finished_steps(tmp_path):
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL)
    out = tmp_path / "limited.h5"
    static = dynfab.run(dynfab.load_scene(scene), solver="static")
    needed = dynfab.run(dynfab.load_scene(scene), solver="dynamic").steps["time_steps"][:, 0]
    assert needed[2] > needed[:2].max(), "the scene must make the last step the longest"
    limit = (needed[:2].max() + needed[2]) // 2  # enough for steps 1-2, not for step 3
    done = dynfab_cli("run", scene, "--solver", "dynamic", "--max-steps", limit, "--out", out,
                      "--quiet")
    assert done.returncode == 3, done.stderr
    assert "load step 3/3" in done.stderr and "dynamic.max_steps" in done.stderr
    kept = dynfab.read_results(out)
    assert kept.step_count == 2
    # The kept steps are relaxed to 1e-8 N: their end displacement is the static one within
    # residual x ||K^-1|| (about 1e-8 N / 0.1 N/m here; test_dynamic_relaxation bounds it exactly).
    np.testing.assert_allclose(kept.steps["end_displacement"],
                               static.steps["end_displacement"][:2], atol=1e-6)


def test_given_dt_above_the_bound_is_allowed_with_a_one_line_warning(tmp_path):
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL.replace("values = [0.3, 0.31, 0.0]", "values = [0.3]"))
    from dynfab.solvers.dynamic import DynamicSolver
    from dynfab.model.yarn import initial_state
    from dynfab.model.builders import build_model
    from dynfab.scene import Dynamic

    model = build_model(dynfab.load_scene(scene))
    physical = DynamicSolver(model, Dynamic(masses="physical", damping="viscous"))
    bound = physical.predicted_stable_dt(initial_state(model), 0.3).min()
    # 1.02 x the bound: above it, yet (the bound being conservative, measured 1.04 x) stable.
    done = dynfab_cli("run", scene, "--solver", "dynamic", "--masses", "physical", "--damping",
                      "viscous", "--dt", 1.02 * bound, "--out", tmp_path / "a.h5", "--quiet")
    assert done.returncode == 0, done.stderr
    warning = [l for l in done.stderr.splitlines() if l.startswith("dynfab: warning:")]
    assert len(warning) == 1 and "above the predicted stable time step" in warning[0]


def test_a_device_that_is_not_there_is_one_line_and_exit_2(tmp_path):
    import warp as wp

    scene = tmp_path / "small.toml"
    scene.write_text(SMALL)
    # "cuda" is a user mistake only where this machine has no CUDA device.
    missing = ["foo"] + ([] if any(str(d).startswith("cuda") for d in wp.get_devices())
                         else ["cuda"])
    for device in missing:
        done = dynfab_cli("run", scene, "--solver", "dynamic", "--device", device, "--out",
                          tmp_path / "x.h5", "--quiet")
        assert done.returncode == 2, done.stderr
        assert "Traceback" not in done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("dynfab: error: --device"), done.stderr
        assert repr(device) in lines[0] and "available: cpu" in lines[0]


def test_semi_implicit_refuses_kinetic_and_fire_damping_in_one_line(tmp_path):
    scene = tmp_path / "small.toml"
    scene.write_text(SMALL)
    for damping in ("kinetic", "fire"):
        done = dynfab_cli("run", scene, "--solver", "dynamic", "--method", "semi_implicit",
                          "--damping", damping, "--out", tmp_path / "x.h5", "--quiet")
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(
            f'dynfab: error: dynamic.damping = "{damping}": not available with dynamic.method = '
            '"semi_implicit"'), done.stderr
