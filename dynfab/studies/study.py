"""Studies: many independent runs of one scene on Dask's distributed scheduler (`dynfab study`).

`study(study_file, out)` runs every case of a study file (`dynfab.studies.file`) as a normal
run, each on a worker of a Dask cluster: an embedded `LocalCluster` of local worker
processes by default (`workers` of them, one thread each), or an existing cluster's
scheduler (`scheduler="tcp://HOST:PORT"`). It writes

* ``OUT/cases/case-NNNN.h5``: each case's result file (`dynfab.results.file` layout, its scene
  in it); a failed case's holds its finished steps and the root attributes
  ``study_status = "failed"`` and ``study_message``;
* ``OUT/study.nc``: the gathered table (`dynfab.studies.table`), once every case has ended;
* ``OUT/study.json``: what the folder holds (the study file's text and its fingerprint),
  which `resume` checks; ``OUT/study.lock``: held while a study runs in the folder.

Workers share no disk with this process (the client): the scene travels as text and a
case's results come back here, where its file is written (`dynfab.studies.case`; `sync`
"steps": every finished step appended and synced as it arrives, "end": the whole file
when the case ends, synced once).

Nothing is lost: a case whose solver fails is recorded as failed and the study goes on; a
killed worker's case is given to another worker by the scheduler; a killed study
continues with `resume=True`, which reruns only the cases whose file is not complete
(a begun case's file travels with it and is resumed at its last finished step). Two
studies on one folder: the second is refused (UserError).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import secrets
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from dynfab.errors import UserError
from dynfab.studies.file import Case, Study, case_fields, load_study

SYNCS = ("steps", "end")
"""How a case's results come back and reach its file (module docstring); "steps" is the
default: the guarantee of `dynfab run` for every case."""
CASES = "cases"
TABLE = "study.nc"
RECORD = "study.json"
LOCK = "study.lock"
POLL_S = 0.25
"""Seconds between looks at the queue and the live line while cases run."""
WORKER_WAIT_S = 60.0
"""How long a study waits for a scheduler's first worker before giving up [s]."""


@dataclass
class StudyResult:
    """What `study` did: the table's path and the cases' counts."""

    table: Path
    cases: int
    finished: int
    failed: int
    ran: int
    """Cases run by this call (the rest were already ended: `resume`)."""
    seconds: float
    workers: int
    messages: dict = field(default_factory=dict)
    """Case index -> the message of each failed case."""
    task_seconds: dict = field(default_factory=dict)
    """Case index -> its task's wall time on its worker [s] (the cases run by this call)."""
    write_seconds: float = 0.0
    """Time this process spent writing the cases' files [s] (appends and syncs included)."""
    repeated_steps: int = 0
    """Steps that came twice (a case rerun after its worker died sends again the steps its
    file has) and were skipped."""
    lost_workers: int = 0
    """Workers that left the cluster while cases ran (killed, a machine lost)."""
    rerun_cases: int = 0
    """Cases begun on a worker that was lost and run again on another."""

    def summary(self) -> str:
        """The line printed at the end of `dynfab study`: the cases, and the workers that ran
        them (those lost among them) and the cases run again."""
        lost = f", {self.lost_workers} lost" if self.lost_workers else ""
        rerun = (f"; {self.rerun_cases} case{'s' * (self.rerun_cases != 1)} run again after "
                 "its worker was lost" if self.rerun_cases else "")
        return (f"study: {self.cases} cases, {self.finished} finished, {self.failed} failed; "
                f"{self.ran} run now on {self.workers} worker{'s' * (self.workers != 1)}{lost} "
                f"in {self.seconds:.1f} s{rerun}")


