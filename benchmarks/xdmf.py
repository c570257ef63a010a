"""Benchmark of the XDMF view (dynfab/xdmf.py): the cost of one rewrite against the steps listed.

Run:  python benchmarks/xdmf.py           (prints a table, writes benchmarks/xdmf.json)
      python benchmarks/xdmf.py --quick   (up to 1000 steps)

A run rewrites ``<result>.xdmf`` whole after a step (`XdmfSync`), so one rewrite
costs O(steps listed); `XdmfSync.update` skips a rewrite while the last one took
more than `XdmfSync.SHARE` (5 %) of the time since it ended, so the view costs at
most about 5 % of a run's time however many steps it has. Measured here: a result file of
the paper's yarn (N = 224 segments, 16 crossings, one yarn) with S steps written
by `dynfab.results.ResultFile` (every step dataset of a static run at its real
size), then `write_xdmf` timed (median of 5, time.perf_counter) and the XDMF
size. "per step" divides a rewrite by S.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dynfab.results import ResultFile
from dynfab.xdmf import nodal_point_data, write_xdmf

SEGMENTS, CROSSINGS = 224, 16


def record(nodes: int, load: float) -> dict:
    """One load step's datasets at their real sizes (values do not matter here)."""
    positions = np.zeros((1, nodes, 2))
    positions[0, :, 0] = np.linspace(0.0, 0.1, nodes)
    crossing_nodes = (2 * np.arange(CROSSINGS) + 1) * SEGMENTS // (2 * CROSSINGS)
    per_crossing = {name: np.full((1, CROSSINGS), load) for name in
                    ("contact_force", "friction_force", "friction_limit", "anchors")}
    step = {"load": [load], "end_force": [load], "end_displacement": [load], "positions": positions,
            "sliding": np.zeros((1, CROSSINGS), bool), "dissipated": [0.0], "crimp": [0.0],
            "residual": [0.0], "iterations": [1], "wall_time": 0.0, **per_crossing}
    step.update(nodal_point_data(positions, step["anchors"], step["contact_force"], crossing_nodes))
    return step


def measure(steps: int, folder: Path) -> dict:
    nodes = SEGMENTS + 1
    out = folder / f"s{steps}.h5"
    attrs = {"scene": "", "solver": "static", "load_control": "force", "projected_length": 0.1}
    reference = {"positions": record(nodes, 0.0)["positions"],
                 "crossing_nodes": np.arange(CROSSINGS)}
    with ResultFile.create(out, attrs=attrs, reference=reference, step_capacity=steps) as sink:
        for i in range(steps):
            sink.append_step(record(nodes, 1e-3 * (i + 1)))
    times = []
    for _ in range(5):
        started = time.perf_counter()
        path = write_xdmf(out)
        times.append(time.perf_counter() - started)
    rewrite = statistics.median(times)
    return {"steps": steps, "rewrite_s": rewrite, "per_step_s": rewrite / steps,
            "xdmf_bytes": path.stat().st_size, "h5_bytes": out.stat().st_size}


def main() -> None:
    counts = [10, 100, 1000] if "--quick" in sys.argv else [10, 100, 1000, 10000]
    rows = []
    with tempfile.TemporaryDirectory(dir=Path(__file__).parent) as folder:
        for steps in counts:
            rows.append(measure(steps, Path(folder)))
            row = rows[-1]
            print(f"{row['steps']:>6} steps: rewrite {1e3 * row['rewrite_s']:8.2f} ms  "
                  f"({1e6 * row['per_step_s']:6.1f} us per step listed)  xdmf "
                  f"{row['xdmf_bytes'] / 1e3:9.1f} kB  h5 {row['h5_bytes'] / 1e6:8.2f} MB",
                  flush=True)
    Path(__file__).with_name("xdmf.json").write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
