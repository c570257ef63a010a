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
from dynfab.results.file import MACHINE_TIMES, finished_counts
from independent import pullout_text

ROOT = Path(__file__).resolve().parents[1]
FIG5 = ROOT / "runs" / "paper_fig5.toml"  # friction on and off: anchors must survive a resume
RELAX = ROOT / "runs" / "relax.toml"  # a transient run: frames


def dynfab_cli(*args, **kwargs):
    """Run `python -m dynfab.cli ...` in a subprocess (the console script's code)."""
    return subprocess.run([sys.executable, "-m", "dynfab.cli", *map(str, args)],
                          capture_output=True, text=True, **kwargs)


def step_arrays(path) -> dict:
    """Every steps/* dataset but the machine's times (`MACHINE_TIMES`: they differ run to run)."""
    results = dynfab.read_results(path)
    return {k: v for k, v in results.steps.items() if k not in MACHINE_TIMES}


def finished_rows(path, group: str = "steps") -> dict:
    """The finished rows of a result file read with plain h5py, as its layout tells a
    script to: rows [0, <group>_done) of every <group>/ dataset (the machine's times left out)."""
    with h5py.File(path, "r") as f:
        count = int(f[f"{group}_done"][0])
        rows = {}
        f[group].visititems(lambda name, obj: rows.__setitem__(name, obj[:count])
                            if isinstance(obj, h5py.Dataset) and name not in MACHINE_TIMES else None)
    return rows


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    path = tmp_path_factory.mktemp("full") / "fig5.h5"
    done = dynfab_cli("run", FIG5, "--out", path, "--quiet")
    assert done.returncode == 0, done.stderr
    return path


def finished_count(path, group: str) -> int:
    """Finished rows in a file being written (0 before it exists)."""
    counts = finished_counts(path) if path.exists() else None
    return 0 if counts is None else counts[0 if group == "steps" else 1]


def kill_at_random_moments(args, out, group, expected, seed, mid_run_kills):
    """Start `dynfab run ...` and kill -9 it at random moments, resuming each time, until
    `mid_run_kills` kills have landed mid-run; after every kill the file must open with
    plain h5py and its finished rows must equal the uninterrupted run's first rows exactly.
    Returns the counts seen after the mid-run kills.

    Each kill waits for a random row count ahead of the file's, then a random fraction
    of a (millisecond) step, so that the kills land mid-run at random phases of the
    writing. A run that finishes before its kill (a loaded machine) starts the file over."""
    rng = random.Random(seed)
    total = len(next(iter(expected.values())))
    counts, seen = [0], []
    for _ in range(5 * mid_run_kills):
        if len(seen) == mid_run_kills:
            break
        if counts[-1] == total:
            out.unlink()
            counts = [0]
        mode = "--resume" if out.exists() else "--overwrite"
        child = subprocess.Popen([sys.executable, "-m", "dynfab.cli", *map(str, args), "--out",
                                  str(out), "--quiet", mode],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        target = rng.randint(min(counts[-1] + 1, total - 3), total - 3)
        deadline = time.monotonic() + 120
        while (finished_count(out, group) < target and child.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.005))
        child.send_signal(signal.SIGKILL)
        child.wait()
        if not out.exists():
            continue
        rows = finished_rows(out, group)
        count = len(next(iter(rows.values()))) if rows else 0
        for name, value in rows.items():  # every finished row, bit for bit
            assert value.shape[0] == count, name
            np.testing.assert_array_equal(value, expected[name][:count], err_msg=name)
        assert count >= counts[-1], "a kill lost finished rows"
        counts.append(count)
        if 0 < count < total:
            seen.append(count)
    assert len(seen) == mid_run_kills, f"too few kills landed mid-run: {seen}"
    return seen