def study(study_file, out, *, scheduler: str | None = None, workers: int | None = None,
          resume: bool = False, sync: str = "steps",
          progress: Callable[[str], None] | None = None,
          status: Callable[[str], None] | None = None,
          stream_interval_s: float | None = None) -> StudyResult:
    """Run a study (a study file's path or a `Study`) into the folder `out`; see the module
    docstring. `progress` receives a line per failed case; `status` the live line (cases
    finished, failed, running, time left), about every POLL_S s. `stream_interval_s`: with
    sync "steps", how soon a running case's steps reach this process [s]
    (`dynfab.studies.case.STREAM_INTERVAL_S` by default)."""
    plan = study_file if isinstance(study_file, Study) else load_study(study_file)
    if sync not in SYNCS:
        raise UserError(f"--sync {sync}: one of {', '.join(SYNCS)}")
    if scheduler is not None and workers is not None:
        raise UserError("--workers sizes the embedded cluster; a --scheduler's cluster has the "
                        "workers its dask worker commands started")
    if workers is not None and workers < 1:
        raise UserError(f"--workers {workers}: at least 1")
    if stream_interval_s is not None and not stream_interval_s >= 0:
        raise UserError(f"--stream-interval {stream_interval_s}: a number of seconds >= 0")
    folder = StudyFolder(Path(out), plan)
    with folder.locked():
        folder.prepare(plan, resume)
        todo = [case for case in plan.cases if folder.state(case)[0] not in ENDED]
        started = time.monotonic()
        worker_count, runner = 0, None
        if todo:
            folder.table.unlink(missing_ok=True)  # a table says every case has ended
            with _cluster(scheduler, workers) as client:
                worker_count = len(client.nthreads())
                runner = _Runner(plan, folder, client, sync, progress, status,
                                 stream_interval_s)
                runner.run(todo)
                worker_count = len(runner.workers_seen) or worker_count
        from dynfab.studies.table import write_table

        write_table(plan, folder, folder.table)
        states = [folder.state(case) for case in plan.cases]
        failed = {case.index: s[1] for case, s in zip(plan.cases, states) if s[0] == "failed"}
        return StudyResult(table=folder.table, cases=len(plan.cases),
                           finished=len(plan.cases) - len(failed), failed=len(failed),
                           ran=len(todo), seconds=time.monotonic() - started,
                           workers=worker_count, messages=failed,
                           task_seconds=runner.task_seconds if runner else {},
                           write_seconds=runner.write_seconds if runner else 0.0,
                           repeated_steps=runner.repeated_steps if runner else 0,
                           lost_workers=len(runner.lost) if runner else 0,
                           rerun_cases=len(runner.rerun) if runner else 0)


ENDED = ("finished", "failed")
"""Case states that need no run."""


# --------------------------------------------------------------------------
# The folder.


class StudyFolder:
    """A study's folder: its lock, its record, its cases' files and their states."""

    def __init__(self, path: Path, plan: Study) -> None:
        self.path = path
        self.cases = path / CASES
        self.table = path / TABLE
        self.width = max(4, len(str(len(plan.cases) - 1)))
        """Digits of a case's number in its file's name."""

    @contextlib.contextmanager
    def locked(self):
        """Hold the folder's lock (refused while another study holds it)."""
        import fcntl

        if self.path.exists() and not self.path.is_dir():
            raise UserError(f"study folder '{self.path}' is a file")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            raise UserError(f"cannot create the study folder '{self.path}': "
                            f"{error.strerror or error}") from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                if error.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                raise UserError(f"study folder '{self.path}' is in use by another dynfab study "
                                f"(pid {holder}): wait for it to end or choose another --out") \
                    from None
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            yield self
        finally:
            os.close(fd)  # releases the lock

    def prepare(self, plan: Study, resume: bool) -> None:
        """Check the folder against `resume` and the study; write its record; clear the
        temporary files of a killed study (the lock is held: no one else writes here)."""
        record = self.path / RECORD
        if record.exists():
            if not resume:
                raise UserError(f"study folder '{self.path}' holds a study: pass --resume to "
                                "continue it, or choose another --out")
            try:
                fingerprint = json.loads(record.read_text()).get("fingerprint")
            except (OSError, ValueError, AttributeError):
                fingerprint = None
            if fingerprint != plan.fingerprint():
                raise UserError(f"cannot resume the study in '{self.path}': it was started from "
                                "a different study (cases, solver or observables)")
        elif resume:
            raise UserError(f"study folder '{self.path}' holds no study: nothing to resume")
        elif self.cases.exists() and any(self.cases.iterdir()):
            raise UserError(f"study folder '{self.path}' has a {CASES}/ folder of another "
                            "study: choose another --out")
        self.cases.mkdir(exist_ok=True)
        for stale in list(self.cases.glob("*.tmp-*")) + list(self.cases.glob("*.part-*")):
            stale.unlink(missing_ok=True)
        if not record.exists():
            _write_atomically(record, json.dumps(
                {"fingerprint": plan.fingerprint(), "study": plan.text,
                 "cases": len(plan.cases)}, indent=1).encode())

    def case_path(self, case: Case) -> Path:
        return self.cases / f"case-{case.index:0{self.width}d}.h5"

    def state(self, case: Case) -> tuple[str, str]:
        """("todo" | "begun" | "finished" | "failed", the failure's message)."""
        import h5py

        from dynfab.results.file import finished_counts

        path = self.case_path(case)
        if not path.exists():
            return "todo", ""
        try:
            with h5py.File(path, "r") as h5:
                failed = h5.attrs.get("study_status") == "failed"
                message = h5.attrs.get("study_message", "")
        except OSError:
            return "todo", ""
        if failed:
            return "failed", message.decode() if isinstance(message, bytes) else str(message)
        counts = finished_counts(path)
        if counts is not None and counts[0] == case.steps:
            return "finished", ""
        return "begun", ""


