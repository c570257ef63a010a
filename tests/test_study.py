"""dynfab study (dynfab/study*.py): the study file's checks, the cases it makes, the gathered
table against serial runs, failed cases, interrupts and --resume, the folder's lock.

The cases are a quarter paper yarn (56 segments, 4 crossings) on a short force path: a few
ms a step, so that a study's cost is the local cluster's start (a few seconds). Every
comparison with a serial run is exact: a case runs the same code on the same scene text in
another process, and the table holds the files' float64 values unchanged.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import xarray as xr

import dynfab
from dynfab.errors import UserError
from dynfab.results.file import MACHINE_TIMES, finished_counts, read_results
from dynfab.studies.study import StudyFolder, study
from dynfab.studies.file import load_position, load_study, parse_study_text

BASE = '''
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
max = 0.3
steps = 4
'''
"""The base scene: a quarter paper yarn pulled to 0.3 N in 4 steps of 0.075 N."""

OBSERVE = '''
[observe]
stretch = "end_displacement"
final = { dataset = "end_displacement", at = "last" }
between = { dataset = "end_force", at = 0.1 }
on_step = { dataset = "end_displacement", at = 0.15 }
'''
"""Every kind of observable: the path, the last step, between two steps (0.1 N lies between
0.075 and 0.15), on a step (0.15 N is step 2)."""


def write_study(folder: Path, vary: str, extra: str = "", observe: str = OBSERVE) -> Path:
    (folder / "base.toml").write_text(BASE)
    path = folder / "study.toml"
    path.write_text(f'title = "test"\nscene = "base.toml"\n{extra}\n[vary]\n{vary}\n{observe}')
    return path


def serial(plan):
    """Each case run in this process, as `dynfab run` would (the serial reference; it also
    compiles the kernels once, into numba's cache, which the workers then load)."""
    return [dynfab.run(case.scene) for case in plan.cases]


# --------------------------------------------------------------------------
# The study file.


def test_a_grid_is_every_combination_the_last_key_fastest(tmp_path):
    plan = load_study(write_study(tmp_path, '"warp.EA" = [10, 12]\n"weft.kawabata_K" = [0.1, 0.2, 0.3]'))
    assert [case.values for case in plan.cases] == [
        (10, 0.1), (10, 0.2), (10, 0.3), (12, 0.1), (12, 0.2), (12, 0.3)]
    assert plan.cases[4].scene.warp.EA == 12 and plan.cases[4].scene.weft.kawabata_K == 0.2
    assert plan.parameter_units() == {"warp.EA": "N", "weft.kawabata_K": "m/N"}


def test_a_key_the_base_leaves_out_is_written_in_and_its_derived_defaults_follow(tmp_path):
    """weft.length defaults to geometry.length when the file leaves it out: a case's scene
    is the base file with the key written in, parsed as such a file would be."""
    (tmp_path / "base.toml").write_text(BASE.replace("length = 0.1\n", ""))
    path = tmp_path / "study.toml"
    path.write_text('scene = "base.toml"\n[vary]\n"geometry.length" = [0.025, 0.05]\n'
                    '"geometry.segments" = [112]\n[observe]\nx = "end_force"\n')
    plan = load_study(path)
    assert [case.scene.weft.length for case in plan.cases] == [0.025, 0.05]
    assert plan.cases[1].scene.geometry.segments == 112


def test_a_latin_hypercube_puts_one_case_in_each_stratum_of_every_range(tmp_path):
    count = 7
    base = BASE + "[friction]\nalpha = 0.2\nbeta = 1e3\ncontact_length = 2e-3\nfiber_radius = 1e-3\n"
    (tmp_path / "base.toml").write_text(base)
    text = (f'scene = "base.toml"\ndesign = "latin_hypercube"\ncount = {count}\nseed = 3\n'
            '[vary]\n"warp.EA" = [10, 20]\n"friction.alpha" = [0.1, 0.4]\n'
            '[observe]\nx = "end_force"\n')
    plan = parse_study_text(text, folder=tmp_path)
    values = np.array([case.values for case in plan.cases])
    for column, (low, high) in zip(values.T, [(10, 20), (0.1, 0.4)]):
        strata = np.floor((column - low) / (high - low) * count).astype(int)
        assert sorted(strata) == list(range(count))  # the Latin hypercube's property
    assert [case.scene.friction.alpha for case in plan.cases] == list(values[:, 1])
    again = parse_study_text(text, folder=tmp_path)
    assert [c.values for c in again.cases] == [c.values for c in plan.cases]  # seeded


@pytest.mark.parametrize("vary, extra, observe, words", [
    ('"warp.EAX" = [1, 2]', "", OBSERVE, "unknown key 'warp.EAX'"),
    ('"wrap.EA" = [1, 2]', "", OBSERVE, 'vary."wrap.EA": not a scene key'),
    ('"warp.EA" = [1, -2]', "", OBSERVE, "the case warp.EA = -2: warp.EA = -2: must be a positive"),
    ('"warp.EA" = []', "", OBSERVE, "non-empty list"),
    ('"warp.EA" = [10, 5]', 'design = "latin_hypercube"\ncount = 4', OBSERVE,
     "lower < upper"),
    ('"geometry.segments" = [56, 112]', 'design = "latin_hypercube"\ncount = 4', OBSERVE,
     "samples real values"),
    ('"warp.EA" = [10, 15]', 'design = "latin_hypercube"', OBSERVE, "needs the number of cases"),
    ('"warp.EA" = [10, 15]', "count = 3", OBSERVE, 'only design = "latin_hypercube"'),
    ('"warp.EA" = [10]', "", '[observe]\nx = "clamp_torque"', "dataset 'clamp_torque' is not"),
    ('"warp.EA" = [10]', "", '[observe]\nx = { dataset = "end_force", at = 0.5 }',
     "does not pass it"),
    ('"warp.EA" = [10]', "", '[observe]\nx = { dataset = "end_force", at = 0.05 }',
     "does not pass it"),
    ('"warp.EA" = [10]', "", "", "[observe]: name at least one"),
    ('"warp.EA" = [10]', 'solver = "newton"', OBSERVE, 'solver = "newton": must be one of'),
])
def test_a_bad_study_is_one_line_before_anything_runs(tmp_path, vary, extra, observe, words):
    with pytest.raises(UserError) as error:
        load_study(write_study(tmp_path, vary, extra, observe))
    assert words in str(error.value) and "\n" not in str(error.value)


def test_every_study_file_in_runs_is_a_valid_study():
    """runs/study_*.toml are study files; the other runs/*.toml are scenes (test_scene.py)."""
    found = sorted((Path(__file__).resolve().parents[1] / "runs").glob("study_*.toml"))
    assert found
    for path in found:
        assert load_study(path).cases


def test_dynfab_study_refuses_a_bad_key_with_exit_2_and_writes_nothing(tmp_path):
    path = write_study(tmp_path, '"warp.EAX" = [1, 2]')
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "study", str(path), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "unknown key 'warp.EAX'" in done.stderr and not (tmp_path / "out").exists()


def test_load_position_finds_the_first_pass_and_is_exact_on_a_step():
    path = np.array([0.1, 0.2, 0.3, 0.2])
    assert load_position(path, 0.1) == (0, 1.0)
    assert load_position(path, 0.3) == (2, 1.0)
    assert load_position(path, 0.25) == (2, pytest.approx(0.5))
    assert load_position(path, 0.05) is None and load_position(path, 0.4) is None


# --------------------------------------------------------------------------
# Running: the table against serial runs, failures, the folder.


def expected_table(plan, runs):
    """The observables of OBSERVE from serial runs, computed here from the datasets."""
    stretch = np.stack([r.steps["end_displacement"] for r in runs])
    force = np.stack([r.steps["end_force"] for r in runs])
    # 0.1 N between step 1 (0.075 N) and step 2 (0.15 N): linear in the load path.
    weight = (0.1 - 0.075) / (0.15 - 0.075)
    return {"stretch": stretch, "final": stretch[:, -1],
            "between": (1 - weight) * force[:, 0] + weight * force[:, 1],
            "on_step": stretch[:, 1]}


def test_a_study_gathers_exactly_the_serial_runs_and_records_a_failed_case(tmp_path):
    """sync "end": files that come back whole. static.max_iterations = 1 fails at step 1
    (Newton needs several iterations): recorded with its message, the study goes on."""
    plan = load_study(write_study(tmp_path, '"warp.EA" = [10, 13.72]\n'
                                            '"static.max_iterations" = [200, 1]'))
    good = [case for case in plan.cases if case.scene.static.max_iterations == 200]
    reference = {case.index: dynfab.run(case.scene) for case in good}
    failures, lines = [], []
    result = study(plan, tmp_path / "out", workers=2, sync="end", progress=failures.append,
                   status=lines.append)
    live = [line for line in lines if line]  # "" clears the line at the end
    pattern = (r"cases: \d finished, \d failed, \d running, \d waiting of 4; "
               r"(about \d+(\.\d)? (s|min|h) left|time left: unknown yet)")
    assert live and all(re.fullmatch(pattern, line) for line in live), live
    assert live[-1].startswith("cases: 2 finished, 2 failed, 0 running, 0 waiting of 4")
    assert (result.cases, result.finished, result.failed) == (4, 2, 2)
    assert len(failures) == 2 and all("no convergence in 1 Newton" in f for f in failures)
    table = xr.open_dataset(result.table)
    expected = expected_table(plan, list(reference.values()))
    for name, values in expected.items():
        got = table[name].values[[0, 2]]  # cases 0 and 2 ran max_iterations = 200
        assert np.array_equal(got.reshape(values.shape), values), name
        assert np.isnan(table[name].values[[1, 3]]).all(), name
    assert list(table["status"].values) == ["finished", "failed"] * 2
    assert "no convergence" in str(table["message"].values[1])
    assert table["stretch"].attrs["units"] == "m" and table["between"].attrs["units"] == "N"
    assert table["warp.EA"].attrs["units"] == "N"
    assert list(table["warp.EA"].values) == [10, 10, 13.72, 13.72]
    for index, run in reference.items():  # each case file is the run's file
        written = read_results(tmp_path / "out" / "cases" / f"case-000{index}.h5")
        assert written.attrs["scene"] == run.attrs["scene"]
        for name, value in run.steps.items():
            if name not in MACHINE_TIMES:
                assert np.array_equal(written.steps[name], value), name
    with h5py.File(tmp_path / "out" / "cases" / "case-0001.h5", "r") as h5:
        assert h5.attrs["study_status"] == "failed"
    with h5py.File(result.table, "r") as h5:  # plain HDF5 reads it too
        assert np.array_equal(h5["final"][[0, 2], 0], expected["final"][:, 0])
    grid = table.set_index(case=table.attrs["parameters"].split()).unstack("case")
    assert grid["final"].sel({"warp.EA": 13.72, "static.max_iterations": 200}).item() == \
        expected["final"][1, 0]
    drawn = dynfab.plot_results(result.table, tmp_path / "plots")  # dynfab plot study.nc
    names = {"stretch.png", "stretch_path.png", "stretch_map.png"}
    names |= {f"{n}{suffix}.png" for n in ("final", "between", "on_step") for suffix in ("", "_map")}
    assert {p.name for p in drawn} == names
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in drawn)


