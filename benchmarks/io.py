"""Benchmark of result writing: time outside the solver per load step, old writer and new.

Run:  python benchmarks/io.py           (prints a table, writes benchmarks/io.json)
      python benchmarks/io.py --quick   (100 and 1000 steps only)

The run: paper Fig. 5's yarn with friction (runs/paper_fig5.toml, entry 0,
prestressed, K = 0.2 m/N) refined to N = 1792 segments, under displacement
control. Measured in one process, time.perf_counter:

- solve: `StaticSolver.step` per load step, the mean over the first
  `SOLVE_STEPS` steps of a 1600-step load path (after one untimed step that
  compiles);
- write: a fake solver returns the record of such a step (every dataset at its
  real size and dtype, the load changed per step), and each writer appends it
  `steps` times to a new file in a temporary folder on the repository's disk:
  create + every append (+ close, which trims, for the new writer), divided by
  the step count. The new writer is `dynfab.results.file.ResultFile` sized for the
  run; the old one is dynfab/results/file.py as of commit `OLD_COMMIT` (read with
  `git show`), which rewrote the whole file at every step, so it is run up to
  `OLD_MAX_STEPS` steps only (its cost per step grows linearly with the steps).
  "new-nosync" is the new writer with ``os.fdatasync`` skipped: not a mode
  dynfab offers, it splits the new writer's cost into its writes and its one
  sync per step;

- disk: the median time of writing one step's bytes in place and
  ``os.fdatasync``, before and after the writes (the floor of a crash-safe
  append: the rows must be on disk before the count that declares them
  finished; it varies with the disk and its other users).

Aims: a flat cost per step, at most half the solve time of a step.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np

from dynfab.model.yarn import initial_state
from dynfab.model.builders import build_model
from dynfab.results.file import ResultFile
from dynfab.run import _reference, _root_attrs
from dynfab.scene import Load, expand_sweep, load_scene, validate_scene, with_key
from dynfab.solvers.static import StaticSolver

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = Path(__file__).resolve().parent / "io.json"
SEGMENTS = 1792
"""Segments of the benchmark yarn (8 times the paper's 224)."""
SOLVE_STEPS = 100
"""Load steps timed for the solve figure."""
OLD_COMMIT = "90b35c4"
"""The last commit with the whole-file-per-step writer."""
OLD_MAX_STEPS = 1000
"""Largest step count run with the old writer (its total time grows with the square)."""


def yarn_scene(steps: int):
    """Fig. 5's friction yarn, N = 1792, `steps` displacement steps to 10 mm."""
    entry = expand_sweep(load_scene(ROOT / "runs" / "paper_fig5.toml"))[0]
    entry = with_key(entry, "geometry.segments", SEGMENTS)
    return validate_scene(replace(entry, load=Load(control="displacement",
                                                 values=tuple(np.linspace(0.01 / steps, 0.01, steps)))))


def solve_time_per_step() -> tuple[float, dict, object, object]:
    """Mean solve time of a 1792-segment step [s], a real record, the model and the solver."""
    model = build_model(yarn_scene(1600))
    solver = StaticSolver(model)
    state, record = solver.step(initial_state(model), float(model.load_values[0]))  # compiles
    state = initial_state(model)
    started = time.perf_counter()
    for value in model.load_values[:SOLVE_STEPS]:
        state, record = solver.step(state, float(value))
    elapsed = (time.perf_counter() - started) / SOLVE_STEPS
    record["wall_time"] = elapsed
    return elapsed, record, model, solver


def old_writer():
    """The ResultFile class of dynfab/results/file.py at OLD_COMMIT."""
    source = subprocess.run(["git", "show", f"{OLD_COMMIT}:dynfab/results/file.py"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "old_results.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("old_results", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["old_results"] = module  # its dataclasses look themselves up there
    spec.loader.exec_module(module)
    return module.ResultFile


def time_writer(writer: str, steps: int, record: dict, solver, folder: Path) -> dict:
    """Write `steps` copies of `record` with `writer` ("new", "old", or "new-nosync": the new
    writer with `os.fdatasync` skipped, to split its cost; not safe against power loss)."""
    if writer == "new-nosync":
        sync, os.fdatasync = os.fdatasync, lambda fd: None
        try:
            return {**time_writer("new", steps, record, solver, folder), "writer": writer}
        finally:
            os.fdatasync = sync
    model = build_model(yarn_scene(steps))
    attrs, reference = _root_attrs(model, solver), _reference(model)
    path = folder / f"{writer}-{steps}.h5"
    appends = np.empty(steps)
    started = time.perf_counter()
    if writer == "new":
        out = ResultFile.create(path, attrs=attrs, reference=reference, step_capacity=steps)
    else:
        out = old_writer().create(path, attrs=attrs, reference=reference)
    for index, value in enumerate(model.load_values):
        entry = {**record, "load": np.full_like(record["load"], value)}
        before = time.perf_counter()
        out.append_step(entry)
        appends[index] = time.perf_counter() - before
    if writer == "new":
        out.close()
    total = time.perf_counter() - started
    with h5py.File(path, "r") as h5:
        assert h5["steps/load"].shape[0] == steps
    size = path.stat().st_size
    path.unlink()
    return {"writer": writer, "steps": steps, "per_step_s": total / steps,
            "append_median_s": float(np.median(appends)), "append_max_s": float(appends.max()),
            "file_MB": size / 1e6}


def sync_latency(folder: Path, row_bytes: int, repeats: int = 100) -> float:
    """Median time [s] of writing `row_bytes` in place and `os.fdatasync` on this disk: the
    floor of a crash-safe append, which must sync its rows before declaring them finished."""
    path = folder / "sync.bin"
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    try:
        os.pwrite(fd, bytes(row_bytes * repeats), 0)
        os.fsync(fd)
        times = np.empty(repeats)
        for index in range(repeats):
            started = time.perf_counter()
            os.pwrite(fd, os.urandom(row_bytes), index * row_bytes)
            os.fdatasync(fd)
            times[index] = time.perf_counter() - started
    finally:
        os.close(fd)
        path.unlink()
    return float(np.median(times))


def main(quick: bool) -> dict:
    solve, record, model, solver = solve_time_per_step()
    row_bytes = sum(np.asarray(v).nbytes for v in record.values())
    counts = (100, 1000) if quick else (100, 1000, 10_000)
    rows = []
    with tempfile.TemporaryDirectory(dir=ROOT / "benchmarks") as folder:
        sync = sync_latency(Path(folder), row_bytes)
        print(f"disk: write {row_bytes / 1e3:.1f} kB + fdatasync, median {1e3 * sync:.3f} ms",
              flush=True)
        for steps in counts:
            for writer in ("new", "new-nosync", "old"):
                if writer == "old" and steps > OLD_MAX_STEPS:
                    continue
                rows.append(time_writer(writer, steps, record, solver, Path(folder)))
                print_row(rows[-1], solve)
    sync_after = sync_latency(ROOT / "benchmarks", row_bytes)
    print(f"disk after: write + fdatasync, median {1e3 * sync_after:.3f} ms", flush=True)
    return {"segments": SEGMENTS, "solve_per_step_s": solve, "bytes_per_step": row_bytes,
            "sync_median_s_before": sync, "sync_median_s_after": sync_after,
            "old_commit": OLD_COMMIT, "writes": rows, "python": platform.python_version(),
            "h5py": h5py.version.version, "hdf5": h5py.version.hdf5_version,
            "machine": platform.machine()}


def print_row(row: dict, solve: float) -> None:
    print(f"{row['writer']:>10} {row['steps']:>6} steps: {1e3 * row['per_step_s']:9.3f} ms/step "
          f"outside the solver ({row['per_step_s'] / solve:6.2f} x solve), append median "
          f"{1e3 * row['append_median_s']:.3f} ms, max {1e3 * row['append_max_s']:.1f} ms, "
          f"file {row['file_MB']:.1f} MB", flush=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="100 and 1000 steps only")
    args = parser.parse_args()
    results = main(args.quick)
    print(f"solve: {1e3 * results['solve_per_step_s']:.3f} ms per 1792-segment static step; "
          f"{results['bytes_per_step'] / 1e3:.1f} kB written per step")
    if not args.quick:
        OUTPUT.write_text(json.dumps(results, indent=2) + "\n")
        print(f"wrote {OUTPUT}")