def test_kill_minus_9_leaves_a_readable_file_and_resume_is_exact(uninterrupted, tmp_path):
    expected = step_arrays(uninterrupted)
    total = expected["load"].shape[0]
    out = tmp_path / "killed.h5"
    kill_at_random_moments(["run", FIG5], out, "steps", expected, 20071, mid_run_kills=4)
    finished = dynfab_cli("run", FIG5, "--out", out, "--quiet",
                          "--resume" if out.exists() else "--overwrite")
    assert finished.returncode == 0, finished.stderr
    resumed = step_arrays(out)
    assert resumed["load"].shape[0] == total
    for name, value in expected.items():
        np.testing.assert_array_equal(resumed[name], value, err_msg=name)
    with h5py.File(out, "r") as f:  # a finished run keeps exactly its steps
        assert f["steps/load"].shape[0] == f["steps_done"][0] == total
    # no temporary file of a killed writer is left: only the result and its XDMF view
    assert sorted(p.name for p in tmp_path.iterdir()) == ["killed.h5", "killed.xdmf"]


def test_kill_minus_9_of_a_transient_run_keeps_its_frames_and_resume_is_exact(tmp_path):
    full = tmp_path / "full.h5"
    done = dynfab_cli("run", RELAX, "--solver", "dynamic", "--out", full, "--quiet")
    assert done.returncode == 0, done.stderr
    expected = dynfab.read_results(full).frames
    out = tmp_path / "killed.h5"
    kill_at_random_moments(["run", RELAX, "--solver", "dynamic"], out, "frames", expected, 5,
                           mid_run_kills=2)
    finished = dynfab_cli("run", RELAX, "--solver", "dynamic", "--out", out, "--quiet",
                          "--resume" if out.exists() else "--overwrite")
    assert finished.returncode == 0, finished.stderr
    assert finished_count(out, "frames") == expected["time"].shape[0]
    frames = dynfab.read_results(out).frames
    for name, value in expected.items():
        np.testing.assert_array_equal(frames[name], value, err_msg=name)


def test_python_api_returns_the_file_arrays(uninterrupted):
    results = dynfab.run(dynfab.load_scene(FIG5), solver="static")
    for name, value in step_arrays(uninterrupted).items():
        np.testing.assert_array_equal(results.steps[name], value, err_msg=name)


def test_summary_table_and_plots(tmp_path):
    out = tmp_path / "fig3.h5"
    done = dynfab_cli("run", ROOT / "runs" / "paper_fig3.toml", "--out", out)
    assert done.returncode == 0, done.stderr
    assert "max R [N]" in done.stdout and "[40/40]" in done.stderr
    # the run's summary after the table: its steps, solver time, each yarn's last state
    results = dynfab.read_results(out)
    steps, labels = results.steps, results.attrs["yarn_labels"]
    summary = done.stdout.strip().splitlines()[-4:]
    assert summary[0] == f"40 load steps, {steps['wall_time'].sum():.3f} s in the solver"
    for k, line in enumerate(summary[1:]):
        assert line == (f"last step, yarn {k + 1} ({labels[k]}): end force "
                        f"{steps['end_force'][-1, k]:.6g} N, end displacement "
                        f"{1e3 * steps['end_displacement'][-1, k]:.5f} mm, load per unit width "
                        f"{steps['stress'][-1, k]:.6g} N/m")
    assert "end displacement" in done.stderr and "(largest of 3 yarns)" in done.stderr
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
        if path.name.startswith("study_"):
            continue  # a study file (dynfab study), not a scene: tests/test_study.py
        scene = dynfab.load_scene(path)
        again = dynfab.parse_scene_text(scene_to_toml(scene))
        assert replace(again, text="") == replace(scene, text=""), path.name


def one_line(stderr: str) -> str:
    """The single line of a command's stderr (fails if there are more, or a traceback)."""
    assert "Traceback" not in stderr, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


def test_two_runs_started_at_once_on_a_new_file_one_wins(uninterrupted, tmp_path):
    """Creating the output is exclusive: never two exit 0 with one result lost."""
    expected = step_arrays(uninterrupted)
    for attempt in range(3):
        out = tmp_path / f"race{attempt}.h5"
        args = [sys.executable, "-m", "dynfab.cli", "run", str(FIG5), "--out", str(out), "--quiet"]
        children = [subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True) for _ in range(2)]
        outcomes = sorted((child.wait(), child.communicate()[1]) for child in children)
        assert [status for status, _ in outcomes] == [0, 2], outcomes
        assert one_line(outcomes[1][1]).startswith("dynfab: error: output file")
        for name, value in step_arrays(out).items():
            np.testing.assert_array_equal(value, expected[name], err_msg=name)