def test_a_second_study_on_a_folder_is_refused(tmp_path):
    plan = load_study(write_study(tmp_path, '"warp.EA" = [10]'))
    with StudyFolder(tmp_path / "out", plan).locked():
        with pytest.raises(UserError, match="in use by another dynfab study"):
            study(plan, tmp_path / "out")


def test_a_folder_holding_a_study_needs_resume_and_the_same_study(tmp_path):
    plan = load_study(write_study(tmp_path, '"warp.EA" = [10]'))
    out = tmp_path / "out"
    with pytest.raises(UserError, match="nothing to resume"):
        study(plan, out, resume=True)
    folder = StudyFolder(out, plan)
    with folder.locked():
        folder.prepare(plan, resume=False)
    with pytest.raises(UserError, match="holds a study: pass --resume"):
        study(plan, out)
    other = load_study(write_study(tmp_path, '"warp.EA" = [11]'))
    with pytest.raises(UserError, match="started from a different study"):
        study(other, out, resume=True)
    assert json.loads((out / "study.json").read_text())["fingerprint"] == plan.fingerprint()


def wait_for(condition, what: str, limit_s: float = 300):
    """Poll `condition` until true; fail the test (not a timing assertion: a stuck study)."""
    deadline = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"never: {what}")
        time.sleep(0.05)


