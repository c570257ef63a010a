"""The dynamic solver: dynamic relaxation of each load step with Warp kernels
(docs/model.md section 5).

Each load step starts from the previous state (under displacement control with
`dynfab.loading.prescribe_load`), integrates the equations of motion of every
yarn (one Warp thread per yarn, the time loop inside the kernel, a bounded
chunk of steps per launch) until the residual, the largest free force
component including friction, is below the tolerance, then finishes the step
with `dynfab.observables.finish_step` (return mapping of the friction anchors,
the step record) exactly as the static reference does.

Integrators (`dynfab.kernels`): `explicit` symplectic Euler with kinetic
damping (Barnes), viscous damping (given c, or adaptive after Underwood) or
FIRE 2.0; `semi_implicit` linearly implicit backward Euler with its own time
step rule (viscous c if one is given; its steps undo themselves instead of
being damped). Masses fictitious (Gershgorin, dt = 1 s) or physical (dt from
the Gershgorin bound times `safety`).

Cores. A Warp launch on the CPU runs its threads one after another on one core,
and releases the GIL while it runs (the compiled kernel is called through ctypes).
A batch of yarns ([sweep] entries or geometry.yarns) is therefore split into
contiguous groups, one per core (`DynamicSolver.use_cores`), and each launch
becomes one launch per group, on views of the same arrays, issued at once from
this thread and from a small pool of worker threads. Thread y of a group's launch
does exactly the arithmetic thread first + y does in a launch of all the yarns,
so a split run gives bit-identical results; each group stops being launched once
all its yarns have finished. One yarn is one thread, with nothing to split; from
SPLIT_MIN_YARNS = 2 yarns on the solver splits (`python benchmarks/dynamic.py` measures
the gain on a quiet machine: docs/results.md, "Batched yarns split across the cores").
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os
import threading
import warnings
from typing import NamedTuple

import numpy as np
import warp as wp

from dynfab.certificate import (MAX_ESCAPES, NEGATIVES, StepStability, certify_yarn, check_accuracy,
                                escape_yarn)
from dynfab.errors import UserError, SolverError
from dynfab.kernels import explicit, fire, motion as motion_module, semi_implicit
from dynfab.kernels import settings as settings_module, transient
from dynfab.kernels import runtime, status, yarn_arrays
from dynfab.kernels.configuration import Configuration
from dynfab.kernels.precision import DEFAULT_TOLERANCE, SCALARS
from dynfab.loading import load_at_time, prescribe_load
from dynfab.model import State
from dynfab.observables import finish_step
from dynfab.scene import Dynamic, check_dynamic_options

STEPS_PER_LAUNCH = 2000
"""Time steps a launch may take before Python regains control (progress, Ctrl-C)."""
_SADDLE_HINT = {"semi_implicit": " (semi_implicit accepts only steps that lower the residual, "
                                  "which cannot lead away from a saddle: use dynamic.method = "
                                  "\"explicit\")"}
"""Why a relaxation restarted from a saddle's escape may not converge, per method."""
MAX_TIGHTENINGS = 3
"""Times a load step relaxed to the default tolerance is relaxed further because its error
bound exceeds the accuracy target (`DynamicSolver._certify`)."""
SPLIT_MIN_YARNS = 2
"""Fewest yarns whose launches are split across cores (one yarn is one thread: nothing to
split)."""


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


