"""The dynamic solver of every model: dynamic relaxation of each load step, or transient dynamics,
with the Warp kernel layer for any structure (docs/model.md section 5, "The dynamic solver
(decisions)").

One solver for the one-yarn model and the woven fabric: it sees only the model's
`dynfab.model.structure.Structure` (laid out and driven by
`dynfab.kernels.structure_relaxation.StructureRelaxation`) and the run contract
(`dynfab.solvers.contract.RunModel`): each load step starts at `model.start_of_step` (the flat
positions, the anchors held, the end loads per chain), is relaxed group by group (a
one-yarn model's yarns, a fabric's patch: `RunModel.groups`, the kernels' groups) until each
group's residual, the largest free force component including friction, is within its
tolerance, is certified (`dynfab.solvers.certificate.certify_groups`: stable minimum or saddle, the
escape from a saddle, the error bound and its accuracy check), and ends at
`model.finish_step` (the return map of the anchors, the record in the model's layout).

Integrators (`dynfab.kernels.structure_explicit`, `structure_semi_implicit`): `explicit`
symplectic Euler with kinetic damping (Barnes), viscous damping (given c, or adaptive after
Underwood) or FIRE 2.0; `semi_implicit` linearly implicit backward Euler with its own time
step rule (viscous c if one is given). Masses fictitious (Gershgorin, dt = 1 s) or physical
(dt from the Gershgorin bound times `safety`), float64 or float32. The transient mode
(`structure_transient`) integrates the equations of motion in physical time over the whole
load path and yields frames (`model.frame`).

Layouts: "grouped" on the CPU (a thread per group, the time loop in the kernel, a chunk of
time steps per launch, 2000 explicit or 16 semi-implicit steps first, then sized to about half
a second, so that progress is shown and Ctrl-C taken within a step; the groups split across
the cores, `use_cores`, bit-identical whatever the split and the chunks) and "node_parallel"
on a CUDA device (a launch per stage): `--device cuda` is the only change.
"""

from __future__ import annotations

import warnings

import numpy as np

from dynfab.solvers.certificate import MAX_ESCAPES, GroupLayout, certify_groups
from dynfab.errors import SolverError, UserError
from dynfab.kernels import runtime, status, structure_forces
from dynfab.kernels.precision import DEFAULT_TOLERANCE
from dynfab.kernels.structure_explicit import MAX_NEGATIVE_STEPS
from dynfab.kernels.structure_relaxation import StructureRelaxation, available_cores
from dynfab.kernels.structure_relaxation import kernel_kinematics
from dynfab.kernels.structure_settings import RELATIVE_TOLERANCE
from dynfab.scene import Dynamic, check_dynamic_options
from dynfab.solvers.contract import step_in_halves
from dynfab.model.step import StepSolution
from dynfab.model.structure import sliding

__all__ = ["DynamicSolver", "DynamicTransient", "MAX_TIGHTENINGS", "available_cores"]

_SADDLE_HINT = {"semi_implicit": " (semi_implicit accepts only steps that lower the residual, "
                                  "which cannot lead away from a saddle: use dynamic.method = "
                                  "\"explicit\")"}
"""Why a relaxation restarted from a saddle's escape may not converge, per method."""
MAX_STIFFENINGS = 3
"""Times a relaxation of crossings that slide that failed runs again with its masses doubled
past the stiffest tangent's where it got to (`DynamicSolver._relax`, docs/model.md 11.13)."""
MAX_TIGHTENINGS = 3
"""Times a load step relaxed to the default tolerance is relaxed further because its error
bound exceeds the accuracy target (`DynamicSolver._certify`)."""


def _check_refusals(structure, options) -> None:
    """A UserError in one line where the structure's elements refuse an option (their
    `REFUSALS`: the spatial ones float32, docs/model.md section 11.11; crossings that slide,
    11.13)."""
    elements = structure_forces.KINDS[kernel_kinematics(structure)]
    who, where = elements.REFUSED_BY
    for name, value, why in elements.REFUSALS:
        if getattr(options, name) == value:
            raise UserError(f'{who} dynamic.{name} = "{value}": {why} '
                            f'(docs/model.md {where})')


