"""Benchmark of `dynfab study`: a local cluster against one process, the [sweep] batch against
the cluster, the cost of --sync steps, and the transfer of a large patch's results.

Run:  python benchmarks/study.py            (prints the tables, writes benchmarks/study.json)
      python benchmarks/study.py --quick    (fewer, smaller cases: checks that it runs)

Parts, each timed with time.perf_counter in this process (the client), warm (every kernel
compiled and in the caches before the timing: one untimed case first):

- fabric: 32 fabric cases, the strip test's clamped 16 x 16 patch of the paper's yarns
  (runs/fabric_strip.toml) on a short path (2 force steps to 1 N), warp.EA x weft.EA
  varied, each command in a fresh process as a user runs it (the kernels already in the
  caches): serially, a loop of `dynfab.run` of each case to its file, as it runs by
  default (the fabric's Newton solves call OpenBLAS, two threads here) and with the BLAS
  on one thread (as Dask's workers run it); and `dynfab.studies.study` on a LocalCluster of
  WORKERS workers (sync "steps", the default). The speed-ups are the ratios of the
  processes' wall times (imports, the cluster's start, the table included). The ceiling:
  WORKERS plain processes started at once, each running every WORKERS-th case with its
  BLAS on one thread, no Dask (`concurrent_processes`): what the cores give independent
  runs here. The dispatch overhead per case (`paired_overhead`): a case's task, sent,
  run, its file brought back and written by the client, less the run's own time on the
  worker (the task's `seconds`); and apart, that run's time against the same run in this
  process. The one-off costs: the cluster's start (start, dynfab imported on every worker,
  close) and a worker's first case (kernels loaded from the caches: the slowest task less
  the median).
- sweep: one-yarn cases of the paper's yarn (runs/paper_fig3.toml, the warp's K = 0.02 to
  1 m/N, 40 displacement steps; and the yarn refined to N = 1792, 10 steps): the
  same K values as one scene's [sweep] (one batched run in one process, static) against a
  study of one case per value on the cluster (sync "end").
- sync: the one-yarn study at N = 224 with sync "steps" (its cases end within the first
  stream interval: they come back whole), "steps" with every step streamed
  (stream_interval_s = 0: a case longer than the interval) and "end": wall time, the
  client's time writing files, a task's median; and this disk's fdatasync, the median of 50.
- transfer: one case of a clamped 32 x 32 patch (one force step): its file's bytes per
  step, and the time a task takes to bring that many bytes to the client (best of 5,
  minus the same for 1 byte).

The machine's load (os.getloadavg) is recorded before and after: on a shared 2-core
machine the speed-up needs a quiet one.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = Path(__file__).resolve().parent / "study.json"
WORKERS = 2


def study_file(folder: Path, scene_text: str, vary: dict, observe: str, name: str) -> Path:
    """A study file in `folder` over the scene `scene_text` (written beside it)."""
    (folder / f"{name}_scene.toml").write_text(scene_text)
    lines = [f'scene = "{name}_scene.toml"', "[vary]"]
    lines += [f'"{key}" = {json.dumps(values)}' for key, values in vary.items()]
    path = folder / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n" + observe)
    return path


def strip_text(patch: int, steps: int) -> str:
    """runs/fabric_strip.toml resized to a `patch` x `patch` patch at the same pitch and
    segments per crossing (L = 0.1 m x patch / 16, 14 segments a crossing), `steps` force
    steps to 1 N."""
    text = (ROOT / "runs" / "fabric_strip.toml").read_text()
    text = text.replace("length = 0.1\n", f"length = {0.1 * patch / 16!r}\n")
    text = text.replace("segments = 224", f"segments = {14 * patch}")
    text = text.replace("crossings = 16", f"crossings = {patch}")
    text = text.replace("count = 16", f"count = {patch}").replace("steps = 10", f"steps = {steps}")
    return text


def yarn_text(segments: int, steps: int) -> str:
    """Fig. 3's yarn (one entry of its sweep: K = 0.2 m/N) at `segments`, `steps` steps."""
    text = (ROOT / "runs" / "paper_fig3.toml").read_text()
    text = text.split("[sweep]")[0].replace("segments = 224", f"segments = {segments}")
    return text.replace("steps = 40", f"steps = {steps}")


