"""dynfab study on a real Dask cluster: a scheduler and two workers started as separate
processes (`dask scheduler`, `dask worker ADDRESS`), on 127.0.0.1 only, every process
ended by the fixture.

One test runs a small study through `dynfab study --scheduler`; the other kills one
worker (its nanny and worker processes, SIGKILL, as a machine lost) while both workers
are running cases, and checks that every case ends once and that the table equals the
serial runs' bit for bit.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import dynfab
from dynfab.results.file import finished_counts
from dynfab.studies.study import study
from dynfab.studies.file import load_study
from test_study import serial, wait_for, write_study

START_LIMIT_S = 120
"""Longest wait for the scheduler's file and its workers (a bound on a stuck start, not a
timing assertion)."""


def dask(*args) -> list[str]:
    return [sys.executable, "-m", "dask", *args]


def start(command: list[str], folder: Path, name: str) -> subprocess.Popen:
    """A process in a session of its own (so that it and its children end together), its
    output in a log file of the test's folder."""
    log = open(folder / f"{name}.log", "w")
    return subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            start_new_session=True, cwd=folder)


def end(process: subprocess.Popen) -> None:
    """SIGKILL the process's whole session (a nanny and its worker), then reap it."""
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    process.wait(timeout=30)


@pytest.fixture
def cluster(tmp_path):
    """(scheduler address, [worker processes]): `dask scheduler` and two `dask worker
    ADDRESS`, one thread each, on 127.0.0.1."""
    folder = tmp_path / "cluster"
    folder.mkdir()
    started = []
    try:
        file = folder / "scheduler.json"
        started.append(start(dask("scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--no-dashboard", "--scheduler-file", str(file)),
                             folder, "scheduler"))
        wait_for(lambda: file.exists() and file.stat().st_size > 0, "the scheduler's file",
                 START_LIMIT_S)
        address = json.loads(file.read_text())["address"]
        workers = [start(dask("worker", address, "--nthreads", "1", "--nworkers", "1",
                              "--host", "127.0.0.1", "--no-dashboard", "--death-timeout", "60",
                              "--local-directory", str(folder)), folder, f"worker{i}")
                   for i in range(2)]
        started += workers
        from distributed import Client

        with Client(address, timeout=START_LIMIT_S) as client:
            client.wait_for_workers(2, timeout=START_LIMIT_S)
        yield address, workers
    finally:
        for process in reversed(started):
            end(process)


def test_dynfab_study_runs_on_a_scheduler_and_its_workers(tmp_path, cluster):
    address, _ = cluster
    path = write_study(tmp_path, '"warp.EA" = [10, 13.72]\n"weft.kawabata_K" = [0.1, 0.2]')
    runs = serial(load_study(path))
    done = subprocess.run([sys.executable, "-m", "dynfab.cli", "study", str(path), "--out",
                           str(tmp_path / "out"), "--scheduler", address],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "4 cases, 4 finished, 0 failed" in done.stderr
    table = xr.open_dataset(tmp_path / "out" / "study.nc")
    assert np.array_equal(table["stretch"].values,
                          np.stack([r.steps["end_displacement"] for r in runs]))


def test_a_killed_worker_s_cases_are_rerun_and_every_case_ends_once(tmp_path, cluster):
    """Six cases of 300 steps on two one-thread workers, their steps streamed every 0.05 s
    (sync "steps"): once two cases have finished steps in their files,
    each worker is running one, and worker 0 is killed. Its case goes to worker 1 (the
    scheduler's log shows a case processing twice), which sends again the steps the file
    has: they are skipped (repeated_steps); each case file is written once, complete, and
    the table is the serial runs' exactly."""
    address, workers = cluster
    path = write_study(tmp_path, '"warp.EA" = [10, 11, 12, 13, 14, 15]\n"load.steps" = [300]')
    plan = load_study(path)
    runs = serial(plan)
    cases = tmp_path / "out" / "cases"
    killed = []

    def kill_when_both_stream(line: str) -> None:
        if killed or not cases.is_dir():
            return
        counts = [finished_counts(p) for p in cases.glob("*.h5")]
        if sum(c is not None and 0 < c[0] < 300 for c in counts) >= 2:
            end(workers[0])
            killed.append(time.monotonic())

    result = study(plan, tmp_path / "out", scheduler=address, status=kill_when_both_stream,
                   stream_interval_s=0.05)
    assert killed, "the worker was never killed"
    from distributed import Client

    with Client(address, timeout=START_LIMIT_S) as client:
        log = client.run_on_scheduler(lambda dask_scheduler: [
            str(entry[0]) for entry in dask_scheduler.transition_log
            if str(entry[0]).startswith("dynfab-case-") and entry[2] == "processing"])
    assert max(log.count(key) for key in set(log)) >= 2  # a case given to a second worker
    assert result.repeated_steps > 0
    assert (result.cases, result.finished, result.failed) == (6, 6, 0)
    # the lost worker and the case run again are said, and the workers are those that ran
    assert (result.workers, result.lost_workers) == (2, 1) and result.rerun_cases >= 1
    assert "on 2 workers, 1 lost" in result.summary()
    assert "run again after its worker was lost" in result.summary()
    files = sorted(cases.iterdir())
    assert [f.name for f in files] == [f"case-000{i}.h5" for i in range(6)]  # once each
    table = xr.open_dataset(result.table)
    assert np.array_equal(table["stretch"].values,
                          np.stack([r.steps["end_displacement"] for r in runs]))
    for index, run in enumerate(runs):
        written = dynfab.read_results(files[index])
        assert written.step_count == 300
        assert np.array_equal(written.steps["positions"], run.steps["positions"])