_POOL: concurrent.futures.ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _worker_pool() -> concurrent.futures.ThreadPoolExecutor:
    """The process's pool of launch threads (one per core but the caller's), made on first use."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = concurrent.futures.ThreadPoolExecutor(
                max_workers=max(1, available_cores() - 1), thread_name_prefix="dynfab-launch")
        return _POOL


class YarnGroup(NamedTuple):
    """Yarns first..stop-1, launched together: their YarnArrays and Motion (views)."""

    first: int
    stop: int
    yarn: object
    motion: object


class DynamicSolver:
    """Relaxes a model's load steps one after another with Warp kernels
    (docs/model.md section 5)."""

    name = "dynamic"

    def __init__(self, model, options: Dynamic | None = None, device: str = "cpu", progress=None):
        self.model = model
        self.options = model.scene.dynamic if options is None else check_dynamic_options(options)
        self.device = device
        self._tolerance_override = None  # a tighter residual the accuracy target asks for [N]
        self.progress = progress
        self._dt_warned = False
        self.damping = self.options.damping_used()
        self.masses = self.options.masses_used()
        self.tolerance = self.options.tolerance or DEFAULT_TOLERANCE[self.options.precision]
        self.scalar = SCALARS[self.options.precision]
        explicit_method = self.options.method == "explicit"
        self.configuration = Configuration(
            precision=self.options.precision, terms=model.terms, method=self.options.method,
            damping=self.damping if explicit_method else None, mode=self.options.mode)
        runtime.initialize(device)
        self._kernel = (explicit.relaxation_kernel if self.options.method == "explicit"
                        else semi_implicit.relaxation_kernel)
        self.yarn = yarn_arrays.upload(model, self.scalar, device)
        self.motion = motion_module.allocate(self.scalar, model.yarn_count, model.segments + 1,
                                             model.crossings, device)
        self._loaded = set()
        self.use_cores(None)

    def use_cores(self, cores: int | None = None) -> None:
        """Launch the yarns on up to `cores` CPU cores (None: every core this process may run
        on; 1: one launch of all the yarns). The yarns are split into min(cores, yarns)
        contiguous groups of nearly equal size when there are at least SPLIT_MIN_YARNS of
        them on a CPU device; results are bit-identical whatever the split."""
        self.cores = available_cores() if cores is None else max(1, int(cores))
        yarns = self.model.yarn_count
        splits = str(self.device).startswith("cpu") and yarns >= SPLIT_MIN_YARNS
        count = min(self.cores, yarns) if splits else 1
        if count == 1:
            self.groups = [YarnGroup(0, yarns, self.yarn, self.motion)]
            return
        bounds = np.linspace(0, yarns, count + 1).round().astype(int)
        self.groups = [YarnGroup(int(a), int(b), yarn_arrays.view(self.yarn, a, b),
                                 motion_module.view(self.motion, a, b))
                       for a, b in zip(bounds[:-1], bounds[1:])]

    def attrs(self) -> dict:
        """Root attributes describing the solver, for the result file."""
        return {"solver": self.name, "dynamic_mode": self.options.mode,
                "dynamic_method": self.options.method, "dynamic_damping": self.damping,
                "dynamic_masses": self.masses,
                "dynamic_dt": "auto" if self.options.dt is None else self.options.dt,
                "dynamic_safety": self.options.safety, "dynamic_tolerance": self.tolerance,
                "dynamic_max_steps": self.options.max_steps,
                "dynamic_precision": self.options.precision,
                "dynamic_accuracy": self.options.accuracy}

    def predicted_stable_dt(self, state, load_value: float = 0.0) -> np.ndarray:
        """Gershgorin's stable time step [s] per yarn at the start of a load step (of a
        transient run: at t = 0, zero load), for this solver's masses (docs/model.md section 5):
        2 min_i sqrt(m_i / sum_j |K_ij|)."""
        if self.options.mode == "transient":
            self._start_transient(state)
        else:
            self._launch(state, load_value, steps=0)
        return self.motion.stable_dt.numpy().astype(float)

    def last_relaxation(self) -> dict:
        """What the last relaxation left, per yarn, also after a SolverError (copies):
        "time_steps" of its last launch, "masses" [kg] (N+1 nodes, as chosen at the step's
        start) and "energy_ratio" [-] (kinetic energy over work done, the divergence check)."""
        return {"time_steps": self.motion.steps.numpy().copy(),
                "masses": self.motion.mass.numpy().copy(),
                "energy_ratio": self.motion.energy_ratio.numpy().copy()}

    def step(self, state, load_value: float):
        """Relax every yarn under `load_value`; returns (new state, record) or raises SolverError
        (the `dynfab.solver.Solver` contract)."""
        if self.options.mode == "transient":
            raise UserError('dynamic.mode = "transient" runs by time, not by load step: '
                             "use DynamicSolver.transient(state), which yields frames")
        self._tolerance_override = None
        codes = self._launch(state, load_value, steps=STEPS_PER_LAUNCH)
        self._warn_if_dt_above_bound()
        while (codes == status.RUNNING).any():
            codes = self._launch(None, load_value, steps=STEPS_PER_LAUNCH)
        self._raise_on_failure(codes)
        positions, residual, steps, stability, at_floor = self._certify(state, load_value, codes)
        new_state, record = finish_step(self.model, state, positions, load_value, residual, steps)
        record["rounding_floor"] = at_floor
        record.update(stability.fields())
        record["time_steps"] = steps
        record["force_evaluations"] = self.motion.force_evaluations.numpy().astype(np.int64)
        record["dt"] = self.motion.dt.numpy().astype(float)
        record["tolerance"] = self.motion.tolerance.numpy().astype(float)
        return new_state, record

    def _certify(self, state, load_value: float, codes: np.ndarray):
        """Certify every relaxed yarn (`dynfab.certificate`, docs/model.md section 6): a yarn on a
        saddle is moved along its escape direction and every yarn relaxed again from there (at most
        MAX_ESCAPES times); then the accuracy check. With the default tolerance, a step whose
        error bound exceeds the accuracy target is relaxed further, to the residual that
        target needs (at most MAX_TIGHTENINGS times), before the check decides. Returns
        (positions, residual [N], time steps, StepStability, at rounding floor)."""
        model = self.model
        steps = self.motion.steps.numpy().astype(np.int64)
        for tightening in range(MAX_TIGHTENINGS + 1):
            certificates, codes, steps, buckled = self._escape_saddles(state, load_value, codes,
                                                                       steps)
            positions = self._positions()
            residual = self.motion.residual.numpy().astype(float)
            stability = StepStability(model.yarn_count)
            stability.buckled[:] = buckled
            for k, (result, _) in enumerate(certificates):
                stability.record(k, result, residual[k])
            at_floor = codes == status.ROUNDING_FLOOR
            needed = self._residual_needed(stability, positions, residual, at_floor)
            if needed is None or tightening == MAX_TIGHTENINGS:
                break
            self._tolerance_override = needed
            codes = self._relax(dataclasses.replace(state, positions=positions), load_value)
            self._raise_on_failure(codes)
            steps = steps + self.motion.steps.numpy().astype(np.int64)
        tolerance = self.motion.tolerance.numpy().astype(float)  # each yarn's, for this step
        for k in range(model.yarn_count):
            check_accuracy(f"yarn {k + 1}", stability.error_estimate[k],
                           stability.scale(positions[k], model.yarns[k].rest_position),
                           residual[k], tolerance[k], self.options.accuracy, bool(at_floor[k]),
                           self.options.precision, "dynamic.accuracy", stability.shift[k])
        return positions, residual, steps, stability, at_floor

    def _escape_saddles(self, state, load_value: float, codes: np.ndarray, steps: np.ndarray):
        """Certify every yarn; move each one on a saddle along its escape and relax again, at
        most MAX_ESCAPES times. Returns (certificates, codes, time steps, buckled flags)."""
        model, fixed = self.model, self.model.fixed_dofs()
        buckled = np.zeros(model.yarn_count, np.bool_)
        P = load_value if model.control == "force" else 0.0
        for attempt in range(MAX_ESCAPES + 1):
            positions = self._positions()
            residual = self.motion.residual.numpy().astype(float)
            certificates = [certify_yarn(positions[k], yarn, state.anchors[k], fixed, residual[k])
                            for k, yarn in enumerate(model.yarns)]
            restart, moved = positions.copy(), False
            for k, (result, directions) in enumerate(certificates):
                if attempt < MAX_ESCAPES and result[NEGATIVES] > 0:
                    escaped = escape_yarn(positions[k], model.yarns[k], P, state.anchors[k],
                                          result, directions)
                    if escaped is not None:
                        restart[k], moved, buckled[k] = escaped, True, True
            if not moved:
                break
            codes = self._relax(dataclasses.replace(state, positions=restart), load_value)
            try:
                self._raise_on_failure(codes)
            except SolverError as error:
                hint = _SADDLE_HINT.get(self.options.method, "")
                raise SolverError(f"{error}; relaxing from a saddle's escape{hint}") from error
            steps = steps + self.motion.steps.numpy().astype(np.int64)
        return certificates, codes, steps, buckled

    def _relax(self, state, load_value: float) -> np.ndarray:
        """Relax every yarn from `state` (the load step's anchors) to the end; the status codes."""
        codes = self._launch(state, load_value, steps=STEPS_PER_LAUNCH)
        while (codes == status.RUNNING).any():
            codes = self._launch(None, load_value, steps=STEPS_PER_LAUNCH)
        return codes

    def _residual_needed(self, stability, positions, residual, at_floor) -> float | None:
        """With the default tolerance (none given), the residual [N] that brings every yarn's
        error bound within the accuracy target, if some yarn's bound exceeds it and is not at
        its rounding floor (there, relaxing further cannot help: the check stops the run);
        half the largest residual the target allows, for a margin. None otherwise."""
        if self.options.tolerance is not None:
            return None
        needed = []
        for k, yarn in enumerate(self.model.yarns):
            target = self.options.accuracy * stability.scale(positions[k], yarn.rest_position)
            bound = stability.error_estimate[k]
            if bound > target and np.isfinite(bound) and residual[k] > 0 and not at_floor[k]:
                needed.append(0.5 * target * residual[k] / bound)
        return min(needed) if needed else None

    def transient(self, state, resume_from: dict | None = None):
        """Run the transient (dynamic.mode = "transient", docs/model.md section 5) from `state`;
        yield frames.

        Physical masses, viscous c (default 0), anchors return-mapped every time step,
        the load ramped piecewise-linearly from 0 at t = 0 through the load values evenly
        spaced over `duration`. One frame (`frames/*` of the result file) at t = 0 and
        every `output_interval`, the last at `duration`; the time step, at most the
        Gershgorin dt (or dynamic.dt), is shortened to land on every frame time.

        `resume_from`, a frame this run wrote, continues from it: the masses and time
        step are still chosen from `state` (the run's state at t = 0) and the frame's
        positions, velocities and anchors replace the kernel's, so a resumed run takes
        the very same steps as an uninterrupted one.
        """
        options = self.options
        kernel, load_path = self._start_transient(state)
        largest_dt = float(self.motion.dt.numpy().min())
        times = np.append(np.arange(0.0, options.duration, options.output_interval),
                          options.duration)
        first = 0
        if resume_from is None:
            yield self._frame(0.0)
        else:
            first = int(np.argmin(np.abs(times - float(resume_from["time"]))))
            motion_module.restore(self.motion, resume_from, self.scalar, self.device)
        for start, end in zip(times[first:-1], times[first + 1:]):
            steps = int(np.ceil((end - start) / largest_dt * (1 - 1e-12)))
            dt = (end - start) / steps
            for done in range(0, steps, STEPS_PER_LAUNCH):
                self._advance(kernel, load_path, time=start + done * dt, dt=dt,
                              steps=min(STEPS_PER_LAUNCH, steps - done))
            yield self._frame(end)

    def _start_transient(self, state):
        """Load `state` and let the transient kernel choose masses and dt; (kernel, load path)."""
        kernel = transient.transient_kernel(self.configuration)
        load_path = wp.array(self.model.load_values, dtype=self.scalar, device=self.device)
        motion_module.start_load_step(self.motion, state.positions, state.anchors, self.scalar,
                                      self.device)
        self._advance(kernel, load_path, time=0.0, dt=self.options.dt or 0.0, steps=0)
        return kernel, load_path

    def _advance(self, kernel, load_path, time: float, dt: float, steps: int) -> None:
        """One launch of the transient kernel: `steps` time steps of `dt` [s] from `time` [s]."""
        settings = settings_module.fill(
            self.scalar, tolerance=0.0, safety=self.options.safety, fixed_dt=dt,
            fictitious=0, damping_coefficient=self.options.damping_coefficient or 0.0,
            max_steps=0, chunk=steps, time=time, duration=self.options.duration)
        self._run(kernel, self.groups, settings, load_path)
        codes = self.motion.status.numpy()
        self._report(codes)
        self._raise_on_failure(codes, allowed=(status.RUNNING,))

    def _frame(self, time: float) -> dict:
        """One transient frame: time, positions, velocities, nodal forces, contact forces,
        anchors and the energy of every term (as `finish_step` reports them) plus the
        kinetic energy [J]."""
        positions = self._positions()
        velocities = self.motion.velocity.numpy().astype(np.float64)
        load = load_at_time(self.model, time)
        yarns = self.model.yarn_count
        state = State(positions=positions, anchors=self.motion.anchors.numpy().astype(np.float64),
                      dissipated=np.zeros(yarns), load=np.full(yarns, load))
        _, record = finish_step(self.model, state, positions, load, np.zeros(yarns),
                                np.zeros(yarns, np.int64))
        frame = {"time": time, "positions": positions, "velocities": velocities,
                 "force": self.motion.force.numpy().astype(np.float64),
                 "contact_force": record["contact_force"], "anchors": record["anchors"]}
        frame.update({name: value for name, value in record.items() if name.startswith("energy/")})
        masses = self.model.stacked("mass")
        frame["energy/kinetic"] = 0.5 * np.sum(masses[:, :, None] * velocities ** 2, axis=(1, 2))
        return frame

    def _launch(self, state, load_value: float, steps: int) -> np.ndarray:
        """Run up to `steps` time steps of every running yarn; a `state` starts a new load step.

        Returns the status code of every yarn (`dynfab.kernels.status`).
        """
        groups = self.groups
        if state is not None:
            positions = prescribe_load(self.model, state, load_value)
            motion_module.start_load_step(self.motion, positions, state.anchors, self.scalar,
                                          self.device)
        elif len(groups) > 1:  # a group whose yarns have all finished is not launched again
            codes = self.motion.status.numpy()
            groups = [g for g in groups if (codes[g.first:g.stop] == status.RUNNING).any()]
        self._run(self._kernel(self.configuration), groups, self._settings(load_value, steps))
        codes = self.motion.status.numpy()
        self._report(codes)
        return codes

    def _run(self, kernel, groups, *inputs) -> None:
        """One launch of `kernel` per group with the group's (yarn, motion) and `inputs`, the
        groups on separate cores at once (this thread and the worker pool's); returns when
        every launch has finished (a CPU launch is synchronous)."""
        if len(groups) == 1:
            group = groups[0]
            wp.launch(kernel, dim=group.stop - group.first,
                      inputs=[group.yarn, group.motion, *inputs], device=self.device)
            return
        if kernel not in self._loaded:  # load (or compile) once, not from two threads at once
            wp.load_module(kernel.module, device=self.device, block_dim=1)
            self._loaded.add(kernel)

        def launch(group):
            wp.launch(kernel, dim=group.stop - group.first, block_dim=1,
                      inputs=[group.yarn, group.motion, *inputs], device=self.device)

        pool = _worker_pool()
        futures = [pool.submit(launch, group) for group in groups[1:]]
        try:
            launch(groups[0])
        finally:
            for future in futures:
                future.result()

    def _settings(self, load_value: float, steps: int):
        """The kernel's Settings for one launch of `steps` time steps."""
        coefficient = self.options.damping_coefficient
        return settings_module.fill(
            self.scalar, end_load=load_value if self.model.control == "force" else 0.0,
            tolerance=self._tolerance_override or self.tolerance, safety=self.options.safety,
            relative_tolerance=(settings_module.RELATIVE_TOLERANCE
                                if self.options.tolerance is None and not self._tolerance_override
                                else 0.0),
            fixed_dt=self.options.dt or 0.0, fictitious=int(self.masses == "fictitious"),
            damping_coefficient=-1.0 if coefficient is None else coefficient,
            max_steps=self.options.max_steps, chunk=steps)

    def _positions(self) -> np.ndarray:
        """Node positions (yarns, N+1, 2) [m] as float64."""
        return self.motion.position.numpy().astype(np.float64)

    def _report(self, codes: np.ndarray) -> None:
        """One progress line per launch, if a progress callback was given."""
        if self.progress is None:
            return
        steps, residual = self.motion.steps.numpy(), self.motion.residual.numpy()
        running = int((codes == status.RUNNING).sum())
        tolerance = self.motion.tolerance.numpy().min()
        self.progress(f"dynamic: {steps.max()} time steps, residual {residual.max():.3g} N "
                      f"(tolerance {tolerance:.3g} N), {running} of {codes.size} yarns running")

    def _raise_on_failure(self, codes: np.ndarray, allowed=status.SUCCESS) -> None:
        """SolverError with one line naming the first failed yarn, unless every code is allowed."""
        for k, code in enumerate(codes):
            if code not in allowed:
                raise SolverError(self._failure_message(k, int(code)))

    def _warn_if_dt_above_bound(self) -> None:
        """A given dt above the predicted stable dt is allowed (Gershgorin is conservative),
        with a warning, once per solver (docs/model.md section 5). Fictitious masses scale with dt:
        no bound."""
        if self.options.dt is None or self.masses == "fictitious" or self._dt_warned:
            return
        bound = float(self.motion.stable_dt.numpy().min())
        if self.options.dt > bound:
            self._dt_warned = True
            warnings.warn(f"dynamic.dt = {self.options.dt:.3g} s is above the predicted stable "
                          f"time step {bound:.3g} s (Gershgorin, conservative): allowed, but the "
                          f"run may diverge (it then stops with exit status 3)",
                          RuntimeWarning, stacklevel=3)

    def _failure_message(self, k: int, code: int) -> str:
        """What went wrong with yarn k, the numbers behind it, and the likely cause."""
        steps = int(self.motion.steps.numpy()[k])
        residual = float(self.motion.residual.numpy()[k])
        start = float(self.motion.start_residual.numpy()[k])
        dt, bound = float(self.motion.dt.numpy()[k]), float(self.motion.stable_dt.numpy()[k])
        where = f"yarn {k + 1}"
        if code in (status.DIVERGED, status.NON_FINITE):
            cause = ("the time step is above the stability bound: lower dynamic.dt or leave it unset"
                     if dt > bound else
                     "a stiffness the bound did not foresee (large strain, a contact closing): "
                     "lower dynamic.safety")
            growth = ("the state became non-finite" if code == status.NON_FINITE else
                      f"the residual grew to {residual:.3g} N from {start:.3g} N"
                      if self._energy_ratio(k) <= status.ENERGY_FACTOR else self._energy_growth(k))
            return (f"{where}: the {self.options.method} integration diverged after {steps} time "
                    f"steps ({growth}); dt = {dt:.3g} s against the predicted stable dt = "
                    f"{bound:.3g} s (Gershgorin); likely cause: {cause}")
        if code == status.STALLED:
            return (f"{where}: FIRE stalled after {steps} time steps (the power stayed negative "
                    f"for {fire.MAX_NEGATIVE_STEPS} steps); residual {residual:.3g} N")
        if code == status.NO_PROGRESS:
            best = float(self.motion.best_residual.numpy()[k])
            since = int(self.motion.steps_since_best.numpy()[k])
            return (f"{where}: the semi_implicit relaxation stopped making progress: its residual "
                    f"has not fallen below {best:.3g} N during the last {since} of {steps} time "
                    f"steps (tolerance {float(self.motion.tolerance.numpy()[k]):.3g} N)"
                    f"{self._open_crossing_hint(k)}")
        if code == status.NOT_POSITIVE_DEFINITE:
            return (f"{where}: the semi_implicit matrix had a pivot that is not positive at every "
                    f"time step tried after {steps} steps; residual {residual:.3g} N")
        return (f"{where}: no convergence in {steps} time steps (dynamic.max_steps); residual "
                f"{residual:.3g} N, tolerance {float(self.motion.tolerance.numpy()[k]):.3g} N"
                f"{self._above_bound_hint(dt, bound) or self._open_crossing_hint(k)}")

    @staticmethod
    def _above_bound_hint(dt: float, bound: float) -> str:
        """A step limit reached with dt above the predicted stable dt: a mode just beyond its
        limit can oscillate at a bounded amplitude (the nonlinear terms stop its growth),
        which no divergence test sees but which keeps the residual up."""
        if not dt > bound:
            return ""
        return (f"; dt = {dt:.3g} s is above the predicted stable dt = {bound:.3g} s "
                "(Gershgorin): a mode beyond its stability limit may be oscillating without "
                "growing; lower dynamic.dt or dynamic.safety")

    def _energy_ratio(self, k: int) -> float:
        """Yarn k's largest kinetic energy / work bound of the load step (explicit; 0 otherwise)."""
        return float(self.motion.energy_ratio.numpy()[k])

    def _energy_growth(self, k: int) -> str:
        """How yarn k's kinetic energy outgrew the work its forces can have done."""
        work = max(float(self.motion.work_bound.numpy()[k]), 0.0)
        energy = float(self.motion.kinetic_peak.numpy()[k])
        return (f"the kinetic energy grew to {energy:.3g} J while the forces can have released "
                f"at most {work:.3g} J since the step's start (divergence beyond "
                f"{status.ENERGY_FACTOR:.0f} x that)")

    def _open_crossing_hint(self, k: int) -> str:
        """With friction, the likely cause of a step that does not converge
        (docs/model.md section 4): a crossing at g ~ 0, where F_T jumps (named), or else crossings
        chattering between stick and slip. "At g ~ 0" is within 1 % of the Kawabata compression
        scale C_wa + C_we. The hint names no dynamic method: which one copes depends on the scene
        (on the paper's friction path every method finishes; a method named here once failed where
        it was recommended), only remedies that hold whatever the method."""
        if not self.configuration.friction or self.model.crossings == 0:
            return ""
        yarn, positions = self.model.yarns[k], self._positions()[k]
        closure = yarn.gap_offset - yarn.crossing_side * positions[yarn.crossing_node, 1]
        j = int(np.argmin(np.abs(closure)))
        if abs(closure[j]) < 0.01 * (yarn.contact_law[1] + yarn.contact_law[3]):
            if yarn.friction_onset == 0.0:
                law = (f"Gralen's limit jumps by beta*ell*r_f = {yarn.friction_constant:.3g} N "
                       "(friction.onset_force = 0: the literal law)")
            else:
                law = (f"Gralen's limit rises by beta*ell*r_f = {yarn.friction_constant:.3g} N "
                       f"over a contact force of about friction.onset_force = "
                       f"{yarn.friction_onset:.3g} N; the static solver handles that onset")
            return (f"; crossing {j + 1} (node {yarn.crossing_node[j]}) sits at opening "
                    f"(g = {closure[j]:.3g} m), where {law}")
        return (f"; likely cause: crossings switching between stick and slip (stick spring "
                f"k_t = {yarn.stick_stiffness:.3g} N/m): a softer friction.stick_stiffness "
                "switches less abruptly, and the static solver settles each crossing's stick or "
                "slip state by Newton iteration")


class DynamicTransient:
    """The transient mode (dynamic.mode = "transient", docs/model.md section 5) through the
    `dynfab.solver.Transient` contract: a DynamicSolver driven by time, not by load step.

    Built with DynamicSolver's arguments; `advance` is `DynamicSolver.transient`.
    """

    name = DynamicSolver.name

    def __init__(self, model, options: Dynamic | None = None, device: str = "cpu", progress=None):
        self.solver = DynamicSolver(model, options, device=device, progress=progress)
        if self.solver.options.mode != "transient":
            raise UserError(f'dynamic.mode = "{self.solver.options.mode}" runs by load step: '
                             "use DynamicSolver.step")

    def attrs(self) -> dict:
        """Root attributes describing the solver, for the result file."""
        return self.solver.attrs()

    def advance(self, state, resume_from: dict | None = None):
        """Frames of the transient from `state` (or after `resume_from`), as they come."""
        return self.solver.transient(state, resume_from)