def test_an_interrupted_study_resumes_its_begun_cases_to_the_serial_results(tmp_path):
    """sync "steps", streamed every 0.05 s: SIGTERM (a batch system's limit) once a case has
    finished steps on disk; the message counts the ended cases; --resume runs the rest, a
    begun case from its last finished step, and the table is the serial runs'."""
    path = write_study(tmp_path, '"warp.EA" = [10, 12, 14]\n"load.steps" = [200]')
    plan = load_study(path)
    runs = serial(plan)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "dynfab.cli", "study", str(path), "--out", str(out),
               "--workers", "2", "--stream-interval", "0.05"]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    try:
        def begun():
            counts = [finished_counts(p) for p in (out / "cases").glob("*.h5")]
            return any(c is not None and 0 < c[0] < 200 for c in counts)
        wait_for(begun, "a case with finished steps on disk")
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 143, stderr
    assert "cases are finished in" in stderr and "continue with --resume" in stderr
    assert not (out / "study.nc").exists()
    partial = [finished_counts(p)[0] for p in (out / "cases").glob("*.h5")]
    assert any(0 < count < 200 for count in partial)
    done = subprocess.run(command + ["--resume"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    table = xr.open_dataset(out / "study.nc")
    expected = np.stack([r.steps["end_displacement"] for r in runs])
    assert np.array_equal(table["stretch"].values, expected)
    for index, run in enumerate(runs):
        written = read_results(out / "cases" / f"case-000{index}.h5")
        assert np.array_equal(written.steps["positions"], run.steps["positions"])


def test_the_example_study_runs_and_its_balanced_case_strains_both_families_alike(tmp_path):
    """runs/study_example.toml (README "Studies"): six cases of the periodic 2 x 2 cell. At
    the wefts' crimp (0.5 mm) the cell is balanced under equal loads: both families strain
    alike (the cell's symmetry, to the solver's rounding); more warp crimp gives the warps
    more strain to straighten out, so their final strain grows with the amplitude."""
    example = Path(__file__).resolve().parents[1] / "runs" / "study_example.toml"
    dynfab.run(load_study(example).cases[0].scene)  # the fabric's kernels into the cache
    out = tmp_path / "study_example"
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "study", str(example), "--out",
                           str(out)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "6 cases, 6 finished, 0 failed" in done.stderr
    table = xr.open_dataset(out / "study.nc")
    final = table["final_strain"].values  # (case, family)
    amplitude = table["geometry.amplitude"].values
    balanced = amplitude == 0.5e-3
    assert np.allclose(final[balanced, 0], final[balanced, 1], rtol=1e-9, atol=0)
    for stiffness in (1e4, 1e5):
        chosen = table["contact.core_stiffness"].values == stiffness
        warp = final[chosen, 0][np.argsort(amplitude[chosen])]
        assert np.all(np.diff(warp) > 0)
    plots = subprocess.run([sys.executable, "-m", "dynfab.cli", "plot", str(out / "study.nc"),
                            "--out", str(out / "plots")], capture_output=True, text=True,
                           timeout=600)
    assert plots.returncode == 0, plots.stderr
    assert (out / "plots" / "final_strain_map.png").stat().st_size > 0


def test_a_study_of_a_clamped_patch_gathers_the_serial_runs(tmp_path):
    """A clamped 2 x 2 patch of the paper's yarns with friction ("affine" planes) as the base
    scene, its warps' EA varied: each case's file and the gathered final strains (both
    families) are exactly those of the serial runs, as for the one-yarn base scene."""
    from dynfab.reports.fabric_data import paper_patch_scene
    from dynfab.scene import scene_to_toml

    base = paper_patch_scene(2, 2, planes="affine",
                             friction={"alpha": 0.2, "beta": 1e3, "contact_length": 2e-3,
                                       "fiber_radius": 1e-3},
                             load={"control": "force", "values": [0.1, 0.2],
                                   "weft_values": [0.05, 0.1]})
    assert base.geometry.boundary == "clamped"
    (tmp_path / "base.toml").write_text(scene_to_toml(base))
    path = tmp_path / "study.toml"
    path.write_text('title = "patch"\nscene = "base.toml"\n[vary]\n"warp.EA" = [10, 13.72]\n'
                    '[observe]\nfinal = { dataset = "strain", at = "last" }\n')
    plan = load_study(path)
    reference = serial(plan)
    result = study(plan, tmp_path / "out", workers=1, sync="end")
    assert (result.cases, result.finished, result.failed) == (2, 2, 0)
    table = xr.open_dataset(result.table)
    for index, run in enumerate(reference):
        assert np.array_equal(table["final"].values[index], run.steps["strain"][-1])
        written = read_results(tmp_path / "out" / "cases" / f"case-000{index}.h5")
        for name, value in run.steps.items():
            if name not in MACHINE_TIMES:
                assert np.array_equal(written.steps[name], value), name
    assert table["final"].shape == (2, 2) and table["final"].values[0, 0] > table["final"].values[1, 0]


def _trim_threshold():
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_the_local_cluster_workers_keep_glibcs_own_trim_rule(monkeypatch):
    """Dask's nanny sets MALLOC_TRIM_THRESHOLD_ = 65536 in the workers it spawns, which made a
    16 x 16 patch's case 1.3 x slower (docs/results.md, "Studies on a Dask cluster"); the
    study's own cluster leaves it unset (unless the user's environment sets it)."""
    from dynfab.studies.study import _cluster

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    with _cluster(None, 1) as client:
        assert set(client.run(_trim_threshold).values()) == {None}


def test_the_live_line_fits_80_columns_and_its_time_left_counts_down():
    # "time left: after the fi" was cut at 80 columns: the counts come first and whole, the
    # other parts only as far as they fit; between two ends the time left falls
    from dynfab.studies.study import fit_line, time_left
    parts = ["cases: 12 finished, 3 failed, 2 running, 183 waiting of 200",
             "about 14 min left", "1 worker lost", "2 cases rerun"]
    line = fit_line(parts, 80)
    assert len(line) <= 79 and line == "; ".join(parts[:2])
    assert fit_line(parts, 200) == "; ".join(parts)
    assert fit_line(parts, 20) == parts[0]
    # two cases ended 10 s apart, 6 pending: 60 s from the last end, then less
    at_end = time_left(0.0, 100.0, 110.0, 2, 6, now=110.0)
    later = time_left(0.0, 100.0, 110.0, 2, 6, now=140.0)
    assert (at_end, later) == ("about 60 s left", "about 30 s left")
    assert time_left(0.0, None, None, 0, 6, now=5.0) == "time left: unknown yet"
