"""The fabric's dynamic solver: each load step relaxed by the Warp kernels
(docs/model.md sections 5, 10).

`FabricDynamicSolver.step(state, warp_value, weft_value)` takes the same state
(`dynfab.fabric.model.FabricState`) and returns the same record keys as
`FabricStaticSolver.step`, so the two are interchangeable and comparable step by step
(tests/test_fabric_dynamic.py). The geometry and parameters are the model's structure
(`dynfab.kernels.fabric_arrays.build` lays it out); the physics of the relaxation is the Warp
twin's own
(`dynfab.kernels.fabric_forces`, `fabric_explicit.FabricExplicit`): forces, contact
forces, friction forces, the reaction at a prescribed end and the anchors' return map.

A load step: the end loads (force control) or the prescribed end displacements
(displacement control, the increment spread along each yarn as the static solver
starts its Newton) are applied, and the patch relaxes from rest (kinetic damping by
default) with the step's anchors held, until the largest free force component is at
most the tolerance; then the anchors are return-mapped radially (docs/model.md section 4).

Friction, against the static solver's outer loop (docs/model.md sections 4, 10): the static solver
freezes F_T during a Newton solve, updates it to Gralen's law at the solution and solves
again until the residual with F_T from the law at the solution is within the tolerance.
The relaxation needs no outer loop: its force evaluates F_T at the current contact force
at every time step (frozen only in the derivative, which an explicit step never takes),
so a converged relaxation is that same consistent point, the residual with F_T from the
law at the solution within the tolerance. The return map after the step is the static
solver's. (A relaxation is not a descent on one potential when F_T moves with R; it
converges where the contact forces settle, which the tests check on small patches.)

Stability (docs/model.md section 6): as the one-yarn dynamic solver uses the shared certificate, the
relaxed state is certified by the model side (`dynfab.certificate.certify_patch`: the
inertia of its Hessian with F_T frozen); from a saddle the certificate's escape
(`dynfab.certificate.escape_patch`) is taken and the step relaxed again from there (at most
`dynfab.certificate.MAX_ESCAPES` times). The load prescription at a step's start, its end
(end displacements, the loads' work, the dissipation), strains and crimps are the model's
(`dynfab.fabric.model.FabricModel`), as the static solver's are: no solver imports another.

Every boundary of docs/model.md section 10 (the clamped patch with fixed or "affine" planes,
the periodic cell under force or displacement control) is data to the kernels
(`dynfab.kernels.fabric_arrays`): the planes move with the summed end displacements and
their friction reaction acts on those ends, the wrap springs join node N-1 to node 1 across
node 0, and under periodic force control each family's end nodes move as one dof, the cell
length, of their summed masses under their summed end forces plus n P (the load potential
-n_wa P_wa (L1 - L) - n_we P_we (L2 - L_we)); under displacement control the cell lengths
are prescribed like any end.
Gravity, a constant force on the physical masses (docs/model.md section 2), is added to the end
loads.

`method="semi_implicit"` relaxes each load step with `fabric_semi_implicit.FabricSemiImplicit`
instead (linearly implicit steps, conjugate gradients preconditioned by the yarns' banded
solves; docs/model.md section 10); everything else above is shared.
"""

from __future__ import annotations

import time

import numpy as np
import warp as wp

from dynfab.certificate import (MAX_ESCAPES, certify_patch, check_patch_accuracy, escape_patch,
                                patch_stability)
from dynfab.errors import SolverError, UserError
from dynfab.fabric.model import FabricState, run_load_path
from dynfab.step import StepSolution
from dynfab.structure import chain_count
from dynfab.kernels.runtime import initialize
from dynfab.kernels import (fabric_arrays, fabric_explicit, fabric_forces, fabric_semi_implicit,
                            status)
from dynfab.terms import friction as gralen