SERIAL = """
import json, sys, time
began = time.perf_counter()
import dynfab
from dynfab.studies.file import load_study
plan, folder = load_study(sys.argv[1]), sys.argv[2]
part, parts = (int(sys.argv[3]), int(sys.argv[4])) if len(sys.argv) > 4 else (0, 1)
each = []
for case in plan.cases[part::parts]:
    start = time.perf_counter()
    dynfab.run(case.scene, out=f"{folder}/serial-{case.index}.h5", overwrite=True)
    each.append(time.perf_counter() - start)
print(json.dumps({"each": each, "process_s": time.perf_counter() - began}))
"""
"""One process running every case of a study to its file, as a user's loop would (or every
`parts`-th from `part`: argv 3 and 4)."""

STUDY = """
import json, sys, time
began = time.perf_counter()
import dynfab
interval = float(sys.argv[5]) if len(sys.argv) > 5 else None
result = dynfab.study(sys.argv[1], sys.argv[2], workers=int(sys.argv[3]), sync=sys.argv[4],
                      stream_interval_s=interval)
print(json.dumps({"process_s": time.perf_counter() - began, "study_s": result.seconds,
                  "task_seconds": list(result.task_seconds.values()),
                  "write_s": result.write_seconds, "failed": result.failed}))
"""
"""One process running a study (`dynfab.studies.study`, its own local cluster)."""


ENVIRONMENT = dict(os.environ)
"""This process's environment at its start: a Dask nanny writes its workers' variables
(distributed.nanny.pre-spawn-environ) into its own process's environment and leaves them
there, where every later process would inherit them; the commands run here get this one."""

ONE_THREAD = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                     "MKL_NUM_THREADS")}
"""What Dask's nanny sets in every worker's environment (distributed.nanny.pre-spawn-environ):
the BLAS libraries on one thread."""


def in_process(script: str, *args, env: dict | None = None) -> dict:
    """Run `script` in a fresh Python process (timed from its start); its JSON line. `env`:
    variables added to its environment."""
    began = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", script, *map(str, args)], capture_output=True,
                          text=True, check=True, env={**ENVIRONMENT, **(env or {})})
    found = json.loads(done.stdout.strip().splitlines()[-1])
    found["wall_s"] = time.perf_counter() - began
    return found


def concurrent_processes(path: Path, tmp: Path, count: int) -> float:
    """Wall time [s] of `count` plain processes started at once, each running every count-th
    case of the study (BLAS on one thread, no Dask): what `count` cores give to independent
    runs on this machine, the ceiling of a study's speed-up over one such process."""
    began = time.perf_counter()
    runs = [subprocess.Popen([sys.executable, "-c", SERIAL, str(path), str(tmp), str(k),
                              str(count)], stdout=subprocess.DEVNULL,
                             env={**ENVIRONMENT, **ONE_THREAD}) for k in range(count)]
    if any(run.wait() for run in runs):
        raise SystemExit("a concurrent serial process failed")
    return time.perf_counter() - began


def serial_seconds(plan, folder: Path) -> tuple[float, list[float]]:
    """Each case run to its file in this process: (total, each) [s]."""
    import dynfab

    dynfab.run(plan.cases[0].scene)  # warm: compiled and cached
    each = []
    for case in plan.cases:
        began = time.perf_counter()
        dynfab.run(case.scene, out=folder / f"serial-{case.index}.h5", overwrite=True)
        each.append(time.perf_counter() - began)
    return sum(each), each


def cluster_start_seconds(workers: int) -> float:
    """Start a LocalCluster, run a task on every worker (dynfab imported), close it [s]."""
    from distributed import Client

    from dynfab.studies.study import local_cluster
    from dynfab.studies.case import worker_info

    began = time.perf_counter()
    with local_cluster(workers) as cluster, Client(cluster) as client:
        client.run(worker_info)
    return time.perf_counter() - began


def run_study(path: Path, folder: Path, sync: str = "steps", workers: int = WORKERS):
    import dynfab

    began = time.perf_counter()
    result = dynfab.study(path, folder, workers=workers, sync=sync)
    return time.perf_counter() - began, result


