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
(docs/model.md section 10) grows as nodes^1.5 (FABRIC_BYTES: its sparse factorisation).
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from dynfab.errors import UserError
from dynfab.scene import Scene, yarn_count

BYTES_PER_NODE = 800
"""Peak memory per node of one yarn, model and solver arrays together [B]."""
PROCESS_BYTES = 500 * 2**20
"""Memory of the process before the model is built: imports, JIT compilation [B]; a first run
with numba's cache empty (a fresh clone) compiles the static solver in the run itself."""
STEP_SCALARS = 24
"""Per-step datasets that hold one number per yarn (load, end force, residual, ...)."""
CROSSING_DATASETS = 6
"""Per-step datasets that hold one number per crossing (contact force, friction, anchors...)."""
FABRIC_BYTES = 100
"""c [B] of a fabric run's memory growth c nodes^1.5 (docs/model.md section 10): the static
solver's sparse LU factors and the step's certificate on the patch's two-dimensional graph
(nested-dissection-like fill). 100 bounds the growth measured on the fabric benchmark's
patches up to 64 x 64 yarns (docs/results.md, "The run's memory budget")."""
FABRIC_CROSSING_DATASETS = 7
"""A fabric step's numbers per crossing: contact force, friction limit, sliding, friction
force (2), anchors (2) (`dynfab.model.fabric.model`)."""
FABRIC_STEP_SCALARS = 40
"""A fabric step's scalars and per-family pairs (load, strain, crimp, energies, residual...)."""
VIEW_BYTES_PER_ENTRY = 3200
"""The XDMF view's datasets of one step or frame (`dynfab.results.views`: 3 or 4 virtual datasets,
metadata only) [B]: a bound of the sizes measured in docs/results.md ("The view")."""
VIEW_BYTES_PER_NODE = 20
"""The view's arrays stored once: each node's plane (8 B), each segment's two nodes and
yarn (int32) [B per node]."""


def fabric_nodes(scene: Scene) -> int:
    """Nodes of a fabric scene: n_wa warps of N+1 nodes and n_we wefts of M+1
    (docs/model.md section 10); a specimen's from its area (`fabric_sizes`)."""
    return fabric_sizes(scene)[0]


def fabric_sizes(scene: Scene) -> tuple[int, int, int]:
    """(nodes, yarns, crossings) of a fabric scene. A specimen's (docs/model.md section 11)
    from its area A: A / (p_wa p_we) crossings, each family n segments per spacing, so
    2 n A / (p_wa p_we) nodes, plus a yarn's end pieces (a bound, not a count)."""
    g, weft, s = scene.geometry, scene.weft, scene.specimen
    if s is None:
        return (weft.count * (g.segments + 1) + g.crossings * (weft.segments + 1),
                weft.count + g.crossings, weft.count * g.crossings)
    p_wa, p_we = scene.warp.spacing, weft.spacing
    area = s.width * s.height if s.test == "bias_extension" else s.side ** 2
    extent = (s.width + s.height) if s.test == "bias_extension" else 2.0 * s.side
    crossings = area / (p_wa * p_we)
    yarns = 2.0 * extent / min(p_wa, p_we)
    n = s.segments_per_spacing
    return int(2 * n * crossings + (n + 2) * yarns), int(yarns), int(crossings)


def memory_bytes(scene: Scene) -> int:
    """Estimated peak memory of a run of `scene` [B]."""
    if scene.geometry.model == "fabric":
        return PROCESS_BYTES + int(FABRIC_BYTES * fabric_nodes(scene) ** 1.5)
    nodes = (scene.geometry.segments + 1) * yarn_count(scene)
    return PROCESS_BYTES + BYTES_PER_NODE * nodes


def result_file_bytes(scene: Scene) -> int:
    """Estimated size of the result file of `scene` [B]: positions (x, z) and the XDMF
    view's two point data (`dynfab.results.xdmf`) per node and step (three node arrays more per
    frame of a transient run), crossings and scalars; a fabric's per step (or frame, with
    its velocities and forces): both families' nodes so, its n_wa x n_we crossings, end force
    and displacement per yarn; the view's
    datasets (`VIEW_BYTES_PER_ENTRY`, `VIEW_BYTES_PER_NODE`)."""
    if scene.geometry.model == "fabric":
        _, yarns, crossings = fabric_sizes(scene)
        per_step = 8 * (4 * fabric_nodes(scene) + FABRIC_CROSSING_DATASETS * crossings
                        + 2 * yarns + FABRIC_STEP_SCALARS) + VIEW_BYTES_PER_ENTRY
        entries = len(scene.load.values)
        if scene.dynamic.mode == "transient" and scene.dynamic.output_interval:
            entries = scene.dynamic.duration / scene.dynamic.output_interval + 2
            per_step += 8 * 4 * fabric_nodes(scene)  # velocities and forces
        return int(entries * per_step) + VIEW_BYTES_PER_NODE * fabric_nodes(scene)
    yarns, nodes = yarn_count(scene), scene.geometry.segments + 1
    per_yarn = 8 * (4 * nodes + CROSSING_DATASETS * scene.geometry.crossings + STEP_SCALARS)
    view = VIEW_BYTES_PER_NODE * yarns * nodes
    if scene.dynamic.mode == "transient" and scene.dynamic.output_interval:
        frames = scene.dynamic.duration / scene.dynamic.output_interval + 2
        return int(frames * (yarns * (per_yarn + 8 * 4 * nodes) + VIEW_BYTES_PER_ENTRY)) + view
    return len(scene.load.values) * (yarns * per_yarn + VIEW_BYTES_PER_ENTRY) + view


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
    need, have = memory_bytes(scene), available_memory_bytes()
    if have is not None and need > have and scene.geometry.model == "fabric":
        raise UserError(
            f"a {_fabric_words(scene)} of {fabric_nodes(scene)} "
            f"nodes needs about {_size(need)} of memory (the static solver's sparse factors, "
            f"about {FABRIC_BYTES} B x nodes^1.5), but {_size(have)} is available: use fewer "
            "yarns or segments")
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
        if scene.geometry.model == "fabric":
            raise UserError(
                f"the result file '{out}' would take about {_size(size)} ({what} of a "
                f"{fabric_nodes(scene)}-node fabric), but {_size(free)} is free there: use "
                "fewer load steps or a coarser mesh")
        raise UserError(
            f"the result file '{out}' would take about {_size(size)} ({what} of "
            f"{scene.geometry.segments + 1} nodes x {yarn_count(scene)} yarn(s)), but "
            f"{_size(free)} is free there: use fewer load steps or frames, or a coarser mesh")


def _fabric_words(scene: Scene) -> str:
    """"a 16 x 16 fabric" or "a bias_extension specimen", as the refusals say it."""
    if scene.specimen is not None:
        return f"{scene.specimen.test} specimen"
    return f"{scene.weft.count} x {scene.geometry.crossings} fabric"


def _size(count: int) -> str:
    """A byte count for people: 1.6 GB, 512 MB."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if count >= scale:
            return f"{count / scale:.3g} {unit}"
    return f"{count / 1e3:.3g} kB"