class DynamicSolver:
    """Relaxes a model's load steps one after another with the Warp kernels
    (docs/model.md section 5); `transient` integrates in time instead.

    `layout` and `order` choose the kernels' layout ("grouped" or "node_parallel"; default the
    device's) and the grouped layout's force order ("scatter" or "gather"), for tests and
    benchmarks (`StructureRelaxation`)."""

    name = "dynamic"

    def __init__(self, model, options: Dynamic | None = None, device: str = "cpu", progress=None,
                 *, layout: str | None = None, order: str = "scatter"):
        self.model = model
        self.options = model.scene.dynamic if options is None else check_dynamic_options(options)
        self.device = device
        self.progress = progress
        """Called as progress(text) within a step: after every launch and before the
        stability check; or None."""
        self.damping = self.options.damping_used()
        self.masses = self.options.masses_used()
        self.tolerance = self.options.tolerance or DEFAULT_TOLERANCE[self.options.precision]
        self._tolerance_override = None  # a tighter residual the accuracy target asks for [N]
        self._dt_warned = False
        runtime.initialize(device)
        transient = self.options.mode == "transient"
        _check_refusals(model.structure, self.options)
        self._kernel_layout = dict(
            method="explicit" if transient else self.options.method, layout=layout, order=order)
        self._cores = None
        self._lay_out()

    def _lay_out(self) -> None:
        """The relaxation of the model's structure as it is now (again after a yarn end has
        left a crossing that slides, docs/model.md 11.13; the kernels built once)."""
        model, method = self.model, self._kernel_layout["method"]
        self.relaxation = StructureRelaxation(
            model.structure, precision=self.options.precision, method=method,
            damping=self.damping if method == "explicit" else None,
            damping_coefficient=self.options.damping_coefficient, masses=self.masses,
            dt=self.options.dt, safety=self.options.safety, layout=self._kernel_layout["layout"],
            order=self._kernel_layout["order"], device=self.device, cores=self._cores)
        self.groups = [np.asarray(chains) for chains in model.groups]
        arrays = self.relaxation.arrays
        kernel_groups = [list(range(arrays.group_chain[g], arrays.group_chain[g + 1]))
                         for g in range(arrays.groups)]
        if kernel_groups != [list(chains) for chains in self.groups]:
            raise ValueError("the model's groups are not its structure's independent groups")
        self._layout = GroupLayout(model)  # what the certificate reads of the structure

    def use_cores(self, cores: int | None = None) -> None:
        """Launch the groups on up to `cores` CPU cores (None: every core this process may run
        on; 1: one launch of all the groups), in contiguous ranges of nearly equal size
        (`StructureRelaxation.use_cores`); results are bit-identical whatever the split."""
        self._cores = cores
        self.relaxation.use_cores(cores)

    @property
    def ranges(self) -> list[tuple[int, int]]:
        """The contiguous ranges of groups launched together (`use_cores`)."""
        return self.relaxation.ranges

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

    def _zero_load(self):
        """The load of the path's scale that is zero (a scalar or a pair)."""
        return np.zeros_like(np.asarray(self.model.step_load(0), float))

    def predicted_stable_dt(self, state, load=None) -> np.ndarray:
        """Gershgorin's stable time step [s] per group at the start of the step to `load` from
        `state` (default: zero load; a transient's start), for this solver's masses
        (docs/model.md section 5): 2 min_i sqrt(m_i / sum_j |K_ij|)."""
        start = self.model.start_of_step(state, self._zero_load() if load is None else load)
        self.relaxation.start(start.positions, start.chain_loads, start.anchors)
        return self.relaxation.group_values("stable_dt")

    def last_relaxation(self) -> dict:
        """What the last relaxation left, per group, also after a SolverError (copies):
        "time_steps" of that relaxation, "masses" [kg] per node (n,) (as chosen at its start)
        and "energy_ratio" [-] (kinetic energy over work done, the divergence check)."""
        read = self.relaxation.group_values
        return {"time_steps": read("steps"), "masses": read("mass"),
                "energy_ratio": read("energy_ratio")}

    # ------------------------------------------------------------------ a load step

    def step(self, state, load):
        """Relax every group under `load` from `state`; returns (new state, record) or raises
        SolverError (the `dynfab.solvers.contract.Solver` contract); where the crossings slide
        and it fails, the step in halves (`dynfab.solvers.contract.step_in_halves`)."""
        return step_in_halves(self._step, self.model, state, load, say=self.progress)

    def _step(self, state, load):
        """`step` in one piece."""
        if self.options.mode == "transient":
            raise UserError('dynamic.mode = "transient" runs by time, not by load step: '
                            "use DynamicSolver.transient(state), which yields frames")
        model = self.model
        if self.relaxation.structure is not model.structure:
            self._lay_out()
        start = model.start_of_step(state, load)
        self.relaxation.rows_floor = None  # each step's masses from its own start
        self._tolerance_override = None
        self._counts = {"steps": 0, "force_evaluations": 0, "cg_iterations": 0}
        outcome = self._relax(start.positions, start, first=True)
        positions, outcome, certificates, buckled = self._certify(start, outcome)
        read = self.relaxation.group_values
        fields = {"residual": outcome.residual, "iterations": self._counts["steps"].copy(),
                  "rounding_floor": outcome.status == status.ROUNDING_FLOOR,
                  **certificates.fields(), "buckled": buckled,
                  "time_steps": self._counts["steps"].copy(),
                  "force_evaluations": self._counts["force_evaluations"].copy(),
                  "dt": read("dt"), "tolerance": read("tolerance")}
        if self.relaxation.method == "semi_implicit":
            fields["cg_iterations"] = self._counts["cg_iterations"].copy()
        return model.finish_step(state, start, StepSolution(positions, certificates.limit,
                                                            fields))

    def _relax(self, positions, start, first: bool = False):
        """Relax every group from `positions` at rest with the step's anchors and loads to the
        tolerance (or the tightened one); the time steps, force evaluations and CG iterations
        counted into the step's; the outcome, or SolverError naming the first failed group.
        Where the crossings slide and a relaxation fails (its residual stalled, diverged or
        out of steps), it runs again from `positions` with masses twice those of the stiffest
        tangent at its start, where it got to and the last try (`StructureRelaxation.stiffen`:
        dt / sqrt(2) each time), at most MAX_STIFFENINGS times (docs/model.md 11.13); the
        masses stay so for the step's later relaxations (its escapes and tightenings)."""
        retries = MAX_STIFFENINGS if sliding(self.model.structure) else 0
        for stiffening in range(retries + 1):
            outcome = self._relax_once(positions, start, first and not stiffening)
            if stiffening == retries or all(code in status.SUCCESS for code in outcome.status):
                break
            reached = self.relaxation.positions()  # read back only where it runs again
            if not np.all(np.isfinite(reached)):
                break
            self.relaxation.stiffen(start.anchors, positions, reached, factor=2.0)
        self._raise_on_failure(outcome.status)
        return outcome

    def _relax_once(self, positions, start, first: bool):
        """`_relax` without its retries; the outcome, failed or not."""
        override = self._tolerance_override
        relative = RELATIVE_TOLERANCE if self.options.tolerance is None and not override else 0.0
        _, outcome = self.relaxation.relax(
            positions, start.chain_loads, start.anchors, tolerance=override or self.tolerance,
            relative_tolerance=relative, max_steps=self.options.max_steps,
            progress=None if self.progress is None else self._report)
        read = self.relaxation.group_values
        self._counts["steps"] = self._counts["steps"] + outcome.steps
        self._counts["force_evaluations"] = (self._counts["force_evaluations"]
                                             + read("force_evaluations"))
        self._counts["cg_iterations"] = self._counts["cg_iterations"] + outcome.cg_iterations
        if first:
            self._warn_if_dt_above_bound()
        return outcome

    def _certify(self, start, outcome):
        """Certify every relaxed group (`dynfab.solvers.certificate.certify_groups`, docs/model.md
        section 6): a group on a saddle is moved along its escape and every group relaxed
        again from there (at most MAX_ESCAPES times); then the accuracy check. With the default
        tolerance, a step whose error bound exceeds the accuracy target is relaxed further, to
        the residual that target needs (at most MAX_TIGHTENINGS times), before the check
        decides. Returns (positions, the last outcome, the GroupCertificates, buckled (G,))."""
        for tightening in range(MAX_TIGHTENINGS + 1):
            positions, outcome, certificates, buckled = self._escape_saddles(start, outcome)
            at_floor = outcome.status == status.ROUNDING_FLOOR
            needed = self._residual_needed(certificates, outcome.residual, at_floor)
            if needed is None or tightening == MAX_TIGHTENINGS:
                break
            self._tolerance_override = needed
            outcome = self._relax(positions, start)
        certificates.check(outcome.tolerance, self.options.accuracy, at_floor,
                           self.options.precision, "dynamic.accuracy")
        return positions, outcome, certificates, buckled

    def _escape_saddles(self, start, outcome):
        """Certify every group; move each one on a saddle along its escape and relax again, at
        most MAX_ESCAPES times. Returns (positions, outcome, certificates, buckled flags)."""
        buckled = np.zeros(len(self.groups), np.bool_)
        for attempt in range(MAX_ESCAPES + 1):
            positions = self.relaxation.positions()
            limit = self.relaxation.tie_forces(positions, start.anchors)[2]
            if self.progress is not None:
                self.progress("dynamic: stability check (inertia of the Hessian)")
            certificates = certify_groups(self.model, positions, start.anchors, limit,
                                          start.chain_loads, outcome.residual, self._layout)
            if attempt == MAX_ESCAPES or not certificates.negatives.any():
                break
            restart, moved = certificates.escaped()
            if not moved.any():
                break
            buckled |= moved
            try:
                outcome = self._relax(restart, start)
            except SolverError as error:
                hint = _SADDLE_HINT.get(self.options.method, "")
                raise SolverError(f"{error}; relaxing from a saddle's escape{hint}") from error
        return positions, outcome, certificates, buckled

    def _residual_needed(self, certificates, residual, at_floor) -> float | None:
        """With the default tolerance (none given), the residual [N] that brings every group's
        error bound within the accuracy target, if some group's bound exceeds it and is not at
        its rounding floor (there, relaxing further cannot help: the check stops the run);
        half the largest residual the target allows, for a margin. None otherwise."""
        if self.options.tolerance is not None:
            return None
        targets = self.options.accuracy * certificates.scales()
        bounds = certificates.stability.error_estimate
        needed = [0.5 * target * r / bound for target, bound, r, floor
                  in zip(targets, bounds, residual, at_floor)
                  if bound > target and np.isfinite(bound) and r > 0 and not floor]
        return min(needed) if needed else None

    # ------------------------------------------------------------------ transient

    def transient(self, state, resume_from: dict | None = None):
        """Run the transient (dynamic.mode = "transient", docs/model.md section 5) from `state`;
        yield frames (`model.frame`).

        Physical masses, viscous c (default 0), anchors return-mapped every time step,
        the load ramped piecewise-linearly from 0 at t = 0 through the load values evenly
        spaced over `duration` (the model's `transient_drive`: the end loads or displacements
        of each family, a specimen's held nodes). One frame at t = 0 and every `output_interval`, the last at
        `duration`; the time step, at most the Gershgorin dt x safety (or dynamic.dt), is
        shortened to land on every frame time.

        `resume_from`, a frame this run wrote, continues from it: the masses and time step are
        still chosen from `state` (the run's state at t = 0) and the frame's positions,
        velocities, forces and anchors replace the kernels', so a resumed run takes the very
        same steps as an uninterrupted one.
        """
        model, options = self.model, self.options
        start = model.start_of_step(state, self._zero_load())
        drive = model.transient_drive()
        restored = None if resume_from is None else model.frame_arrays(resume_from)
        frames = self.relaxation.transient(
            start.positions, start.anchors, drive.path, options.duration,
            options.output_interval, resume_from=restored,
            progress=None if self.progress is None else self._report, name=model.group_name,
            driven=drive.driven)
        for raw in frames:
            yield model.frame(raw["time"], raw)

    # ------------------------------------------------------------------ reporting

    def _report(self, relaxation) -> None:
        """One progress line per launch."""
        read = relaxation.group_values
        codes = read("status")
        running = int((codes == status.RUNNING).sum())
        self.progress(f"dynamic: {read('steps').max()} time steps, residual "
                      f"{read('residual').max():.3g} N (tolerance {read('tolerance').min():.3g} "
                      f"N), {running} of {codes.size} groups running")

    def _raise_on_failure(self, codes: np.ndarray) -> None:
        """SolverError with one line naming the first failed group, unless every one succeeded."""
        for k, code in enumerate(codes):
            if code not in status.SUCCESS:
                raise SolverError(self._failure_message(k, int(code)))

    def _warn_if_dt_above_bound(self) -> None:
        """A given dt above the predicted stable dt is allowed (Gershgorin is conservative),
        with a warning, once per solver (docs/model.md section 5). Fictitious masses scale with
        dt: no bound."""
        if self.options.dt is None or self.masses == "fictitious" or self._dt_warned:
            return
        bound = float(self.relaxation.group_values("stable_dt").min())
        if self.options.dt > bound:
            self._dt_warned = True
            warnings.warn(f"dynamic.dt = {self.options.dt:.3g} s is above the predicted stable "
                          f"time step {bound:.3g} s (Gershgorin, conservative): allowed, but the "
                          f"run may diverge (it then stops with exit status 3)",
                          RuntimeWarning, stacklevel=4)

    def _value(self, name: str, k: int) -> float:
        return float(self.relaxation.group_values(name)[k])

    def _failure_message(self, k: int, code: int) -> str:
        """What went wrong with group k, the numbers behind it, and the likely cause."""
        steps = int(self._value("steps", k))
        residual, start = self._value("residual", k), self._value("start_residual", k)
        dt, bound = self._value("dt", k), self._value("stable_dt", k)
        tolerance = self._value("tolerance", k)
        where = self.model.group_name(k)
        method = self.relaxation.method
        if code in (status.DIVERGED, status.NON_FINITE):
            cause = ("the time step is above the stability bound: lower dynamic.dt or leave it "
                     "unset" if dt > bound else
                     "a stiffness the bound did not foresee (large strain, a contact closing): "
                     "lower dynamic.safety")
            growth = ("the state became non-finite" if code == status.NON_FINITE else
                      f"the residual grew to {residual:.3g} N from {start:.3g} N"
                      if self._value("energy_ratio", k) <= status.ENERGY_FACTOR
                      else self._energy_growth(k))
            return (f"{where}: the {method} integration diverged after {steps} time "
                    f"steps ({growth}); dt = {dt:.3g} s against the predicted stable dt = "
                    f"{bound:.3g} s (Gershgorin); likely cause: {cause}")
        if code == status.STALLED:
            return (f"{where}: FIRE stalled after {steps} time steps (the power stayed negative "
                    f"for {MAX_NEGATIVE_STEPS} steps); residual {residual:.3g} N")
        if code == status.NO_PROGRESS:
            best = self._value("best_residual", k)
            since = int(self._value("steps_since_best", k))
            again = (f" (relaxed {MAX_STIFFENINGS + 1} times, the masses doubled each time)"
                     if sliding(self.model.structure) else "")
            return (f"{where}: the {method} relaxation stopped making progress: its residual "
                    f"has not fallen below {best:.3g} N during the last {since} of {steps} time "
                    f"steps (tolerance {tolerance:.3g} N){again}{self._open_tie_hint(k)}")
        if code == status.NOT_POSITIVE_DEFINITE:
            return (f"{where}: the semi_implicit matrix had a pivot that is not positive at every "
                    f"time step tried after {steps} steps; residual {residual:.3g} N")
        return (f"{where}: no convergence in {steps} time steps (dynamic.max_steps); residual "
                f"{residual:.3g} N, tolerance {tolerance:.3g} N"
                f"{self._above_bound_hint(dt, bound) or self._open_tie_hint(k)}")

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

    def _energy_growth(self, k: int) -> str:
        """How group k's kinetic energy outgrew the work its forces can have done."""
        work = max(self._value("work_bound", k), 0.0)
        energy = self._value("kinetic_peak", k)
        return (f"the kinetic energy grew to {energy:.3g} J while the forces can have released "
                f"at most {work:.3g} J since the step's start (divergence beyond "
                f"{status.ENERGY_FACTOR:.0f} x that)")

    def _open_tie_hint(self, k: int) -> str:
        """With friction, the likely cause of a step that does not converge
        (docs/model.md section 4): a crossing of group k at g ~ 0, where F_T jumps (named: its
        place among the group's ties and its node a along that node's chain), or else
        crossings chattering between stick and slip. "At g ~ 0" is within 1 % of the Kawabata
        compression scale C_a + C_b. The hint names no dynamic method: which one copes depends
        on the scene, only remedies that hold whatever the method."""
        s, a = self.model.structure, self.relaxation.arrays
        ties = np.arange(a.group_tie[k], a.group_tie[k + 1])
        if not s.has_friction or ties.size == 0:
            return ""
        positions = self.relaxation.positions()
        z_b = np.where(s.tie_b[ties] >= 0, positions[np.maximum(s.tie_b[ties], 0), -1], 0.0)
        closure = s.tie_gap_offset[ties] - s.tie_side[ties] * (positions[s.tie_a[ties], -1]
                                                               - z_b)
        j = int(np.argmin(np.abs(closure)))
        t = ties[j]
        alpha, constant, onset, stick = s.tie_friction_law[t]
        law = s.tie_contact_law[t]
        if abs(closure[j]) < 0.01 * (law[1] + law[3]):
            node = int(s.tie_a[t] - s.chain_start[np.searchsorted(s.chain_start, s.tie_a[t],
                                                                  side="right") - 1])
            if onset == 0.0:
                rule = (f"Gralen's limit jumps by beta*ell*r_f = {constant:.3g} N "
                        "(friction.onset_force = 0: the literal law)")
            else:
                rule = (f"Gralen's limit rises by beta*ell*r_f = {constant:.3g} N "
                        f"over a contact force of about friction.onset_force = "
                        f"{onset:.3g} N; the static solver handles that onset")
            return (f"; crossing {j + 1} (node {node}) sits at opening "
                    f"(g = {closure[j]:.3g} m), where {rule}")
        return (f"; likely cause: crossings switching between stick and slip (stick spring "
                f"k_t = {stick:.3g} N/m): a softer friction.stick_stiffness "
                "switches less abruptly, and the static solver settles each crossing's stick or "
                "slip state by Newton iteration")


class DynamicTransient:
    """The transient mode (dynamic.mode = "transient", docs/model.md section 5) through the
    `dynfab.solvers.contract.Transient` contract: a DynamicSolver driven by time, not by load step.

    Built with DynamicSolver's arguments; `advance` is `DynamicSolver.transient`.
    """

    name = DynamicSolver.name

    def __init__(self, model, options: Dynamic | None = None, device: str = "cpu", progress=None,
                 **layout):
        self.solver = DynamicSolver(model, options, device=device, progress=progress, **layout)
        if self.solver.options.mode != "transient":
            raise UserError(f'dynamic.mode = "{self.solver.options.mode}" runs by load step: '
                            "use DynamicSolver.step")

    def attrs(self) -> dict:
        """Root attributes describing the solver, for the result file."""
        return self.solver.attrs()

    def advance(self, state, resume_from: dict | None = None):
        """Frames of the transient from `state` (or after `resume_from`), as they come."""
        return self.solver.transient(state, resume_from)
