"""A fabric scene (geometry.model = "fabric", docs/model.md section 10) as a run: its model
and its solvers under the run's contract.

`FabricModel` (`dynfab.fabric.model`) is what a run needs of a fabric scene: its structure
(`dynfab.build.fabric`), its yarn families, the load path, the as-woven reference, the root
attributes, the start state and a resumed state; `FabricSolver` wraps `FabricStaticSolver`
(or the dynamic one)
so that it conforms to `dynfab.solver.Solver`: `step(state, load)` with `load` the step's
pair (warp value, weft value) of the path, the same kind of thing the one-yarn model's load
value is (a value of the path, not an index into it), returning a record of the names
below, written as `steps/<name>` (units in `dynfab.results.UNITS`).

Record of one fabric step (n_wa warps of N+1 nodes, n_we wefts of M+1 nodes; Y = n_wa
+ n_we yarns, warps first):

- load (2,): (warp, weft) value [N or m]; end_force, end_displacement (Y,) [N], [m];
- positions (n_wa, N+1, 2): the warps' (x, z); weft_positions (n_we, M+1, 2): the
  wefts' (y, z) [m];
- strain, crimp (2,): (warp, weft) nominal strain and mean crimp [-]; stress (2,):
  (warp, weft) load per unit width [N/m] (`FabricModel.stresses`);
- slip_ratio: the largest slip ratio of the step's crossing nodes [-]
  (`dynfab.domain.slip_ratios`; a run stops a step above 1/2, docs/model.md section 10);
- contact_force, friction_limit, sliding (n_wa, n_we); friction_force, anchors
  (n_wa, n_we, 2) [N], [m] (in-plane: warp x, weft y; the anchors relative to the planes);
- warp_planes (n_wa,): the plane y = Y_k of each warp, weft_planes (n_we,): x = X_j of each
  weft [m], where they are at the step's end (they move with "affine" planes and on the
  periodic cell, docs/model.md section 10);
- dissipated, work [J]; energy/<term> [J] per active term of the registry
  (`dynfab.terms.registry`, its dataset names and order, as the one-yarn model's);
- residual [N], iterations, friction_solves, rounding_floor; the certificate
  (`dynfab.certificate.StepStability`, docs/model.md section 6): stable, buckled (an escape
  from a saddle was taken), lowest_eigenvalue [N/m] (the lowest eigenvalue of the
  frozen-F_T Hessian on the unknowns), lowest_eigenvalue_error [N/m] (lambda_min lies in
  [lowest_eigenvalue - error, lowest_eigenvalue]), error_estimate [m] (residual x est
  ||H^-1||_inf, the position error bound the accuracy check holds to static.accuracy or
  dynamic.accuracy of the step's largest displacement), negative_eigenvalues; scalars;
- with the dynamic solver, time_steps (the time steps of the step's relaxations, also its
  iterations), and with the semi-implicit method cg_iterations (their CG iterations).
"""

from __future__ import annotations

import numpy as np

from dynfab.certificate import CERTIFICATE_KEYS
from dynfab.domain import fabric_slip_ratios
from dynfab.fabric.assembly import TERMS
from dynfab.fabric.model import FabricModel, FabricState
from dynfab.terms import registry


