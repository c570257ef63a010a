"""The solvers of every model, by name: `make_solver(model, "static" | "dynamic")`.

Neither a solver nor the model side: the one place that knows which solver classes drive
which model (`dynfab.solvers.contract` states their contracts). The static solver is one for every
model (numba and scipy; its backend follows the structure, `dynfab.solvers.static`); a dynamic one
imports Warp, so it is imported only when asked for.
"""

from __future__ import annotations

from dynfab.errors import UserError
from dynfab.options import check_solver


def make_solver(model, name: str, device: str | None = None, status=None):
    """The solver `name` ("static" or "dynamic") built for `model` (its options are the
    scene's): a `dynfab.solvers.contract.Solver` driven by load step or, for dynamic.mode =
    "transient", a `Transient` driven by time; it reports within a step to `status` (per
    Newton iteration or yarn solved, per launch of a relaxation). One dynamic solver drives
    every model (`dynfab.solvers.dynamic`), one static solver too (`dynfab.solvers.static`: its
    backend follows the structure)."""
    name = check_solver(name)
    if name == "static":
        if device is not None:
            raise UserError(f"--device {device}: the static solver runs on the CPU (numba); "
                            "a device is for --solver dynamic")
        if model.scene.dynamic.mode == "transient":
            raise UserError('dynamic.mode = "transient" integrates in time, which the static '
                            "solver does not: run it with --solver dynamic (or remove the "
                            "mode for a quasi-static run)")
        from dynfab.solvers.static import StaticSolver  # its backend follows the structure
        return StaticSolver(model, status=status)
    from dynfab.solvers.dynamic import DynamicSolver, DynamicTransient
    kind = DynamicTransient if model.scene.dynamic.mode == "transient" else DynamicSolver
    return kind(model, device=device or "cpu", progress=status)
