"""What a run will need, estimated before anything is allocated, and refused if it cannot fit.

A scene with 10^8 segments used to be killed for memory partway through writing
its file (docs/results.md, "The run's memory budget"); one with 10^8 load steps
hung. `check_budget` estimates the peak memory of the model and solver and the
size of the result file from the scene alone, and raises a UserError (exit
status 2) with the estimate when either exceeds what the machine has (available
memory, free disk space where the file goes).

The memory model is linear in the number of nodes: BYTES_PER_NODE bounds the growth
of the peak resident memory of `dynfab.run` (static, one yarn, 4 crossings, step
certificate included) per node, and PROCESS_BYTES the imports and a first run's JIT
compilation, both measured with the script in `tests/test_budget.py`. A fabric's
(docs/model.md section 10) grows as nodes^1.5 (FABRIC_BYTES: its sparse factorisation). The
estimates read the mesh's size (`dynfab.model.builders.mesh_size`: nodes, yarns, crossings,
whether the chains are tied to one another), not which model the scene is.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from dynfab.errors import UserError
from dynfab.model.builders import mesh_size
from dynfab.scene import Scene

BYTES_PER_NODE = 800
"""Peak memory per node of one yarn, model and solver arrays together [B]."""
PROCESS_BYTES = 500 * 2**20
"""Memory of the process before the model is built: imports, JIT compilation [B]; a first run
with numba's cache empty (a fresh clone) compiles the static solver in the run itself."""
STEP_SCALARS = 24
"""Per-step numbers per yarn, at most (load, end force, residual, ...)."""
CROSSING_DATASETS = 7
"""Per-step numbers per crossing, at most: a fabric's contact force, friction limit, sliding,
friction force (2), anchors (2)."""
FAMILY_SCALARS = 40
"""Per-step scalars and per-family pairs (a fabric's load, strain, crimp, energies, ...)."""
FABRIC_BYTES = 100
"""c [B] of a fabric run's memory growth c nodes^1.5 (docs/model.md section 10): the static
solver's sparse LU factors and the step's certificate on the patch's two-dimensional graph
(nested-dissection-like fill). 100 bounds the growth measured on the fabric benchmark's
patches up to 64 x 64 yarns (docs/results.md, "The run's memory budget")."""
VIEW_BYTES_PER_ENTRY = 3200
"""The XDMF view's datasets of one step or frame (`dynfab.results.views`: 3 or 4 virtual datasets,
metadata only) [B]: a bound of the sizes measured in docs/results.md ("The view")."""
VIEW_BYTES_PER_NODE = 20
"""The view's arrays stored once: each node's plane (8 B), each segment's two nodes and
yarn (int32) [B per node]."""


def memory_bytes(scene: Scene) -> int:
    """Estimated peak memory of a run of `scene` [B] (module docstring)."""
    size = mesh_size(scene)
    if size.coupled:
        return PROCESS_BYTES + int(FABRIC_BYTES * size.nodes ** 1.5)
    return PROCESS_BYTES + BYTES_PER_NODE * size.nodes


def result_file_bytes(scene: Scene) -> int:
    """Estimated size of the result file of `scene` [B]: per step (or frame of a transient
    run, with its velocities and forces) the positions and the XDMF view's two point data
    (`dynfab.results.xdmf`) per node, CROSSING_DATASETS numbers per crossing, STEP_SCALARS per
    yarn and FAMILY_SCALARS, and the view's datasets (`VIEW_BYTES_PER_ENTRY`,
    `VIEW_BYTES_PER_NODE`)."""
    size = mesh_size(scene)
    per_step = 8 * (4 * size.nodes + CROSSING_DATASETS * size.crossings
                    + STEP_SCALARS * size.yarns + FAMILY_SCALARS) + VIEW_BYTES_PER_ENTRY
    entries = len(scene.load.values)
    if scene.dynamic.mode == "transient" and scene.dynamic.output_interval:
        entries = scene.dynamic.duration / scene.dynamic.output_interval + 2
        per_step += 8 * 4 * size.nodes  # velocities and forces
    return int(entries * per_step) + VIEW_BYTES_PER_NODE * size.nodes


MEMORY_READING_AGE = 1.0
"""How long one reading of the available memory is reused [s]: a study's many small runs
read /proc/meminfo once a second, not once a run (the kernel's summing of it costs a
sizeable part of a small run's bookkeeping)."""
_last_reading: tuple[float, int | None] | None = None
"""(time.monotonic() [s], value [B]) of the last reading of /proc/meminfo."""


def available_memory_bytes() -> int | None:
    """MemAvailable of /proc/meminfo [B] (a reading at most MEMORY_READING_AGE old), or
    None where it cannot be read."""
    global _last_reading
    now = time.monotonic()
    if _last_reading is None or now - _last_reading[0] > MEMORY_READING_AGE:
        _last_reading = (now, _read_available_memory())
    return _last_reading[1]


def _read_available_memory() -> int | None:
    """MemAvailable of /proc/meminfo [B], or None where it cannot be read."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_budget(scene: Scene, out: str | os.PathLike | None) -> None:
    """UserError if the run's memory or result file (at `out`) cannot fit."""
    size = mesh_size(scene)
    need, have = memory_bytes(scene), available_memory_bytes()
    if have is not None and need > have:
        growth = (f"the static solver's sparse factors, about {FABRIC_BYTES} B x nodes^1.5"
                  if size.coupled else f"{BYTES_PER_NODE} B per node")
        raise UserError(f"{size.name} needs about {_size(need)} of memory ({growth}), but "
                        f"{_size(have)} is available: use fewer yarns or segments")
    if out is None:
        return
    folder = Path(out).resolve().parent
    while not folder.exists():
        folder = folder.parent
    file_size, free = result_file_bytes(scene), shutil.disk_usage(folder).free
    if file_size > free:
        what = ("frames" if scene.dynamic.mode == "transient"
                else f"{len(scene.load.values)} load steps")
        raise UserError(
            f"the result file '{out}' would take about {_size(file_size)} ({what} of "
            f"{size.short_name}), but {_size(free)} is free there: use fewer load steps or "
            "frames, or a coarser mesh")


def _size(count: int) -> str:
    """A byte count for people: 1.6 GB, 512 MB."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if count >= scale:
            return f"{count / scale:.3g} {unit}"
    return f"{count / 1e3:.3g} kB"