def _write_atomically(path: Path, data: bytes) -> None:
    """Write `data` to `path` through a temporary file, synced, then renamed."""
    tmp = path.with_name(f"{path.name}.part-{os.getpid()}")
    with open(tmp, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
    with contextlib.suppress(OSError):
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# --------------------------------------------------------------------------
# The cluster.


@contextlib.contextmanager
def _cluster(scheduler: str | None, workers: int | None):
    """A Dask client: of an embedded LocalCluster (`workers` processes, one thread each;
    default one per core), or of the scheduler at `scheduler`."""
    from distributed import Client

    from dynfab.studies.case import worker_info

    if scheduler is None:
        count = workers or os.cpu_count() or 1
        with _workers_deaf_to_ctrl_c():
            cluster = local_cluster(count)
        try:
            with cluster, Client(cluster) as client:
                yield client
        except KeyboardInterrupt:
            # the cluster closes under an interrupt: its scheduler's complaints about the
            # connections closing are no news to the user
            logging.getLogger("distributed").setLevel(logging.CRITICAL + 1)
            raise
        return
    try:
        client = Client(scheduler, timeout=10)
    except (OSError, TimeoutError, ValueError) as error:
        raise UserError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there: "
                        f"{str(error).splitlines()[0] if str(error) else type(error).__name__}") \
            from None
    with client:
        try:
            client.wait_for_workers(1, timeout=WORKER_WAIT_S)
        except TimeoutError:
            raise UserError(f"--scheduler {scheduler}: no worker joined it in {WORKER_WAIT_S:g} s "
                            "(start some with: dask worker ADDRESS --nthreads 1)") from None
        try:
            client.run(worker_info)
        except Exception as error:  # noqa: BLE001 (a worker that cannot run dynfab)
            raise UserError(f"--scheduler {scheduler}: a worker cannot import dynfab: "
                            f"{type(error).__name__}: {error}") from None
        yield client


WORKER_ENVIRONMENT = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
"""Dask settings of the local cluster's workers: Dask's nanny sets MALLOC_TRIM_THRESHOLD_ =
65536 in every worker it spawns, which makes glibc return freed memory at once and fault it
in again at the next allocation (a 16 x 16 patch's case took longer with it:
docs/results.md, "Studies on a Dask cluster"); None leaves glibc's own rule."""


def local_cluster(workers: int):
    """The study's embedded cluster: a LocalCluster of `workers` worker processes on this
    machine, one thread each, no dashboard, its workers spawned with `WORKER_ENVIRONMENT`."""
    import dask
    from distributed import LocalCluster

    with dask.config.set(WORKER_ENVIRONMENT):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR)