def test_a_file_being_written_refuses_a_second_writer(tmp_path):
    """--overwrite and --resume of a file another process writes: exit 2, file untouched."""
    from dynfab.results.file import ResultFile

    out = tmp_path / "busy.h5"
    done = dynfab_cli("run", FIG5, "--out", out, "--quiet")
    assert done.returncode == 0, done.stderr
    before = out.read_bytes()
    holder = ResultFile.resume(out)  # holds the writer lock, like a running dynfab
    try:
        for mode in ("--overwrite", "--resume"):
            busy = dynfab_cli("run", FIG5, "--out", out, "--quiet", mode)
            assert busy.returncode == 2, busy.stderr
            assert "being written by another dynfab process" in one_line(busy.stderr)
            assert out.read_bytes() == before
    finally:
        holder.close()
    assert dynfab.read_results(out).step_count == 40


def test_resume_of_a_finished_file_says_so_and_writes_nothing(uninterrupted, tmp_path):
    out = tmp_path / "done.h5"
    out.write_bytes(uninterrupted.read_bytes())
    mtime = out.stat().st_mtime_ns
    done = dynfab_cli("run", FIG5, "--out", out, "--resume")
    assert done.returncode == 0, done.stderr
    assert one_line(done.stderr) == f"'{out}' is already complete: nothing to do"
    assert done.stdout == ""
    assert out.read_bytes() == uninterrupted.read_bytes() and out.stat().st_mtime_ns == mtime


@pytest.mark.parametrize("flag", [None, "--overwrite"])
def test_run_out_a_directory_is_named_at_once(tmp_path, flag):
    done = dynfab_cli("run", FIG5, "--out", tmp_path, *([flag] if flag else []))
    assert done.returncode == 2
    assert one_line(done.stderr) == f"dynfab: error: output file '{tmp_path}' is a directory"


@pytest.mark.parametrize("case", ["existing_file", "unwritable"])
def test_plot_out_that_cannot_be_a_folder_is_one_line(uninterrupted, tmp_path, case):
    out = tmp_path / "taken.png" if case == "existing_file" else Path("/proc/nope")
    if case == "existing_file":
        out.write_bytes(b"keep")
    done = dynfab_cli("plot", uninterrupted, "--out", out)
    assert done.returncode == 2
    assert one_line(done.stderr).startswith("dynfab: error:") and str(out) in done.stderr
    if case == "existing_file":
        assert out.read_bytes() == b"keep"


def python_startup_time() -> float:
    """Seconds the interpreter takes to start (site included) before any dynfab code runs:
    a SIGINT before then is Python's own, which dynfab cannot handle."""
    started = time.monotonic()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.monotonic() - started


STOPPED = {signal.SIGINT: ("interrupted", 130), signal.SIGTERM: ("terminated", 143)}
"""Signal -> (the word of the command's last line, its exit status): a SIGTERM is taken as a
Ctrl-C is, with exit status 128 + 15 (what a shell reports for a process SIGTERM ended)."""


@pytest.mark.parametrize("delay, signum", [(0.05, signal.SIGINT), (0.2, signal.SIGINT),
                                           (0.4, signal.SIGINT), (0.2, signal.SIGTERM)])
