"""One case of a study, run on a Dask worker (`dynfab study`): what travels, and how back.

A worker shares no disk with the study's client (on a real cluster it is another
machine), so the case's scene travels as TOML text, and its results travel back to the
client, which writes the case's file in the study's folder. On the worker the case is a
normal `dynfab.run.run_to_file` into a scratch folder of its own (in memory, /dev/shm,
where the machine has one, so that the run's per-step disk syncs cost nothing there: the
client's file is the one kept), removed when the case ends. How the results travel is
the study's `sync`:

* "steps": once the case has run `STREAM_INTERVAL_S`, the worker puts its finished load
  steps' rows on a Dask queue (`distributed.Queue`, through the scheduler), then those
  finished since at most every `STREAM_INTERVAL_S`, the first message with the file's
  root attributes and reference; the client appends each step to the case's file at once,
  synced, as a run does. A message is a round trip through the scheduler, which would
  cost a short case more than its run: a case that ends within the first interval comes
  back whole, as in "end".
* "end": the worker returns the finished file's bytes with the task's result; the client
  writes them in one go, synced once.

A case the client had begun (a study killed in "steps") travels with its file's bytes
(`partial`) and is resumed from its last finished step (`run_to_file(resume=True)`).

A solver failure (SolverError), or any other error of the case, ends the task normally
with status "failed" and the message, and the file (its finished steps) in its bytes:
a failed case is recorded, and the study goes on. A worker that dies takes its task
with it; the scheduler gives it to another worker (Dask's allowed failures).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

STREAM_INTERVAL_S = 1.0
"""Least time between two messages of a case's steps, and before the first ("steps") [s]: a
finished step reaches the client within about this (plus the transfer)."""
SCRATCH_ROOTS = ("/dev/shm",)
"""Folders in memory tried first for a case's scratch file (then the system's temp folder)."""


def scratch_folder() -> Path:
    """A new private folder for one case's scratch file on this machine."""
    for root in SCRATCH_ROOTS:
        if os.path.isdir(root) and os.access(root, os.W_OK):
            try:
                return Path(tempfile.mkdtemp(prefix="dynfab-case-", dir=root))
            except OSError:
                pass
    return Path(tempfile.mkdtemp(prefix="dynfab-case-"))


def run_case(task: dict) -> dict:
    """Run one case on this worker; its outcome (module docstring).

    `task`: ``index``, ``scene`` (TOML text), ``solver``, ``sync`` ("steps", "end"),
    ``queue`` (the queue's name, "steps" only), ``stream_interval`` (STREAM_INTERVAL_S
    unless given), ``partial`` (the bytes of a begun case's file, or None). Returns ``index``, ``status`` ("finished", "failed"), ``message``,
    ``file`` (the case file's bytes: "end", a failed case, or a case that ended before its
    first message; else None), ``seconds``
    (the task's wall time [s]), ``worker`` (its address), ``pid``.
    """
    started = time.perf_counter()
    from dynfab.errors import SolverError
    from dynfab.run import run_to_file
    from dynfab.scene import parse_scene_text

    folder = scratch_folder()
    path = folder / "case.h5"
    status, message = "finished", ""
    try:
        resume = task.get("partial") is not None
        if resume:
            path.write_bytes(task["partial"])
        stream = None
        if task["sync"] == "steps":
            from dynfab.results.file import finished_counts

            begun = (finished_counts(path) or (0, 0))[0] if resume else 0
            stream = _Stream(task["queue"], task["index"], path, begun,
                             task.get("stream_interval", STREAM_INTERVAL_S))
        try:
            scene = parse_scene_text(task["scene"], source=f"case {task['index']}")
            run_to_file(scene, task["solver"], path, resume=resume, progress=stream)
        except SolverError as error:
            status, message = "failed", str(error)
        except Exception as error:  # noqa: BLE001 (any error of a case is recorded, not fatal)
            status, message = "failed", f"{type(error).__name__}: {error}"
        streamed = stream is not None and stream.sent_head
        if streamed and status == "finished":
            stream.send()  # the steps since the last message
        keep = not streamed or status == "failed"
        data = path.read_bytes() if keep and path.is_file() else None
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return {"index": task["index"], "status": status, "message": message, "file": data,
            "seconds": time.perf_counter() - started, "worker": _worker_address(),
            "pid": os.getpid()}


class _Stream:
    """The `progress` of the worker's run in "steps": the finished steps' rows, read back
    from the scratch file, put on the study's queue at most every STREAM_INTERVAL_S."""

    def __init__(self, queue_name: str, index: int, path: Path, begun: int,
                 interval: float) -> None:
        self.queue, self.interval = _queue(queue_name), interval
        self.index, self.path, self.sent_head = index, path, False
        self.sent_rows = begun
        """Rows the client has: those of the file the case resumed, then those sent."""
        self.last = time.monotonic()
        """When the last message went (or the case began)."""

    def __call__(self, line: str) -> None:
        if time.monotonic() - self.last >= self.interval:
            self.send()

    def send(self) -> None:
        """Put the rows finished since the last message (none: nothing) on the queue."""
        first, steps = read_rows(self.path, self.sent_rows)
        self.last = time.monotonic()
        if not steps:
            return
        message = {"case": self.index, "first": first, "steps": steps}
        if not self.sent_head:
            message["head"] = read_head(self.path)
            self.sent_head = True
        self.queue.put(message)
        self.sent_rows = first + len(steps)


_QUEUES: dict = {}
"""This worker's handle of each study's queue, by name (made once: a handle costs a round
trip to the scheduler)."""


def _queue(name: str):
    from distributed import Queue

    if name not in _QUEUES:
        _QUEUES.clear()  # one study at a time per worker, as a rule: keep the latest
        _QUEUES[name] = Queue(name)
    return _QUEUES[name]


def read_rows(path: Path, first: int) -> tuple[int, list[dict]]:
    """(first, [{name: value}, ...]): the finished rows of steps/ of a result file from row
    `first` on."""
    import h5py

    with h5py.File(path, "r") as h5:
        done = int(h5["steps_done"][0])
        columns: dict = {}
        h5["steps"].visititems(lambda name, obj: columns.__setitem__(name, obj[first:done])
                               if isinstance(obj, h5py.Dataset) else None)
    return first, [{name: rows[i] for name, rows in columns.items()}
                   for i in range(done - first)]


def read_head(path: Path) -> tuple[dict, dict]:
    """(root attributes, reference datasets) of a result file, as `ResultFile.create` takes
    them."""
    import h5py

    from dynfab.results.file import read_results

    with h5py.File(path, "r") as h5:
        names: list[str] = []
        if "reference" in h5:
            h5["reference"].visititems(lambda name, obj: names.append(f"reference/{name}")
                                       if isinstance(obj, h5py.Dataset) else None)
    results = read_results(path, only=names)
    return results.attrs, results.reference


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return ""


def worker_info() -> dict:
    """What a worker runs (`Client.run` before a study): dynfab's version, its pid, cores."""
    import dynfab

    return {"dynfab": dynfab.__version__, "pid": os.getpid(), "cpus": os.cpu_count()}