SCALAR = wp.float64
MAX_STEPS = 2_000_000
"""Time steps a relaxation may take per load step (launched a chunk at a time)."""
_STATUS = {status.MAX_STEPS: "the time-step limit", status.NON_FINITE: "a non-finite force",
           status.STALLED: "FIRE stalled", status.DIVERGED: "divergence",
           status.NOT_POSITIVE_DEFINITE: "pivots that are not positive at every dt",
           status.NO_PROGRESS: "no progress"}
METHODS = ("explicit", "semi_implicit")
"""The integrators: `fabric_explicit.FabricExplicit` (every damping) or
`fabric_semi_implicit.FabricSemiImplicit` (linearly implicit, PCG; no damping to choose)."""


class FabricDynamicSolver:
    """Relaxes a fabric's load steps one after another with the Warp kernels
    (docs/model.md sections 5, 10)."""

    def __init__(self, model, device: str = "cpu", damping: str = "kinetic",
                 tolerance: float | None = None, max_steps: int = MAX_STEPS,
                 layout: str | None = None, method: str = "explicit",
                 damping_coefficient: float | None = None, accuracy: float | None = None,
                 status=None):
        if method not in METHODS:
            raise UserError(f"fabric: dynamic.method = {method!r} unknown; one of {METHODS}")
        self.model = model
        self.tolerance = (model.scene.static.tolerance if tolerance is None
                          else float(tolerance))
        """Residual tolerance [N] of a relaxation (the static Newton tolerance by default)."""
        self.accuracy = model.scene.dynamic.accuracy if accuracy is None else float(accuracy)
        """Largest accepted error bound of a step relative to its largest displacement
        (docs/model.md, "Stability and accuracy of a converged step"; the scene's
        dynamic.accuracy by default)."""
        self.max_steps = int(max_steps)
        self.arrays = fabric_arrays.build(model.structure)
        # the kernels built with friction in every case (F_T = k_t = 0 without it): one
        # variant per damping, the one the kernel tests build
        if damping == "viscous" and damping_coefficient is None:
            raise UserError("fabric: viscous damping needs its coefficient c [1/s] (no adaptive c)")
        self.relaxation = fabric_explicit.FabricExplicit(
            self.arrays, device=device, layout=layout, damping=damping, friction=True,
            coefficient=damping_coefficient or 0.0) \
            if method == "explicit" else fabric_semi_implicit.FabricSemiImplicit(
                self.arrays, device=device, layout=layout)
        self.relaxation.report = self._report
        self.status = status
        """Called as status(text) within a step: at every launch of a relaxation (at most
        every `fabric_relaxation.CHUNK_SECONDS`; its time steps and residual) and before the
        stability check; or None."""
        self.method = method
        self.linear_iterations = 0
        """CG iterations of every relaxation so far (0 with the explicit method)."""
        self.fabric = model.structure
        self.yarns = chain_count(self.fabric)
        f = self.fabric
        self._plane_shift = np.stack([f.tie_plane[:, 0] - f.rest_position[f.tie_a, 0],
                                      f.tie_plane[:, 1] - f.rest_position[f.tie_b, 0]], axis=1)
        """The kernels' anchors (slip from the crossing nodes' as-woven coordinates) minus
        the static solver's (slip from the planes) [m]: a rounding-size constant."""
        reaction = self.arrays.free.copy()
        reaction[f.load_node] = 1.0  # the end dofs unmasked: their internal force is read
        self._reaction_fabric = fabric_arrays.upload(
            fabric_arrays.PatchArrays(**{**vars(self.arrays), "free": reaction}), SCALAR,
            device)
        self.device = device

    def initial_state(self) -> FabricState:
        """As woven, anchors at zero slip, nothing dissipated (the model's)."""
        return self.model.initial_state()

    # ------------------------------------------------------------------ pieces

    def external_force(self, P: np.ndarray) -> np.ndarray:
        """End loads P (Y,) [N] on each yarn's last node along the yarn, plus gravity (n, 2) [N]."""
        a, f = self.arrays, self.fabric
        force = a.weight.copy()
        force[f.load_node, 0] += P
        return force

    def crossing_forces(self, pos: np.ndarray, kernel_anchors: np.ndarray):
        """(R (C,) [N], friction force on the slip (C, 2) [N]) from the kernels' crossing pass."""
        a = self.arrays
        passes = fabric_forces.kernels(SCALAR, True)
        contact = wp.zeros(a.crossings, dtype=SCALAR, device=self.device)
        friction = wp.zeros(a.crossings, dtype=wp.vec2d, device=self.device)
        wp.launch(passes.crossing_pass, dim=a.crossings, device=self.device,
                  inputs=[self._vectors(pos), self.relaxation.fabric,
                          self._vectors(kernel_anchors), contact, friction])
        return contact.numpy().astype(float), friction.numpy().astype(float)

    def internal_force(self, pos: np.ndarray, kernel_anchors: np.ndarray) -> np.ndarray:
        """-dV/dr (n, 2) [N] without external loads, the end dofs unmasked (the kernels' passes)."""
        a = self.arrays
        passes = fabric_forces.kernels(SCALAR, True)
        pos_wp = self._vectors(pos)
        contact = wp.zeros(a.crossings, dtype=SCALAR, device=self.device)
        friction = wp.zeros(a.crossings, dtype=wp.vec2d, device=self.device)
        force = wp.zeros(a.nodes, dtype=wp.vec2d, device=self.device)
        wp.launch(passes.crossing_pass, dim=a.crossings, device=self.device,
                  inputs=[pos_wp, self._reaction_fabric, self._vectors(kernel_anchors), contact,
                          friction])
        wp.launch(passes.node_pass, dim=a.nodes, device=self.device,
                  inputs=[pos_wp, self._reaction_fabric, contact, friction,
                          self._vectors(np.zeros((a.nodes, 2))), force])
        return force.numpy().astype(float)

    def friction_limits(self, R: np.ndarray) -> np.ndarray:
        """F_T [N] of Gralen's law with its onset at contact forces R (docs/model.md section 4); 0
        where open."""
        alpha, constant, onset, _ = self.arrays.friction_law
        out = np.zeros(R.size)
        gralen.limits(np.ascontiguousarray(R, float), alpha, constant, onset, out)
        return out

    def _vectors(self, values):
        return wp.array(np.asarray(values, float), dtype=wp.vec2d, device=self.device)

    # ------------------------------------------------------------------ steps

    def _report(self, steps: int, residual: float) -> None:
        """The relaxation's progress (`PatchRelaxation.report`) as a status line."""
        if self.status is not None:
            self.status(f"{steps} time steps, residual {residual:.3g} N (tolerance "
                        f"{self.tolerance:.3g} N)")

    def relax(self, pos: np.ndarray, P: np.ndarray, anchors: np.ndarray):
        """Relax from `pos` under end loads P with the (static-convention) anchors held;
        returns (positions, outcome) or raises SolverError."""
        positions, outcome = self.relaxation.relax(pos, self.external_force(P), self.tolerance,
                                                   self.max_steps, anchors + self._plane_shift)
        self.linear_iterations += getattr(outcome, "cg_iterations", 0)
        if outcome.status != status.CONVERGED:
            cause = _STATUS.get(outcome.status, f"status {outcome.status}")
            raise SolverError(
                f"fabric dynamic: relaxation stopped by {cause} after {outcome.steps} time steps; "
                f"residual {outcome.residual:.3g} N, tolerance {self.tolerance:.3g} N")
        return positions, outcome

    name = "dynamic"

    @classmethod
    def from_scene(cls, model, device: str = "cpu", status=None) -> "FabricDynamicSolver":
        """The solver of `model` with its scene's [dynamic] options (`check_dynamic_keys`)."""
        dynamic = model.scene.dynamic
        check_dynamic_keys(dynamic)
        initialize(device)
        return cls(model, device=device, damping=dynamic.damping_used(),
                   tolerance=dynamic.tolerance, max_steps=dynamic.max_steps,
                   method=dynamic.method, damping_coefficient=dynamic.damping_coefficient,
                   accuracy=dynamic.accuracy, status=status)

    def attrs(self) -> dict:
        """Root attributes of the result file describing the solver and its options."""
        static, dynamic = self.model.scene.static, self.model.scene.dynamic
        return {"solver": self.name, "static_tolerance": static.tolerance,
                "static_max_iterations": static.max_iterations,
                "dynamic_damping": dynamic.damping_used(), "dynamic_method": dynamic.method,
                "dynamic_accuracy": dynamic.accuracy}

    def step(self, state: FabricState, load):
        """Relax the step under `load` = (warp value, weft value) from `state`; returns (new
        state, record) (`dynfab.solver.Solver`) or raises SolverError. The record holds the
        static solver's keys, iterations counting time steps, plus time_steps and, with the
        semi-implicit method, cg_iterations."""
        model = self.model
        start = model.start_of_step(state, load)
        pos, anchors, P = start.positions, start.anchors, start.chain_loads
        linear = self.linear_iterations
        began = time.perf_counter()
        pos, outcome = self.relax(pos, P, anchors)
        steps, escapes = outcome.steps, 0
        while True:
            R, _ = self.crossing_forces(pos, anchors + self._plane_shift)
            limit = self.friction_limits(R)
            if self.status is not None:
                self.status("stability check (inertia of the Hessian)")
            checked = certify_patch(model, pos, anchors, limit)
            if checked.negatives == 0 or escapes == MAX_ESCAPES:
                break
            escaped = escape_patch(model, pos, P, anchors, limit, checked)
            if escaped is None:
                break
            escapes += 1
            pos, outcome = self.relax(escaped, P, anchors)
            steps += outcome.steps
        self.relax_time = time.perf_counter() - began
        """The wall time of the last step's relaxations and stability checks [s]."""
        stability = patch_stability(checked, outcome.residual, escapes)
        check_patch_accuracy(model, checked, stability, pos, outcome.residual, self.tolerance,
                             self.accuracy, False, "dynamic.accuracy")
        fields = dict(residual=[outcome.residual], iterations=[steps],
                      friction_solves=[1 + escapes], rounding_floor=[False],
                      negative_eigenvalues=[checked.negatives], **stability.fields(),
                      time_steps=[steps])
        if self.method == "semi_implicit":
            fields["cg_iterations"] = [self.linear_iterations - linear]
        return model.finish_step(state, start, StepSolution(pos, limit, fields))

    def run(self, state: FabricState | None = None):
        """Every load step of the model in sequence; returns (final state, records)."""
        return run_load_path(self, state)