def test_ctrl_c_while_starting_is_one_line_and_exit_130(tmp_path, delay, signum):
    """A SIGINT (or SIGTERM: exit 143) during the imports (the first half second): no
    traceback, nothing written."""
    word, exit_status = STOPPED[signum]
    delay += 1.5 * python_startup_time()
    out = tmp_path / "early.h5"
    child = subprocess.Popen([sys.executable, "-m", "dynfab.cli", "run", str(FIG5), "--out",
                              str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    child.send_signal(signum)
    stdout, stderr = child.communicate()
    assert child.returncode == exit_status, stderr
    line = one_line(stderr)
    if not out.exists():
        assert line == f"dynfab: {word}; nothing was written"
    else:  # the run got as far as its first steps: a file exists only with some
        kept = finished_count(out, "steps")
        assert kept > 0 and line == (f"dynfab: {word}; {kept} finished load step"
                                     f"{'s are' if kept > 1 else ' is'} in '{out}': "
                                     "continue with --resume")


@pytest.mark.parametrize("signum, stop", [(signal.SIGINT, KeyboardInterrupt),
                                           (signal.SIGTERM, "Terminated")])
def test_a_signal_during_a_held_import_is_raised_once_the_import_is_done(monkeypatch,
                                                                          signum, stop):
    """numba's C extension turns a KeyboardInterrupt during its import into an ImportError
    (its traceback printed: seen once in a CI run of the test above). The command imports it
    with the signals held (`cli._import_holding_signals`): the import ends, then the signal
    is raised as its handler would have. Without the hold the interrupt cuts the import
    short (`imported` stays empty)."""
    from dynfab import cli

    stop = cli.Terminated if stop == "Terminated" else stop
    imported = []

    def import_module(name):
        os.kill(os.getpid(), signum)  # delivered at the next bytecode, inside the import
        imported.append(name)

    monkeypatch.setattr(cli.importlib, "import_module", import_module)
    previous = signal.signal(signal.SIGTERM, cli._terminate)
    try:
        with pytest.raises(stop):
            cli._import_holding_signals(("numba",))
        assert signal.getsignal(signal.SIGTERM) is cli._terminate  # given back
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert imported == ["numba"]


def test_a_ctrl_c_while_main_sets_its_handlers_is_one_line_and_exit_130(monkeypatch, capsys):
    """A SIGINT delivered just after `main` set the Ctrl-C handler and before the rest (seen
    once in CI: a traceback and status -2 from the test above): one line and exit 130. The
    signal is real, sent at the first handler's setting; `os._exit` is replaced to keep the
    test's process."""
    from dynfab import cli

    set_handler = signal.signal

    def signal_then_interrupt(signum, handler):
        previous = set_handler(signum, handler)
        if signum == signal.SIGINT and handler is signal.default_int_handler:
            os.kill(os.getpid(), signal.SIGINT)  # delivered at the next bytecode
        return previous

    def exit_status(status):
        raise SystemExit(status)

    monkeypatch.setattr(cli.signal, "signal", signal_then_interrupt)
    monkeypatch.setattr(cli.os, "_exit", exit_status)
    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(SystemExit) as stop:
            cli.main(["run", str(FIG5), "--out", "never.h5"])
    finally:
        for signum, handler in saved.items():
            set_handler(signum, handler)
    assert stop.value.code == 130
    assert one_line(capsys.readouterr().err) == "dynfab: interrupted; nothing was written"


def interrupt_after(args, out, group, count, signum=signal.SIGINT):
    """Start `dynfab ARGS` (progress on), send it a real SIGINT (or `signum`) once `out` holds
    `count` finished rows of `group` ("steps" or "frames"); assert exit status 130 (143 for
    SIGTERM) and return (its stderr, the finished rows then on disk)."""
    child = subprocess.Popen([sys.executable, "-m", "dynfab.cli", *map(str, args)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while finished_count(out, group) < count and time.monotonic() < deadline:
        time.sleep(0.001)
    child.send_signal(signum)
    _, stderr = child.communicate()
    assert child.returncode == STOPPED[signum][1], stderr
    return stderr, finished_count(out, group)


def test_ctrl_c_mid_run_names_the_finished_steps_kept(uninterrupted, tmp_path):
    expected = step_arrays(uninterrupted)
    out = tmp_path / "mid.h5"
    stderr, kept = interrupt_after(["run", FIG5, "--out", out], out, "steps", 5)
    assert 5 <= kept < 40, "the interrupt must land mid-run"
    line = stderr.strip().splitlines()[-1]  # after the per-step progress lines
    assert "Traceback" not in stderr
    assert line == (f"dynfab: interrupted; {kept} finished load steps are in '{out}': "
                    "continue with --resume")
    for name, value in finished_rows(out).items():
        np.testing.assert_array_equal(value, expected[name][:kept], err_msg=name)


def test_ctrl_c_mid_transient_run_names_the_frames_kept(tmp_path):
    out = tmp_path / "relax.h5"
    stderr, kept = interrupt_after(["run", RELAX, "--solver", "dynamic", "--out", out], out,
                                   "frames", 5)
    assert "Traceback" not in stderr and 5 <= kept
    assert stderr.strip().splitlines()[-1] == (
        f"dynfab: interrupted; {kept} finished frames are in '{out}': continue with --resume")


def test_sigterm_mid_run_is_taken_as_a_ctrl_c_and_names_the_steps_kept(uninterrupted, tmp_path):
    """`kill` (SIGTERM) mid-run: one line naming the finished steps kept, exit status 143, the
    steps on disk those of the uninterrupted run (it killed the process without a word)."""
    expected = step_arrays(uninterrupted)
    out = tmp_path / "term.h5"
    stderr, kept = interrupt_after(["run", FIG5, "--out", out], out, "steps", 5, signal.SIGTERM)
    assert 5 <= kept < 40, "the signal must land mid-run"
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == (
        f"dynfab: terminated; {kept} finished load steps are in '{out}': continue with --resume")
    for name, value in finished_rows(out).items():
        np.testing.assert_array_equal(value, expected[name][:kept], err_msg=name)


def test_sigterm_within_a_long_first_step_removes_the_file_it_made(tmp_path):
    """The fabric at the friction onset, relaxed semi-implicitly: its first step runs for
    minutes (the relaxation cannot finish there, docs/model.md). A SIGTERM within it, once
    the file exists, is taken between two launches of the relaxation's kernel: one line,
    exit status 143, and the file this run made, holding no step, removed with its view
    (it was left behind, without a word)."""
    out = tmp_path / "onset.h5"
    child = subprocess.Popen([sys.executable, "-m", "dynfab.cli", "run",
                              str(ROOT / "runs" / "fabric_onset.toml"), "--solver", "dynamic",
                              "--method", "semi_implicit", "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while not out.exists() and child.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert out.exists(), child.communicate()[1]
    child.send_signal(signal.SIGTERM)
    _, stderr = child.communicate()
    assert child.returncode == 143, stderr
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == "dynfab: terminated; nothing was written"
    assert not out.exists() and not out.with_suffix(".xdmf").exists()


def test_sigterm_mid_run_of_a_clamped_patch_keeps_its_finished_steps(tmp_path):
    """The pull-out (a clamped patch, 22 static steps) under `kill` (SIGTERM) once three
    steps are on disk: one line naming the finished steps kept, exit status 143, and those
    steps, read with plain h5py, the uninterrupted run's first ones exactly (both families'
    positions, the crossings' forces, every steps/ dataset but the wall time)."""
    scene = tmp_path / "pullout.toml"
    scene.write_text(pullout_text())  # runs/fabric_pullout.toml to its peak, crossings fixed
    full = tmp_path / "full.h5"
    done = dynfab_cli("run", scene, "--solver", "static", "--out", full, "--quiet")
    assert done.returncode == 0, done.stderr
    expected = step_arrays(full)
    out = tmp_path / "term.h5"
    stderr, kept = interrupt_after(["run", scene, "--solver", "static", "--out", out], out,
                                   "steps", 3, signal.SIGTERM)
    assert 3 <= kept < len(expected["load"]), "the signal must land mid-run"
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == (
        f"dynfab: terminated; {kept} finished load steps are in '{out}': continue with --resume")
    rows = finished_rows(out)
    assert "weft_positions" in rows
    for name, value in rows.items():
        np.testing.assert_array_equal(value, expected[name][:kept], err_msg=name)


def test_dynfab_help_describes_the_command_in_whole_sentences():
    # the description was the module docstring's first line, cut mid-sentence ("`dynfab
    # xdmf` and"): it must end a sentence and name what the command does
    done = dynfab_cli("--help")
    assert done.returncode == 0
    description = done.stdout.split("\n\n")[1].replace("\n", " ")
    assert description.endswith(".") and "` and" not in description
    for word in ("run", "plot", "fit", "study"):
        assert word in description