def fabric_part(tmp: Path, cases: int, patch: int) -> dict:
    """Serial against the local cluster, each a fresh process as a user runs them."""
    import dynfab
    from dynfab.studies.file import load_study

    ea = list(np.round(np.linspace(10.0, 17.0, cases // 4), 4))
    path = study_file(tmp, strip_text(patch, 2), {"warp.EA": ea, "weft.EA": [10, 12, 14, 16]},
                      '[observe]\nstrain = "strain"\n', "fabric")
    dynfab.run(load_study(path).cases[0].scene)  # compiled into the caches: both start warm
    serial = in_process(SERIAL, path, tmp)
    single = in_process(SERIAL, path, tmp, env=ONE_THREAD)
    together = concurrent_processes(path, tmp, WORKERS)
    start = cluster_start_seconds(WORKERS)
    study = in_process(STUDY, path, tmp / "fabric_out", WORKERS, "steps")
    paired = paired_overhead(load_study(path), tmp)
    tasks = study["task_seconds"]
    return {"cases": cases, "patch": patch, "steps": 2,
            "serial_process_s": serial["wall_s"], "serial_case_median_s":
            statistics.median(serial["each"]),
            "serial_1thread_process_s": single["wall_s"],
            "serial_1thread_case_median_s": statistics.median(single["each"]),
            "study_process_s": study["wall_s"], "speed_up": serial["wall_s"] / study["wall_s"],
            "speed_up_over_1thread": single["wall_s"] / study["wall_s"],
            "plain_processes": WORKERS, "plain_processes_s": together,
            "ceiling_speed_up_over_1thread": single["wall_s"] / together,
            "study_task_median_s": statistics.median(tasks),
            "study_client_write_per_case_s": study["write_s"] / cases,
            "cluster_start_s": start, "worker_warmup_s": max(tasks) - statistics.median(tasks),
            **paired, "failed": study["failed"]}


def paired_overhead(plan, tmp: Path, pairs: int = 6) -> dict:
    """A case run in this process (BLAS on one thread, as on a worker) and the same case as
    a study's task on a one-worker LocalCluster (sync "end": the file comes back and is
    written as the study writes it), alternately `pairs` times, so that the machine's other
    load falls on both alike: the medians; the dispatch overhead, the task less the run on
    the worker (its `seconds`); and the run on the worker over the run here."""
    import dynfab
    from distributed import Client
    from threadpoolctl import threadpool_limits

    from dynfab.studies.study import _write_atomically, local_cluster
    from dynfab.studies.case import run_case

    case = plan.cases[0]
    task = {"index": 0, "scene": case.text, "solver": "static", "sync": "end", "queue": None,
            "partial": None}
    here, there, inside = [], [], []
    with local_cluster(1) as cluster, Client(cluster) as client, threadpool_limits(1):
        client.submit(run_case, task, pure=False).result()  # the worker's first case: warm
        for _ in range(pairs):
            began = time.perf_counter()
            dynfab.run(case.scene, out=tmp / "paired.h5", overwrite=True)
            here.append(time.perf_counter() - began)
            began = time.perf_counter()
            outcome = client.submit(run_case, task, pure=False).result()
            _write_atomically(tmp / "paired-case.h5", outcome["file"])
            there.append(time.perf_counter() - began)
            inside.append(outcome["seconds"])
    overhead = statistics.median(there) - statistics.median(inside)
    return {"paired_case_here_s": statistics.median(here),
            "paired_case_on_worker_s": statistics.median(there),
            "paired_task_inside_worker_s": statistics.median(inside),
            "dispatch_overhead_per_case_s": overhead,
            "dispatch_overhead_fraction": overhead / statistics.median(here),
            "worker_run_over_here": statistics.median(inside) / statistics.median(here)}


def sweep_part(tmp: Path, cases: int, segments: int, steps: int) -> dict:
    import dynfab
    from dynfab.studies.file import load_study

    values = [float(v) for v in np.round(np.linspace(0.02, 1.0, cases), 6)]
    text = yarn_text(segments, steps)
    # the warp's K varied (the weft's stays 0.2): one batched scene, or one case a value
    swept = dynfab.parse_scene_text(text + "\n[sweep]\n" + f'"warp.kawabata_K" = {values}\n')
    dynfab.run(swept)
    began = time.perf_counter()
    dynfab.run(swept, out=tmp / f"sweep-{segments}.h5", overwrite=True)
    batch = time.perf_counter() - began
    path = study_file(tmp, text, {"warp.kawabata_K": values},
                      '[observe]\nforce = { dataset = "end_force", at = "last" }\n',
                      f"yarn{segments}")
    plan = load_study(path)
    dynfab.run(plan.cases[0].scene)  # warm for the workers' cache
    wall, result = run_study(path, tmp / f"yarn{segments}_out", sync="end")
    serial, _ = serial_seconds(plan, tmp)
    return {"cases": cases, "segments": segments, "steps": steps, "sweep_batch_s": batch,
            "study_s": wall, "serial_s": serial, "study_over_sweep": wall / batch,
            "worker_task_mean_s": statistics.mean(result.task_seconds.values())}


def sync_part(tmp: Path, cases: int, segments: int, steps: int) -> dict:
    values = [float(v) for v in np.round(np.linspace(0.02, 1.0, cases), 6)]
    found = {"cases": cases, "segments": segments, "steps": steps,
             "fdatasync_median_s": disk_sync_seconds(tmp)}
    for name, sync, interval in (("steps", "steps", None), ("steps_streamed", "steps", 0.0),
                                 ("end", "end", None)):
        path = study_file(tmp, yarn_text(segments, steps), {"warp.kawabata_K": values},
                          '[observe]\nforce = "end_force"\n', f"sync_{name}")
        began = time.perf_counter()
        import dynfab

        result = dynfab.study(path, tmp / f"sync_{name}_out", workers=WORKERS, sync=sync,
                              stream_interval_s=interval)
        found[name] = {"study_s": time.perf_counter() - began,
                       "client_write_s": result.write_seconds,
                       "client_write_per_step_s": result.write_seconds / (cases * steps),
                       "task_median_s": statistics.median(result.task_seconds.values())}
    return found


def disk_sync_seconds(folder: Path, count: int = 50) -> float:
    path = folder / "sync.bin"
    fd = os.open(path, os.O_RDWR | os.O_CREAT)
    try:
        times = []
        for i in range(count):
            os.pwrite(fd, os.urandom(4096), 4096 * (i % 8))
            began = time.perf_counter()
            os.fdatasync(fd)
            times.append(time.perf_counter() - began)
    finally:
        os.close(fd)
    return statistics.median(times)


def _bytes(count: int) -> bytes:
    return bytes(count)


def transfer_part(tmp: Path, patch: int) -> dict:
    from distributed import Client

    from dynfab.studies.study import local_cluster

    path = study_file(tmp, strip_text(patch, 1), {"warp.EA": [13.72]},
                      '[observe]\nstrain = "strain"\n', "transfer")
    wall, result = run_study(path, tmp / "transfer_out", sync="end", workers=1)
    size = (tmp / "transfer_out" / "cases" / "case-0000.h5").stat().st_size
    with local_cluster(1) as cluster, Client(cluster) as client:
        def best(count: int) -> float:
            times = []
            for _ in range(5):
                began = time.perf_counter()
                client.submit(_bytes, count, pure=False).result()
                times.append(time.perf_counter() - began)
            return min(times)
        best(1)
        empty, full = best(1), best(size)
    moved = max(full - empty, 1e-9)
    return {"patch": patch, "steps": 1, "file_bytes_per_step": size, "case_task_s":
            statistics.mean(result.task_seconds.values()), "transfer_s": moved,
            "transfer_MB_per_s": size / moved / 1e6, "task_round_trip_s": empty}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer, smaller cases")
    parser.add_argument("--parts", default="fabric,sweep,sync,transfer")
    args = parser.parse_args()
    parts = args.parts.split(",")
    found = {"machine": platform.machine(), "cpus": os.cpu_count(), "workers": WORKERS,
             "load_before": os.getloadavg(), "quick": args.quick}
    with tempfile.TemporaryDirectory(dir=ROOT) as name:
        tmp = Path(name)
        if "fabric" in parts:
            found["fabric"] = fabric_part(tmp, 8 if args.quick else 32, 4 if args.quick else 16)
            print_part("fabric", found["fabric"])
        if "sweep" in parts:
            found["sweep"] = [sweep_part(tmp, 8 if args.quick else 32, 224, 40)]
            if not args.quick:
                found["sweep"].append(sweep_part(tmp, 32, 1792, 10))
            for entry in found["sweep"]:
                print_part("sweep", entry)
        if "sync" in parts:
            found["sync"] = sync_part(tmp, 8 if args.quick else 32, 224, 40)
            print_part("sync", found["sync"])
        if "transfer" in parts:
            found["transfer"] = transfer_part(tmp, 4 if args.quick else 32)
            print_part("transfer", found["transfer"])
    found["load_after"] = os.getloadavg()
    print(f"load average before {found['load_before']}, after {found['load_after']}")
    if not args.quick:
        kept = json.loads(OUTPUT.read_text()) if OUTPUT.exists() else {}
        kept.update(found)  # the parts run now replace theirs; the others are kept
        OUTPUT.write_text(json.dumps(kept, indent=2) + "\n")
        print(f"wrote {OUTPUT}")


def print_part(name: str, values: dict) -> None:
    shown = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                      for k, v in values.items())
    print(f"{name}: {shown}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
