"""What a run will need, estimated before anything is allocated, and refused if it cannot fit.

A scene with 10^8 segments used to be killed for memory after writing 1.6 GB;
one with 10^8 load steps hung. `check_budget` estimates the peak memory of the
model and solver and the size of the result file from the scene alone, and
raises a UserError (exit status 2) with the estimate when either exceeds what
the machine has (available memory, free disk space where the file goes).

The memory model is linear in the number of nodes: BYTES_PER_NODE bounds the growth
of the peak resident memory of `dynfab.run` (static, one yarn, 4 crossings, step
certificate included) per node, and PROCESS_BYTES the imports and a first run's JIT
compilation, both measured with the script in `tests/test_budget.py`.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from dynfab.errors import UserError
from dynfab.scene import Scene, yarn_count

BYTES_PER_NODE = 800
"""Peak memory per node of one yarn, model and solver arrays together [B]."""
PROCESS_BYTES = 400 * 2**20
"""Memory of the process before the model is built: imports, JIT compilation [B]."""
STEP_SCALARS = 24
"""Per-step datasets that hold one number per yarn (load, end force, residual, ...)."""
CROSSING_DATASETS = 6
"""Per-step datasets that hold one number per crossing (contact force, friction, anchors...)."""


def memory_bytes(scene: Scene) -> int:
    """Estimated peak memory of a run of `scene` [B]."""
    nodes = (scene.geometry.segments + 1) * yarn_count(scene)
    return PROCESS_BYTES + BYTES_PER_NODE * nodes


def result_file_bytes(scene: Scene) -> int:
    """Estimated size of the result file of `scene` [B]: positions (x, z) and the XDMF
    view's two point data (`dynfab.xdmf`) per node and step (three node arrays more per
    frame of a transient run), crossings and scalars."""
    yarns, nodes = yarn_count(scene), scene.geometry.segments + 1
    per_yarn = 8 * (4 * nodes + CROSSING_DATASETS * scene.geometry.crossings + STEP_SCALARS)
    if scene.dynamic.mode == "transient" and scene.dynamic.output_interval:
        frames = scene.dynamic.duration / scene.dynamic.output_interval + 2
        return int(frames * yarns * (per_yarn + 8 * 4 * nodes))
    return len(scene.load.values) * yarns * per_yarn


def available_memory_bytes() -> int | None:
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
    need, have = memory_bytes(scene), available_memory_bytes()
    if have is not None and need > have:
        raise UserError(
            f"geometry.segments = {scene.geometry.segments} x {yarn_count(scene)} yarn(s) needs "
            f"about {_size(need)} of memory ({BYTES_PER_NODE} B per node), but {_size(have)} "
            "is available: use fewer segments or yarns")
    if out is None:
        return
    folder = Path(out).resolve().parent
    while not folder.exists():
        folder = folder.parent
    size, free = result_file_bytes(scene), shutil.disk_usage(folder).free
    if size > free:
        what = ("frames" if scene.dynamic.mode == "transient"
                else f"{len(scene.load.values)} load steps")
        raise UserError(
            f"the result file '{out}' would take about {_size(size)} ({what} of "
            f"{scene.geometry.segments + 1} nodes x {yarn_count(scene)} yarn(s)), but "
            f"{_size(free)} is free there: use fewer load steps or frames, or a coarser mesh")


def _size(count: int) -> str:
    """A byte count for people: 1.6 GB, 512 MB."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if count >= scale:
            return f"{count / scale:.3g} {unit}"
    return f"{count / 1e3:.3g} kB"