@contextlib.contextmanager
def _workers_deaf_to_ctrl_c():
    """Ignore SIGINT while the local cluster's worker processes are spawned: they inherit
    it ignored (Python leaves an ignored SIGINT so), so that a Ctrl-C at the terminal, which
    reaches every process of its group, interrupts the study (this process), which closes
    the cluster, and not each worker with a traceback. A Ctrl-C during these seconds is
    lost. Only from the main thread (elsewhere signals cannot be set)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# --------------------------------------------------------------------------
# Running the cases.


class _Runner:
    """Submits the cases, writes what comes back, shows the live line."""

    def __init__(self, plan: Study, folder: StudyFolder, client, sync: str, progress,
                 status, stream_interval_s: float | None = None) -> None:
        self.plan, self.folder, self.client, self.sync = plan, folder, client, sync
        self.progress, self.status = progress, status
        self.writers: dict[int, object] = {}
        self.done = self.failed = 0
        self.checked = False
        self.queue = None
        self.first_end: float | None = None
        """When the first case of this run ended (the rate of the others gives the time left)."""
        self.task_seconds: dict[int, float] = {}
        self.write_seconds = 0.0
        self.repeated_steps = 0
        self.stream_interval_s = stream_interval_s
        self.shown = 0.0
        """When the live line was last shown."""
        self.last_end: float | None = None
        """When the last case ended (seen at the live line's next showing)."""
        self.ended_shown = 0
        """Cases ended when the live line was last shown."""
        self.workers_seen: set = set()
        """Workers that ran a case (its outcome's), or were in the cluster while cases ran."""
        self.lost: set = set()
        """Workers seen that left the cluster while cases ran."""
        self.rerun: set = set()
        """Cases whose steps came again from a second worker (theirs was lost)."""

    def run(self, todo: list[Case]) -> None:
        from distributed import Queue, wait

        token = secrets.token_hex(6)
        if self.sync == "steps":
            self.queue = Queue(f"dynfab-study-{token}", client=self.client)
        from dynfab.studies.case import run_case

        pending = {}
        for case in todo:
            task = {"index": case.index, "scene": case.text, "solver": self.plan.solver,
                    "sync": self.sync, "queue": self.queue.name if self.queue else None,
                    "partial": self._partial(case)}
            if self.stream_interval_s is not None:
                task["stream_interval"] = self.stream_interval_s
            future = self.client.submit(run_case, task, key=f"dynfab-case-{token}-{case.index}",
                                        pure=False)
            pending[future] = case
        self.started, self.total, self.pending = time.monotonic(), len(todo), pending
        try:
            while pending:
                self._drain()
                try:
                    done = wait(list(pending), timeout=POLL_S, return_when="FIRST_COMPLETED").done
                except TimeoutError:
                    done = set()
                if done:
                    self._drain()
                for future in done:
                    began = time.perf_counter()
                    self._finish(pending.pop(future), future)
                    self.write_seconds += time.perf_counter() - began
                self._show()
        finally:
            for future in pending:
                future.cancel()
            for writer in self.writers.values():
                with contextlib.suppress(Exception):
                    writer.close(trim=False)  # every finished row kept, resumable
            self.writers.clear()
            if self.status is not None:
                self.status("")

    def _partial(self, case: Case) -> bytes | None:
        """A begun case's file, to resume on a worker (None: from its start)."""
        path = self.folder.case_path(case)
        if self.folder.state(case)[0] == "begun":
            return path.read_bytes()
        path.unlink(missing_ok=True)  # unreadable: made before its first step
        return None

    def _drain(self) -> None:
        """Append every step waiting on the queue to its case's file ("steps")."""
        if self.queue is None:
            return
        for message in self.queue.get(batch=True):
            began = time.perf_counter()
            self._append(message)
            self.write_seconds += time.perf_counter() - began
            if time.monotonic() - self.shown >= POLL_S:
                self._show()  # a long drain (a sync per step) keeps the line live

    def _append(self, message: dict) -> None:
        from dynfab.results.file import ResultFile
        from dynfab.results.views import add_views

        index = message["case"]
        case = self.plan.cases[index]
        writer = self.writers.get(index)
        if writer is None:
            path = self.folder.case_path(case)
            if path.exists():
                writer = ResultFile.resume(path, step_capacity=case.steps, views=add_views)
            else:
                attrs, reference = message["head"]
                writer = ResultFile.create(path, attrs=attrs, reference=reference,
                                           step_capacity=case.steps, views=add_views)
            self.writers[index] = writer
        for row, step in enumerate(message["steps"], start=message["first"]):
            if row < writer.step_count:
                self.repeated_steps += 1  # a case rerun after its worker died
                self.rerun.add(index)
                continue
            if row > writer.step_count:
                raise RuntimeError(f"case {index}: step {row + 1} arrived before step "
                                   f"{writer.step_count + 1}")
            writer.append_step(step)

    def _finish(self, case: Case, future) -> None:
        """Write the case's end: close its streamed file, or write the file that came back."""
        if future.status == "error":
            error = future.exception()
            outcome = {"status": "failed", "file": None,
                       "message": f"{type(error).__name__}: {error}"}
        else:
            outcome = future.result()
            self.task_seconds[case.index] = outcome["seconds"]
            if outcome.get("worker"):
                self.workers_seen.add(outcome["worker"])
        path = self.folder.case_path(case)
        writer = self.writers.pop(case.index, None)
        if outcome["status"] == "finished":
            if outcome["file"] is not None:
                if writer is not None:
                    writer.close(trim=False)
                _write_atomically(path, outcome["file"])
            elif writer is None or writer.step_count != case.steps:
                raise RuntimeError(f"case {case.index}: finished with "
                                   f"{0 if writer is None else writer.step_count} of "
                                   f"{case.steps} steps received")
            else:
                writer.close()
            self.done += 1
            self._check_observables(case)
            return
        if writer is not None:
            writer.close(trim=False)
        _write_failed(path, case, self.plan.solver, outcome)
        self.failed += 1
        if self.progress is not None:
            self.progress(f"case {case.index} failed ({case_fields(self.plan, case)}): "
                          f"{outcome['message']}")

    def _check_observables(self, case: Case) -> None:
        """Once, on the first finished case: every observable's dataset is in its file."""
        if self.checked:
            return
        import h5py

        with h5py.File(self.folder.case_path(case), "r") as h5:
            have = []
            h5["steps"].visititems(lambda name, obj: have.append(name)
                                   if isinstance(obj, h5py.Dataset) else None)
        for observable in self.plan.observables:
            if observable.dataset not in have:
                raise UserError(f"observe.{observable.name}: this scene's runs write no "
                                f"steps/{observable.dataset}; they write: "
                                + ", ".join(sorted(n for n in have if "/" not in n)))
        self.checked = True

    def _show(self) -> None:
        self.shown = now = time.monotonic()
        nthreads = self.client.nthreads()
        present = set(nthreads)
        self.lost |= self.workers_seen - present
        self.workers_seen |= present
        if self.status is None:
            return
        total, pending = self.total, len(self.pending)
        ended = self.done + self.failed
        if ended and self.first_end is None:
            self.first_end = now
        if ended != self.ended_shown:  # a case ended since the line was last shown
            self.last_end, self.ended_shown = now, ended
        running = min(pending, sum(nthreads.values()) or 1)
        parts = [f"cases: {self.done} finished, {self.failed} failed, {running} running, "
                 f"{pending - running} waiting of {total}",
                 time_left(self.started, self.first_end, self.last_end, ended, pending, now)]
        if self.lost:
            parts.append(f"{len(self.lost)} worker{'s' * (len(self.lost) != 1)} lost")
        if self.rerun:
            parts.append(f"{len(self.rerun)} case{'s' * (len(self.rerun) != 1)} rerun")
        self.status(fit_line(parts, shutil.get_terminal_size().columns))


def time_left(started: float, first_end: float | None, last_end: float | None, ended: int,
              pending: int, now: float) -> str:
    """The live line's time left, counting down between the cases' ends: the pace of the ended
    cases (after the first, which paid the workers' start) times the cases pending, from the
    last end, less the time since it."""
    if not ended or last_end is None:
        return "time left: unknown yet"
    pace = (last_end - first_end) / (ended - 1) if ended > 1 else first_end - started
    return f"about {_duration(max(last_end + pace * pending - now, 0.0))} left"


def fit_line(parts: list[str], width: int) -> str:
    """The parts joined by "; ", as many from the first as fit in `width` - 1 columns (the
    first always: the counts)."""
    line = parts[0]
    for part in parts[1:]:
        if len(line) + 2 + len(part) > width - 1:
            break
        line = f"{line}; {part}"
    return line


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _write_failed(path: Path, case: Case, solver: str, outcome: dict) -> None:
    """A failed case's file: the file that came back (its finished steps) or, without one,
    a result file of its scene with no step; with the study's failure attributes."""
    from dynfab.results.file import ResultFile

    tmp = path.with_name(f"{path.name}.part-{os.getpid()}")
    tmp.unlink(missing_ok=True)
    message = outcome["message"] or "failed"
    if outcome.get("file") is not None:
        tmp.write_bytes(outcome["file"])
        writer = ResultFile.resume(tmp)
    else:
        writer = ResultFile.create(tmp, attrs={"scene": case.text, "solver": solver},
                                   reference={})
    writer.set_attrs(study_status="failed", study_message=message)
    writer.close()
    with open(tmp, "rb+") as handle:
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def ended_counts(out, plan: Study) -> tuple[int, int]:
    """(cases ended, cases) of the study `plan` in the folder `out`, for the line after an
    interrupt."""
    folder = StudyFolder(Path(out), plan)
    return sum(folder.state(case)[0] in ENDED for case in plan.cases), len(plan.cases)