class FabricSolver:
    """A fabric solver under `dynfab.solver.Solver`, one load step per call: the static
    `FabricStaticSolver`, or the dynamic `FabricDynamicSolver` (Warp), which returns the
    same record (plus its time steps)."""

    def __init__(self, model: FabricModel, name: str = "static", device: str = "cpu",
                 status=None):
        self.model, self.name = model, name
        if name == "dynamic":
            from dynfab.fabric.dynamic import FabricDynamicSolver  # imports Warp: only here
            from dynfab.kernels.runtime import initialize

            initialize(device)
            dynamic = model.scene.dynamic
            self.engine = FabricDynamicSolver(model, device=device,
                                              damping=dynamic.damping_used(),
                                              tolerance=dynamic.tolerance,
                                              max_steps=dynamic.max_steps,
                                              method=dynamic.method,
                                              damping_coefficient=dynamic.damping_coefficient,
                                              accuracy=dynamic.accuracy, status=status)
        else:
            from dynfab.fabric.static import FabricStaticSolver

            self.engine = FabricStaticSolver(model, status)  # reports per Newton iteration

    def attrs(self) -> dict:
        static = self.model.scene.static
        attrs = {"solver": self.name, "static_tolerance": static.tolerance,
                 "static_max_iterations": static.max_iterations}
        if self.name == "static":
            attrs["static_accuracy"] = static.accuracy  # as the one-yarn run's
        if self.name == "dynamic":
            attrs["dynamic_damping"] = self.model.scene.dynamic.damping_used()
            attrs["dynamic_method"] = self.model.scene.dynamic.method  # as the one-yarn run's
            attrs["dynamic_accuracy"] = self.model.scene.dynamic.accuracy
        return attrs

    def step(self, state: FabricState, load) -> tuple[FabricState, dict]:
        """Solve the step under `load` = (warp value, weft value) from `state` (not modified);
        returns (new state, record of the module docstring's names). SolverError as
        `FabricStaticSolver.step`."""
        warp_value, weft_value = (float(v) for v in load)
        new, raw = self.engine.step(state, warp_value, weft_value)
        model = self.model
        warps, wefts = model.split(new.positions)
        shape = (model.warps, model.wefts)
        record = {
            "load": np.array([warp_value, weft_value]),
            "end_force": raw["end_force"], "end_displacement": raw["end_displacement"],
            "positions": warps, "weft_positions": wefts,
            "strain": raw["strain"], "stress": model.stresses(raw["end_force"]),
            "crimp": raw["crimp"],
            "contact_force": raw["contact_force"], "friction_limit": raw["friction_limit"],
            "sliding": raw["sliding"], "friction_force": raw["friction_force"].reshape(*shape, 2),
            "anchors": new.anchors.reshape(*shape, 2),
            **model.planes(new.positions),
            "dissipated": new.dissipated, "work": new.work,
            "residual": raw["residual"], "iterations": raw["iterations"],
            "friction_solves": raw["friction_solves"], "rounding_floor": raw["rounding_floor"],
            **{name: raw[name] for name in CERTIFICATE_KEYS},
            "negative_eigenvalues": raw["negative_eigenvalues"],
        }
        record.update(self._energies(new, warp_value, weft_value, raw["friction_limit"]))
        ratios = fabric_slip_ratios(record, *model.crossing_nodes())
        record["slip_ratio"] = np.max(np.concatenate([r.ravel() for r in ratios]), initial=0.0)
        for name in ("time_steps", "cg_iterations"):  # the dynamic solver's (the semi-implicit's)
            if name in raw:
                record[name] = raw[name]
        return new, {name: np.asarray(value) for name, value in record.items()}

    def _energies(self, state: FabricState, warp_value, weft_value, limit) -> dict:
        """energy/<term> [J] at the step's end: the load term with the end forces P (force
        control; none under displacement control), friction with the return-mapped anchors."""
        model = self.model
        P = (model.yarn_loads(warp_value, weft_value) if model.control == "force"
             else np.zeros(model.yarns))
        terms = model.energies(state.positions, P, state.anchors, np.asarray(limit).ravel())
        values = dict(zip(TERMS, terms))  # the assembly's energy vector, by term name
        return {registry.TERMS[registry.index(term)].dataset: float(values[term])
                for term in registry.active_terms(model.scene)}


_DYNAMIC_SUPPORTED = {"mode": "quasi_static", "method": "explicit", "precision": "float64",
                      "masses": None, "dt": None, "safety": 0.9}
"""The [dynamic] settings the fabric's dynamic solver runs (`FabricDynamicSolver`: a
quasi-static explicit relaxation in float64 with its own fictitious masses and time step);
any other value is refused rather than ignored; method "semi_implicit" is accepted too
(`fabric_semi_implicit.FabricSemiImplicit`, docs/model.md section 10)."""


def check_dynamic_keys(dynamic) -> None:
    """Refuse, in one line, a [dynamic] setting the fabric's dynamic solver would ignore."""
    from dynfab.errors import UserError

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