_DYNAMIC_SUPPORTED = {"mode": "quasi_static", "method": "explicit", "precision": "float64",
                      "masses": None, "dt": None, "safety": 0.9}
"""The [dynamic] settings the fabric's dynamic solver runs (`FabricDynamicSolver`: a
quasi-static explicit relaxation in float64 with its own fictitious masses and time step);
any other value is refused rather than ignored; method "semi_implicit" is accepted too
(`fabric_semi_implicit.FabricSemiImplicit`, docs/model.md section 10)."""


def check_dynamic_keys(dynamic) -> None:
    """Refuse, in one line, a [dynamic] setting the fabric's dynamic solver would ignore."""
    for key, supported in _DYNAMIC_SUPPORTED.items():
        value = getattr(dynamic, key)
        if key == "method" and value == "semi_implicit":  # FabricSemiImplicit
            continue
        if value != supported:
            raise UserError(f"dynamic.{key} = {value!r}: the fabric's dynamic solver runs "
                            f"{key} = {supported!r} only (docs/model.md section 10)")
    if dynamic.damping_used() == "viscous" and dynamic.damping_coefficient is None:
        raise UserError("dynamic.damping = 'viscous': the fabric's dynamic solver has no "
                        "adaptive viscous coefficient; give dynamic.damping_coefficient [1/s] "
                        "or use \"kinetic\" or \"fire\"")
