"""kill -9 a result-file writer thousands of times at random moments; check the file each time.

Run:  python benchmarks/io_kills.py [KILLS]   (default 2000; prints a summary,
      writes benchmarks/io_kills.json)

Not part of the test suite (it takes minutes); the suite kills real runs a
few times (tests/test_cli.py, tests/test_results.py). Here a forked child
resumes the file and appends synthetic steps as fast as it can, every value
of step n equal to n, with no capacity hint, so that the file also grows
(an atomic rewrite) now and then, and, in half of the runs, it rewrites the
file (`set_attrs` + `flush`) every 10th step, so that kills land in rewrites
and publishing too, not only in the in-place appends. After each kill at a random delay (0 to 60
ms after the child starts appending), the parent opens the file with plain
``h5py.File(path, "r")`` and checks, by the layout's rule (rows
``[0, steps_done)``), that every finished row holds its step's values, that
no finished step was lost, and that no temporary file is left once the next
writer starts.
"""

from __future__ import annotations

import json
import os
import random
import signal
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from dynfab.results.file import ResultFile

OUTPUT = Path(__file__).resolve().parent / "io_kills.json"
RESTART_STEPS = 500
"""The file starts over past this many steps, so that the rewrites that grow it stay short
(a rewrite longer than the kill window would take every later kill)."""
YARNS, NODES, CROSSINGS = 2, 225, 16
"""Sizes of the paper's two-yarn scene (small rows keep the rewrites, and so the loop, quick)."""


def step(n: int) -> dict:
    """Synthetic step n: every value is n (sliding: n odd)."""
    return {"load": np.full(YARNS, float(n)), "positions": np.full((YARNS, NODES, 2), float(n)),
            "contact_force": np.full((YARNS, CROSSINGS), float(n)),
            "sliding": np.full((YARNS, CROSSINGS), n % 2 == 1),
            "iterations": np.full(YARNS, n, dtype=np.int64), "wall_time": float(n)}


def child(path: Path, ready: int, rewrites: bool) -> None:
    """Resume `path` and append forever (killed by the parent); with `rewrites`, rewrite the
    whole file every 10th step too."""
    out = ResultFile.resume(path)
    os.write(ready, b"r")
    while True:
        n = out.step_count
        out.append_step(step(n))
        if rewrites and n % 10 == 9:
            out.set_attrs(note=f"after step {n}")
            out.flush()


def check(path: Path) -> int:
    """Open with plain h5py; every finished row must hold its step's values. The count."""
    with h5py.File(path, "r") as h5:
        count = int(h5["steps_done"][0])
        for name in step(0):
            rows = h5[f"steps/{name}"][:count] if count else np.zeros((0,))
            for n in range(count):
                expected = (n % 2 == 1) if name == "sliding" else n
                if not np.all(rows[n] == expected):
                    raise AssertionError(f"steps/{name}[{n}] is not step {n}'s")
    return count


def main(kills: int) -> dict:
    rng = random.Random(20071)
    folder = Path(tempfile.mkdtemp(dir=Path(__file__).resolve().parent))
    path = folder / "kills.h5"
    count, gains, started, files = RESTART_STEPS, [], time.perf_counter(), 0
    for _ in range(kills):
        if count >= RESTART_STEPS:
            files += 1
            ResultFile.create(path, attrs={"scene": "", "solver": "static",
                                           "load_control": "force"},
                              reference={}, overwrite=True).close()
            count = 0
        read, write = os.pipe()
        rewrites = rng.random() < 0.5
        pid = os.fork()
        if pid == 0:
            try:
                os.close(read)
                child(path, write, rewrites)
            finally:
                os._exit(1)
        os.close(write)
        os.read(read, 1)  # resumed: its lock is held
        os.close(read)
        time.sleep(rng.uniform(0.0, 0.06))
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        before, count = count, check(path)
        if count < before:
            raise AssertionError(f"finished steps lost: {before} then {count}")
        gains.append(count - before)
    ResultFile.resume(path).close()  # removes the temporary files of killed writers
    leftovers = sorted(p.name for p in folder.iterdir() if p != path)
    path.unlink()
    folder.rmdir()
    if leftovers:
        raise AssertionError(f"temporary files left: {leftovers}")
    return {"kills": kills, "files": files, "steps_checked": sum(gains),
            "kills_that_added_nothing": gains.count(0),
            "seconds": time.perf_counter() - started, "failures": 0}


if __name__ == "__main__":
    summary = main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000)
    print(f"{summary['kills']} kills -9, every one left a plainly readable file with every "
          f"finished step ({summary['steps_checked']} steps appended over "
          f"{summary['files']} files; "
          f"{summary['kills_that_added_nothing']} kills landed before a step finished); "
          f"{summary['seconds']:.0f} s")
    OUTPUT.write_text(json.dumps(summary, indent=2) + "\n")
