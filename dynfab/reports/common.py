"""Helpers the reports share: the output folder, the machine, the CSV, JSON and text writers,
and the paper's yarns (cut to fewer crossings for the quick reports).

Figure helpers (saving, a new figure, the axis style) are dynfab.plots.figures's.
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from dynfab.errors import UserError
from dynfab.plots.style import output_folder  # noqa: F401 (the reports' --out check)
from dynfab.scene import Load, Scene, expand_sweep, load_scene, validate_scene, with_key

RUNS = Path(__file__).resolve().parents[2] / "runs"
"""The paper scene files of the source tree (the README's editable install keeps it)."""


def machine() -> dict:
    """What the report ran on: `uname -m`, `nproc`, the Python version."""
    return {"machine": platform.machine(), "cpus": os.cpu_count(),
            "python": platform.python_version(), "platform": platform.platform()}


def report_header(report: str, plan: str, quick: bool) -> dict:
    """The first entries of a report's summary: the report, its plan, quick or not, the machine."""
    return {"report": report, "plan": plan, "quick": quick, "machine": machine()}


def write_summary(out: Path, summary: dict, files: Iterable[Path], started: float) -> dict:
    """Finish `summary`: the wall time since `started` (time.perf_counter) and the files
    written, ``summary.json`` last; write it as ``summary.json`` and return it."""
    summary["wall_time_s"] = time.perf_counter() - started
    summary["files"] = [str(path) for path in files] + [str(out / "summary.json")]
    write_json(out / "summary.json", summary)
    return summary


def kernel_name(solver) -> str:
    """A dynamic solver's kernel variant as one string
    (`dynfab.kernels.structure_variants.Variant.name`: method/layout/order/precision/couplings;
    the damping and the load control are data, not variants)."""
    return solver.relaxation.variant.name


def plain(value):
    """JSON-ready: numpy scalars to Python, non-finite floats to None, sets to lists."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def csv_cell(value):
    """A CSV cell: repr for floats (every digit), '' for None, anything else as it is."""
    if isinstance(value, float):
        return repr(value)
    return "" if value is None else value


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[dict],
              cell: Callable = csv_cell) -> Path:
    """Write `rows` (dicts keyed by `columns`) as CSV, each value through `cell`; the path."""
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: cell(v) for k, v in row.items()})
    return path


def write_json(path: Path, data) -> Path:
    """Write `data`, made JSON-ready by `plain`, as indented JSON; the path."""
    path.write_text(json.dumps(plain(data), indent=1) + "\n")
    return path


def write_text(path: Path, text: str) -> Path:
    """Write `text` to `path`; the path."""
    path.write_text(text)
    return path


def paper_scene_file(name: str, reader: str) -> Scene:
    """The scene file `runs/<name>`; UserError naming `reader` (who needs it) if missing."""
    path = RUNS / name
    if not path.is_file():
        raise UserError(f"paper scene '{path}' not found: {reader} reads the runs/ folder of a "
                         "dynfab source tree")
    return load_scene(path)


def paper_yarns(reader: str) -> tuple[Scene, Scene]:
    """(frictionless, friction): the K = 0.2 m/N entry of runs/paper_fig3.toml and the
    friction-on entry of runs/paper_fig5.toml."""
    fig3 = paper_scene_file("paper_fig3.toml", reader)
    fig5 = paper_scene_file("paper_fig5.toml", reader)
    frictionless = next(s for s in expand_sweep(fig3) if s.warp.kawabata_K == 0.2)
    friction = next(s for s in expand_sweep(fig5) if s.friction and s.friction.alpha > 0)
    return frictionless, friction


def with_load(scene: Scene, control: str, values, **changes) -> Scene:
    """`scene` with the load path `values` under `control` (and any other field `changes`),
    validated."""
    return validate_scene(replace(scene, load=Load(control=control, values=values), **changes))


def with_path(scene: Scene, top: float, steps: int, **changes) -> Scene:
    """Displacement control to `top` [m] in `steps` equal steps (as `max`/`steps` in TOML)."""
    return with_load(scene, "displacement", tuple(top * k / steps for k in range(1, steps + 1)),
                     **changes)


def default_stick_stiffness(scene: Scene) -> float:
    """k_t = EA / (L / N) [N/m] (docs/model.md section 7)."""
    return scene.warp.EA * scene.geometry.segments / scene.geometry.length


def cut_yarn(scene: Scene, crossings: int, segments: int | None = None, *,
             scale_load: bool = False) -> Scene:
    """The same yarn with `crossings` crossings at the same spacing (L scaled, the weft as it
    was: `with_key` leaves its length and count), N = `segments` (None: as it is); with
    `scale_load`, the load values scaled with L (the same strains under displacement control).

    The crossings are set before N, so that N divides 2 x crossings at every change
    (N = 224 divides 2 x 4 too)."""
    ratio = crossings / scene.geometry.crossings
    length = scene.geometry.length * ratio
    scene = with_key(scene, "geometry.crossings", crossings)
    if segments is not None:
        scene = with_key(scene, "geometry.segments", segments)
    scene = with_key(scene, "geometry.length", length)
    if scale_load:
        scene = with_key(scene, "load.values", [v * ratio for v in scene.load.values])
    return scene
