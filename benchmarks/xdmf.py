"""Benchmark of the XDMF view (dynfab/results/xdmf.py): the cost of one rewrite against the steps
listed.

Run:  python benchmarks/xdmf.py           (prints a table, writes benchmarks/xdmf.json)
      python benchmarks/xdmf.py --quick   (up to 1000 steps)

A run rewrites ``<result>.xdmf`` whole after a step (`XdmfSync`), so one rewrite
costs O(steps listed); `XdmfSync.update` skips a rewrite while the last one took
more than `XdmfSync.SHARE` (5 %) of the time since it ended, so the view costs at
most about 5 % of a run's time however many steps it has. Measured here: a result file of
the paper's yarn (N = 224 segments, 16 crossings, one yarn) with S steps written
by `dynfab.results.file.ResultFile` (every step dataset of a static run at its real
size) with the view's datasets (`dynfab.results.views.add_views`, as a run writes it),
then `write_xdmf` timed (median of 5, time.perf_counter) and the XDMF size.
"per step" divides a rewrite by S. The cost of ``view/``: the same file written
without it, its size and the time of all the writes (``write_s``) against those
with it ("view ... per step": the difference divided by S). Last, the bytes of a
row's views by layout (`view_bytes_per_row`): `dynfab.results.views.add_views` on files
of 100 and 200 rows of made-up datasets, the difference divided by 100.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from dynfab.results.file import ResultFile
from dynfab.results.views import add_views
from dynfab.results.xdmf import write_xdmf

SEGMENTS, CROSSINGS = 224, 16


def record(nodes: int, load: float) -> dict:
    """One load step's datasets at their real sizes (values do not matter here)."""
    positions = np.zeros((1, nodes, 2))
    positions[0, :, 0] = np.linspace(0.0, 0.1, nodes)
    per_crossing = {name: np.full((1, CROSSINGS), load) for name in
                    ("contact_force", "friction_force", "friction_limit", "anchors")}
    step = {"load": [load], "end_force": [load], "end_displacement": [load], "positions": positions,
            "sliding": np.zeros((1, CROSSINGS), bool), "dissipated": [0.0], "crimp": [0.0],
            "residual": [0.0], "iterations": [1], "wall_time": 0.0, **per_crossing}
    step.update({"xdmf/contact_force": np.zeros((1, nodes)), "xdmf/slip": np.zeros((1, nodes))})
    return step


def write(out: Path, steps: int, views) -> float:
    """Write the S steps (with or without `views`); the time it took [s]."""
    nodes = SEGMENTS + 1
    attrs = {"scene": "", "solver": "static", "load_control": "force", "projected_length": 0.1}
    reference = {"positions": record(nodes, 0.0)["positions"],
                 "crossing_nodes": np.arange(CROSSINGS)}
    started = time.perf_counter()
    with ResultFile.create(out, attrs=attrs, reference=reference, step_capacity=steps,
                           views=views) as sink:
        for i in range(steps):
            sink.append_step(record(nodes, 1e-3 * (i + 1)))
    return time.perf_counter() - started


def measure(steps: int, folder: Path) -> dict:
    out, bare = folder / f"s{steps}.h5", folder / f"bare{steps}.h5"
    write_s, bare_write_s = write(out, steps, add_views), write(bare, steps, None)
    times = []
    for _ in range(5):
        started = time.perf_counter()
        path = write_xdmf(out)
        times.append(time.perf_counter() - started)
    rewrite = statistics.median(times)
    return {"steps": steps, "rewrite_s": rewrite, "per_step_s": rewrite / steps,
            "xdmf_bytes": path.stat().st_size, "h5_bytes": out.stat().st_size,
            "h5_bytes_without_view": bare.stat().st_size, "write_s": write_s,
            "write_s_without_view": bare_write_s}


def view_bytes_per_row(folder: Path) -> dict[str, float]:
    """Bytes of one row's views: one yarn of the paper (N = 224); a 4 x 4 fabric of 56
    segments per yarn with fixed planes, and with moving planes (4 views a row)."""
    def size(rows: int, prefixes: tuple, moving: bool) -> int:
        out = folder / f"views{rows}.h5"
        with h5py.File(out, "w") as h5:
            h5.attrs.update(scene="", projected_length=0.025, width_per_yarn=0.00625,
                            length_per_weft=0.00625)
            yarns, nodes = (1, SEGMENTS + 1) if prefixes == ("",) else (4, 57)
            for prefix in prefixes:
                h5[f"reference/{prefix}positions"] = np.zeros((yarns, nodes, 2))
                h5.create_dataset(f"steps/{prefix}positions", (rows, yarns, nodes, 2), "f8")
                for name in ("contact_force", "slip") + (("plane",) if moving else ()):
                    h5.create_dataset(f"steps/xdmf/{prefix}{name}", (rows, yarns, nodes), "f8")
        bare = out.stat().st_size
        with h5py.File(out, "a") as h5:
            add_views(h5)
        return out.stat().st_size - bare

    layouts = {"one yarn": (("",), False), "fabric, fixed planes": (("", "weft_"), False),
               "fabric, moving planes": (("", "weft_"), True)}
    return {name: (size(200, *layout) - size(100, *layout)) / 100
            for name, layout in layouts.items()}


def main() -> None:
    counts = [10, 100, 1000] if "--quick" in sys.argv else [10, 100, 1000, 10000]
    rows = []
    with tempfile.TemporaryDirectory(dir=Path(__file__).parent) as folder:
        for steps in counts:
            rows.append(measure(steps, Path(folder)))
            row = rows[-1]
            print(f"{row['steps']:>6} steps: rewrite {1e3 * row['rewrite_s']:8.2f} ms  "
                  f"({1e6 * row['per_step_s']:6.1f} us per step listed)  xdmf "
                  f"{row['xdmf_bytes'] / 1e3:9.1f} kB  h5 {row['h5_bytes'] / 1e6:8.2f} MB  view "
                  f"{(row['h5_bytes'] - row['h5_bytes_without_view']) / steps:6.0f} B and "
                  f"{1e3 * (row['write_s'] - row['write_s_without_view']) / steps:5.2f} ms "
                  "per step", flush=True)
        per_row = view_bytes_per_row(Path(folder))
    for name, value in per_row.items():
        print(f"views of a row, {name}: {value:.0f} B")
    Path(__file__).with_name("xdmf.json").write_text(
        json.dumps({"rewrites": rows, "view_bytes_per_row": per_row}, indent=2) + "\n")


if __name__ == "__main__":
    main()
