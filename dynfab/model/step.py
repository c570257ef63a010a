"""A load step between the model and a solver: where it starts, and what the solver found
(docs/model.md, "The structure": the solvers see the structure, the model turns their
solution into its state and record).

`RunModel.start_of_step` gives a `StepStart`; a solver returns a `StepSolution`;
`RunModel.finish_step` makes the new state and the step's record from them. Every solver
of every model goes through these two, so no solver builds a record and no model knows
its solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class StepStart:
    """Where a load step starts, for every model (`RunModel.start_of_step`), in the structure's
    order (`dynfab.model.structure`): what a solver needs of the model to solve the step."""

    load: np.ndarray
    """The step's value of the load path [N or m], as `RunModel.step_load` gives it."""
    positions: np.ndarray
    """(n, dim) [m]: the previous state's, and under displacement control the loaded ends
    moved to their prescribed displacements (the increment spread along each chain)."""
    anchors: np.ndarray
    """(T, 2) [m] the friction anchors held during the step (docs/model.md section 4): the
    slip of each tie's node a (and b) from its plane."""
    chain_loads: np.ndarray
    """(Y,) [N] the end force along each chain's last node: the load under force control,
    0 under displacement control."""


@dataclass
class StepSolution:
    """What a solver found for a load step (`RunModel.finish_step` turns it into the new state
    and the step's record)."""

    positions: np.ndarray
    """(n, dim) [m] the converged positions."""
    limit: np.ndarray | None
    """(T,) [N] the friction limits F_T at the solution (Gralen's law of its contact forces);
    None where the model computes them from the positions (the one-yarn model's)."""
    fields: dict
    """Record entries the solver reports, each with one value per group of the structure
    (`RunModel.groups`: a one-yarn model's yarns, a fabric's one patch): residual [N],
    iterations, rounding_floor and the certificate's fields
    (`dynfab.solvers.certificate.StepStability`), and its own (time_steps, cg_iterations, ...;
    `dynfab.results.file.UNITS`)."""


